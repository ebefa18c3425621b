"""The network input height chosen from the camera: the far person reaches the size the
detector needs, within the measured range of inputs."""

from __future__ import annotations

import dataclasses
import logging
import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from follow.camera import CameraModel, CameraPose
from follow.config import PoseConfig
from follow.pose.input_size import (
    MAX_INPUT_HEIGHT_PX,
    MIN_INPUT_HEIGHT_PX,
    far_person_input_px,
    input_height_for_camera,
    pose_config_for_camera,
    reliable_person_input_px,
)


def camera(size=(640, 480), hfov_deg=60.0) -> CameraModel:
    pose = CameraPose(height_m=1.0, pitch_rad=0.0, roll_rad=0.0, yaw_rad=0.0, x_m=0.0, y_m=0.0)
    return CameraModel.from_fov(size, hfov_deg, pose)


def test_a_wider_camera_needs_a_larger_input():
    config = PoseConfig()
    narrow = pose_config_for_camera(config, camera(hfov_deg=50.0)).input_height_px
    wide = pose_config_for_camera(config, camera(hfov_deg=90.0)).input_height_px
    assert narrow < wide


def test_a_nearer_far_person_allows_a_smaller_input():
    indoor = dataclasses.replace(PoseConfig(), far_person_distance_m=4.0)
    outdoor = dataclasses.replace(PoseConfig(), far_person_distance_m=8.0)
    cam = camera()
    assert (pose_config_for_camera(indoor, cam).input_height_px
            < pose_config_for_camera(outdoor, cam).input_height_px)  # fmt: skip


@given(st.floats(100.0, 3000.0), st.sampled_from([360, 480, 720, 1080]),
       st.floats(2.0, 20.0), st.floats(40.0, 160.0))  # fmt: skip
def test_the_far_person_reaches_the_reliable_size_unless_clamped(focal_px, rows, far_m, need_px):
    config = dataclasses.replace(PoseConfig(), far_person_distance_m=far_m,
                                 min_person_input_px=need_px)  # fmt: skip
    height = input_height_for_camera(focal_px, rows, config)
    assert height % 8 == 0 and MIN_INPUT_HEIGHT_PX <= height <= MAX_INPUT_HEIGHT_PX
    person_in_input = focal_px * config.far_person_height_m / far_m * height / rows
    if height < MAX_INPUT_HEIGHT_PX:
        assert person_in_input >= need_px - 1e-9
    if height > MIN_INPUT_HEIGHT_PX:  # the smallest such multiple of 8
        assert person_in_input * (height - 8) / height < need_px


def test_resolution_does_not_change_the_choice_for_the_same_field_of_view():
    config = PoseConfig()
    low = pose_config_for_camera(config, camera((640, 360), 70.0)).input_height_px
    high = pose_config_for_camera(config, camera((1280, 720), 70.0)).input_height_px
    assert abs(low - high) <= 8


def test_switched_off_the_configured_height_stays_and_a_too_small_one_is_warned(caplog):
    config = dataclasses.replace(PoseConfig(), input_height_from_camera=False,
                                 input_height_px=256)  # fmt: skip
    cam = camera(hfov_deg=100.0)
    with caplog.at_level(logging.WARNING, logger="follow.pose.input_size"):
        chosen = pose_config_for_camera(config, cam)
    assert chosen.input_height_px == 256
    assert far_person_input_px(chosen, cam) < reliable_person_input_px(config)
    assert "may miss them" in caplog.text


@pytest.mark.parametrize("focal, rows", [(0.0, 480), (math.nan, 480), (500.0, 0)])
def test_an_impossible_camera_is_refused(focal, rows):
    with pytest.raises(ValueError, match="camera"):
        input_height_for_camera(focal, rows, PoseConfig())


def test_follow_run_sizes_the_network_for_its_camera(model_path, caplog):
    """The wiring: `follow run`'s perception asks the rule, and the detector it builds runs
    at the chosen height."""
    from follow.config import Config
    from follow.run import build_perception

    model_path("pose/human-pose-estimation-0001.onnx")
    config = Config().replace("pose", precision="fp32", warmup_runs=0)
    with caplog.at_level(logging.INFO):
        build_perception(config, camera((640, 480), 90.0))
    # FP32 finds the far person from 74 px: 64 px in the 480-line image -> 555 -> 560 px
    # (the INT8 model's 85 px would need 638, clamped to 576 and warned about)
    assert "pose input 560 px (chosen for the camera)" in caplog.text
    assert "found reliably from 74 px" in caplog.text
    assert "may miss them" not in caplog.text
