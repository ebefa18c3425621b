"""The robot scene of `follow bench --scene robot`: real crops placed where a 60-degree
camera 1 m up sees people at their distances, and the bench run on it."""

from __future__ import annotations

import argparse

import numpy as np
import pytest

from follow.eval.robot_scene import PERSON_HEIGHT_M, RobotScene


@pytest.fixture
def data_root(data_path):
    data_path("ccf_crops/p01.jpg")
    return data_path("cuhk03_val/0000_00.jpg").parents[1]


def test_people_stand_at_their_distances_in_the_image(data_root):
    scene = RobotScene(data_root, people=5, far_m=8.0)
    f_y = scene.camera.K[1, 1]
    assert scene.distances_m[0] == 2.5 and scene.distances_m[-1] == 8.0
    for person, distance in enumerate(scene.distances_m):
        x0, y0, width, height = scene.person_box_px(person, 0)
        assert height == pytest.approx(f_y * PERSON_HEIGHT_M / distance, abs=1.5)
        feet_v = scene.camera.K[1, 2] + f_y * 1.0 / distance  # camera 1 m up, level
        assert y0 + height == pytest.approx(feet_v, abs=1.5)
    frame = scene.read_frame(0)
    assert frame.shape == (480, 640, 3) and frame.dtype == np.uint8
    x0, y0, width, height = scene.person_box_px(0, 0)
    assert (frame[y0 + height // 2, x0 + width // 2] != 128).any()  # the target is there


@pytest.mark.parametrize(("people", "far_m", "distances_m"), [
    (1, 8.0, [2.5]), (2, 8.0, [2.5, 8.0]), (3, 8.0, [2.5, 3.0, 8.0]),
])  # fmt: skip
def test_the_farthest_person_stands_at_far_m(data_root, people, far_m, distances_m):
    assert RobotScene(data_root, people=people, far_m=far_m).distances_m == distances_m


def test_people_walk_side_to_side(data_root):
    scene = RobotScene(data_root, people=1)
    assert scene.person_box_px(0, 0)[0] != scene.person_box_px(0, 20)[0]


@pytest.mark.parametrize(("people", "far_m"), [(0, 5.0), (6, 5.0), (3, 2.0)])
def test_an_impossible_scene_is_refused(data_root, people, far_m):
    with pytest.raises(ValueError, match="robot scene"):
        RobotScene(data_root, people=people, far_m=far_m)


def test_bench_on_the_robot_scene_runs_the_target_alone_at_smaller_inputs(data_root, monkeypatch,
                                                                          model_path):  # fmt: skip
    from follow.eval import bench

    model_path("pose/human-pose-estimation-0001.onnx")
    monkeypatch.setenv("FOLLOW_DATA_DIR", str(data_root))
    parser = argparse.ArgumentParser()
    bench.add_arguments(parser)
    args = parser.parse_args(["--scene", "robot", "--people", "1", "--frames", "8",
                              "--warmup", "2"])  # fmt: skip
    args.json = True
    result = bench.main(args)
    assert result["scene"].startswith("robot view, 1 people")
    shares = result["input_height_px_shares"]
    assert sum(shares.values()) == pytest.approx(1.0, abs=0.01)
    assert min(shares) < result["input_height_px"] == max(shares)
    assert result["people_in_view_max"] == 1


def test_each_bench_pass_starts_its_input_heights_afresh(data_root, model_path):
    """The stages and the runner each play the frames from the first on, on one
    detector: a pass sizes its first frames from its own, not from the last pass's."""
    from follow.config import Config
    from follow.eval import bench
    from follow.pose.detector import PoseDetector

    model_path("pose/human-pose-estimation-0001.onnx")
    scene = RobotScene(data_root, people=1, frame_count=7)
    config = Config().replace("pose", warmup_runs=0)
    detector = PoseDetector(config.pose)
    first, second = (bench.stage_times(config, detector, scene, 7, 0, True) for _ in range(2))
    # full height on the first frame and the 7th, whichever pass it is
    assert first["input_height_px_shares"] == second["input_height_px_shares"]
    assert first["input_height_px_shares"][368] == pytest.approx(2 / 7, abs=1e-3)


def test_pose_scene_compares_people_sized_with_fixed_input(data_root, monkeypatch, model_path):
    from follow.eval import pose_scene

    model_path("pose/human-pose-estimation-0001.onnx")
    monkeypatch.setenv("FOLLOW_DATA_DIR", str(data_root))
    parser = argparse.ArgumentParser()
    pose_scene.add_arguments(parser)
    args = parser.parse_args(["--scenes", "1:5", "--frames", "7"])
    args.json = True
    (row,) = pose_scene.main(args)["rows"]
    sized, fixed = row["people-sized"], row["fixed"]
    assert list(fixed["input_height_px_shares"]) == [368]
    # the target alone, 2.5 m away: full height on the first frame and every 6th
    assert sized["input_height_px_shares"][368] == pytest.approx(2 / 7, abs=1e-3)
    assert sized["neck"] == [1.0] and fixed["neck"] == [1.0]


def test_pose_scene_refuses_a_malformed_scene_list():
    from follow.eval.pose_scene import scene_list

    with pytest.raises(argparse.ArgumentTypeError, match="PEOPLE:FAR_M"):
        scene_list("five")
