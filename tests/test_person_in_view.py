"""Where a camera sees a standing person straight ahead, against the pinhole geometry
worked out by hand, and what that means for the following distance."""

import math

import pytest

from follow.camera import CameraModel, CameraPose
from follow.config import Config, ControlConfig
from follow.person_in_view import edge_margins_px, person_in_view, view_warnings
from follow.ukf.models import population_ankle_height_m


def _camera(height_m: float, pitch_deg: float = 0.0) -> CameraModel:
    return CameraModel.from_fov((640, 480), 70.0, CameraPose(height_m, math.radians(pitch_deg)))


def test_a_level_camera_sees_the_neck_and_ankles_from_where_the_pinhole_model_says():
    config = Config()
    camera = _camera(0.9)
    top, bottom = edge_margins_px(camera, config.pose)
    assert 2.0 < top < 8.0 and 8.0 < bottom < 30.0  # half / two cells of a 368-576 px input
    f, cy = camera.K[1, 1], camera.K[1, 2]
    neck_rise = config.tracker.default_neck_height_m - 0.9
    ankle_drop = 0.9 - population_ankle_height_m(config.tracker)
    views = person_in_view(camera, config)
    # the neck reaches the top margin, the ankles the bottom one
    assert views["neck"].from_m == pytest.approx(f * neck_rise / (cy + 0.5 - top), abs=0.011)
    assert views["ankles"].from_m == pytest.approx(f * ankle_drop / (479.5 - bottom - cy),
                                                   abs=0.011)  # fmt: skip
    for view in views.values():
        assert view.until_m == config.pose.far_person_distance_m
    assert view_warnings(views, config) == []


def test_the_following_distance_inside_the_blind_band_is_named():
    config = Config()
    low = person_in_view(_camera(0.5), config)  # neck above the image nearer than ~1.85 m
    [warning] = view_warnings(low, config)
    assert "following distance (1.8 m)" in warning and "neck is out of view" in warning
    high = person_in_view(_camera(1.5), config)  # feet below the image nearer than ~2.8 m
    assert high["ankles"].from_m > 2.5 and high["neck"].from_m < 1.5
    nearer = Config(control=ControlConfig(following_distance_m=1.5))
    [warning] = view_warnings(high, nearer)
    assert "ankles are out of view" in warning and "neck alone" in warning
    assert view_warnings(high, Config(control=ControlConfig(following_distance_m=3.0))) == []


def test_a_camera_pitched_steeply_down_loses_far_necks_and_says_so():
    config = Config()
    views = person_in_view(_camera(1.5, 50.0), config)
    assert views["neck"].from_m is None  # straight ahead, never in view
    assert views["ankles"].from_m is not None and views["ankles"].until_m < 5.0
    warnings = view_warnings(views, config)
    assert len(warnings) == 2 and "8 m away" in warnings[1] and "pitch the camera up" in warnings[1]


def test_a_camera_pitched_steeply_up_is_told_to_pitch_down():
    config = Config()
    views = person_in_view(_camera(0.8, -32.0), config)  # far necks sink below the image
    assert views["neck"].farthest_off == "below"
    warning = view_warnings(views, config)[-1]
    assert "8 m away" in warning and warning.endswith("pitch the camera down")


def test_a_camera_facing_backwards_is_told_so_not_to_pitch_up():
    config = Config()
    backwards = CameraModel.from_fov((640, 480), 70.0, CameraPose(0.9, 0.2, yaw_rad=3.14))
    views = person_in_view(backwards, config)
    assert views["neck"].from_m is None and views["ankles"].from_m is None
    [warning] = view_warnings(views, config)
    assert "never in view" in warning and "yaw_rad" in warning
    assert "pitch the camera up" not in warning


def test_no_margin_without_edge_dropping():
    config = Config()
    import dataclasses

    pose = dataclasses.replace(config.pose, top_edge_margin_cells=0.0, bottom_edge_margin_cells=0.0)
    assert edge_margins_px(_camera(0.9), pose) == (0.0, 0.0)
