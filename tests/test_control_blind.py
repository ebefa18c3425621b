"""Bounded blind driving: a target that is not seen drives the robot no further than
`max_blind_drive_s`, only turning toward its predicted bearing; a coasting track ages;
a target outside the camera's field of view gets no forward command."""

import math

import numpy as np
import pytest

from follow.camera import CameraModel, CameraPose
from follow.config import ConfigError, ControlConfig
from follow.control.controller import FollowingController
from follow.control.target import TargetMotion, ViewCone
from follow.pipeline import FrameResult, target_motion
from follow.types import Observation, Odometry, TargetEstimate, TargetStatus, TrackState

CFG = ControlConfig()
PERIOD = 1.0 / CFG.control_rate_hz


def _drive_then_lose(controller, xy=(4.0, 0.0), seen_s=2.0, blind_s=1.0):
    """Follow a target seen at `xy` for `seen_s`, then hold its prediction unobserved."""
    commands = []
    t = 0.0
    while t < seen_s:
        commands.append((t, controller.update(TargetMotion(np.array(xy), np.zeros(2), t), t)))
        t += PERIOD
    last_seen = t - PERIOD
    while t < seen_s + blind_s:
        blind = TargetMotion(np.array(xy), np.zeros(2), last_seen, observed=False)
        commands.append((t, controller.update(blind, t)))
        t += PERIOD
    return last_seen, commands


def test_forward_speed_falls_to_zero_within_the_blind_drive_bound():
    cfg = ControlConfig(max_blind_drive_s=0.4, target_timeout_s=0.8)
    last_seen, commands = _drive_then_lose(FollowingController(cfg))
    before = [c for t, c in commands if t <= last_seen]
    blind = [(t - last_seen, c) for t, c in commands if t > last_seen]
    assert before[-1].forward_mps == pytest.approx(cfg.max_forward_speed_mps)
    speeds = [c.forward_mps for _, c in blind]
    assert all(np.diff(speeds) <= 1e-12)  # never speeds up
    assert speeds[0] < before[-1].forward_mps
    for unseen_s, c in blind:
        assert c.forward_mps <= cfg.max_forward_speed_mps * max(0.0, 1 - unseen_s / 0.4) + 1e-9
        if unseen_s >= cfg.max_blind_drive_s:
            assert c.forward_mps == 0.0
    # Past target_timeout_s the target is lost: a full stop.
    assert all(c.is_stop for u, c in blind if u > cfg.target_timeout_s)


def test_blind_robot_only_turns_toward_the_predicted_bearing_at_the_search_rate():
    cfg = ControlConfig(max_blind_drive_s=0.3, target_timeout_s=1.0, search_yaw_rate_radps=0.3)
    last_seen, commands = _drive_then_lose(FollowingController(cfg), xy=(3.0, 1.5))
    blind = [(t - last_seen, c) for t, c in commands if t > last_seen]
    turning = [c for u, c in blind if 0.3 <= u <= 1.0]
    assert turning and all(c.forward_mps == 0.0 for c in turning)
    assert all(0.0 < c.yaw_rate_radps <= 0.3 + 1e-12 for c in turning)  # to the left


def test_a_coasting_track_ages_with_its_last_observation():
    # The track was last observed at 1.0 s; the frame at 1.7 s only predicts it.
    observation = Observation(np.array([320.0, 200.0]))
    seen = TrackState(4, np.array([4.0, 0.0, 0.0, 0.0, 1.45]), np.eye(5) * 0.01, True, 1.0,
                      observation=observation)  # fmt: skip
    coasting = TrackState(4, np.array([4.0, 0.0, 0.0, 0.0, 1.45]), np.eye(5) * 0.01, True, 1.0)
    estimate = TargetEstimate(TargetStatus.TRACKING, 4, {4: 0.8}, 1.7)

    def result(track, stamp):
        return FrameResult(0, stamp, Odometry.origin(stamp), [], [track], estimate)

    fresh = target_motion(result(seen, 1.0), Odometry.origin(1.0))
    assert fresh.observed and fresh.stamp_s == 1.0
    motion = target_motion(result(coasting, 1.7), Odometry.origin(1.7))
    assert not motion.observed and motion.stamp_s == 1.0  # not the frame's time
    controller = FollowingController(ControlConfig(target_timeout_s=0.5))
    assert controller.update(motion, 1.7).is_stop  # 0.7 s unseen > target_timeout_s


def test_view_cone_of_a_camera_and_no_forward_outside_it():
    camera = CameraModel.from_fov((640, 480), 70.0, CameraPose(height_m=1.0))
    view = ViewCone.from_camera(camera)
    assert math.degrees(view.horizontal_fov_rad) == pytest.approx(70.0, abs=0.2)
    assert view.contains(np.array([3.0, 0.0]))
    assert view.contains(np.array([3.0, 3.0 * math.tan(math.radians(30))]))
    assert not view.contains(np.array([3.0, 3.0 * math.tan(math.radians(40))]))
    assert not view.contains(np.array([-3.0, 0.0]))
    turned = ViewCone.from_camera(camera.with_pose(CameraPose(1.0, yaw_rad=math.radians(90))))
    assert turned.contains(np.array([0.0, 3.0])) and not turned.contains(np.array([3.0, 0.0]))
    # 4 m ahead and 45 degrees to the left: turning, but never driving toward it blind.
    cfg = ControlConfig(turn_in_place_bearing_rad=1.2)
    xy = np.array([4.0, 4.0])
    free = FollowingController(cfg)
    bounded = FollowingController(cfg, view=view)
    for i in range(30):
        t = i * PERIOD
        a = free.update(TargetMotion(xy, np.zeros(2), t), t)
        b = bounded.update(TargetMotion(xy, np.zeros(2), t), t)
    assert a.forward_mps > 0.1
    assert b.forward_mps == 0.0 and b.yaw_rate_radps > 0


@pytest.mark.parametrize(
    "key, value",
    [("max_blind_drive_s", 5.0), ("max_blind_drive_s", 0.0), ("watchdog_timeout_s", 1e9),
     # a frozen result is driven on unslowed until the watchdog: no longer than blind
     ("watchdog_timeout_s", 1.5), ("watchdog_timeout_s", -1.0),
     ("control_rate_hz", 1.0), ("missing_target_warn_s", float("nan")),
     # the configuration's other ranges hold for a ControlConfig made in code too: an
     # hour's search turned the robot an hour after a loss
     ("target_timeout_s", 60.0), ("search_duration_s", 3600.0),
     ("max_forward_speed_mps", 50.0)],
)  # fmt: skip
def test_safety_timeouts_are_bounded(key, value):
    with pytest.raises(ConfigError, match=key):
        FollowingController(ControlConfig(**{key: value}))


def test_blind_speed_falls_from_the_speed_at_the_last_observation_not_the_maximum():
    cfg = ControlConfig(max_blind_drive_s=0.5, target_timeout_s=1.0)
    near = (cfg.following_distance_m + 0.3, 0.0)  # a slow approach, well under the maximum
    last_seen, commands = _drive_then_lose(FollowingController(cfg), xy=near)
    v0 = [c for t, c in commands if t <= last_seen][-1].forward_mps
    assert 0.05 < v0 < 0.5 * cfg.max_forward_speed_mps
    blind = [(t - last_seen, c) for t, c in commands if t > last_seen]
    for unseen_s, c in blind:
        assert c.forward_mps <= v0 * max(0.0, 1 - unseen_s / cfg.max_blind_drive_s) + 1e-9
    driven_m = sum(c.forward_mps * PERIOD for _, c in blind)
    assert driven_m <= 0.5 * v0 * cfg.max_blind_drive_s + v0 * PERIOD


def test_after_a_loss_the_robot_does_not_speed_up_toward_a_target_it_does_not_see():
    c = FollowingController()
    last_seen, commands = _drive_then_lose(c, blind_s=0.0)
    assert commands[-1][1].forward_mps == pytest.approx(CFG.max_forward_speed_mps)
    t = last_seen + PERIOD
    assert c.update(None, t).is_stop  # lost: stopped at once
    for _ in range(5):  # the track's prediction comes back, still unseen
        t += PERIOD
        blind = TargetMotion(np.array([4.0, 0.0]), np.zeros(2), last_seen, observed=False)
        assert c.update(blind, t).forward_mps == 0.0


def test_backing_off_from_an_unseen_target_also_ends_within_the_blind_drive_bound():
    cfg = ControlConfig(allow_backing_off=True, max_blind_drive_s=0.3, target_timeout_s=1.0)
    too_close = (cfg.following_distance_m - 0.8, 0.0)
    last_seen, commands = _drive_then_lose(FollowingController(cfg), xy=too_close)
    v0 = [c for t, c in commands if t <= last_seen][-1].forward_mps
    assert v0 == pytest.approx(-cfg.max_backward_speed_mps)  # backing off while seen
    blind = [(t - last_seen, c) for t, c in commands if t > last_seen]
    speeds = [abs(c.forward_mps) for _, c in blind]
    assert all(np.diff(speeds) <= 1e-12)  # never speeds up, backward either
    for unseen_s, c in blind:
        assert abs(c.forward_mps) <= abs(v0) * max(0.0, 1 - unseen_s / 0.3) + 1e-9
        if unseen_s >= cfg.max_blind_drive_s:
            assert c.forward_mps == 0.0  # turning only


def test_blind_driving_never_starts_backing_off():
    cfg = ControlConfig(allow_backing_off=True, max_blind_drive_s=0.5, target_timeout_s=1.0)
    c = FollowingController(cfg)
    last_seen, commands = _drive_then_lose(c, blind_s=0.0)
    assert commands[-1][1].forward_mps > 0
    t = last_seen
    for _ in range(10):  # predicted (unseen) right in front of the robot
        t += PERIOD
        blind = TargetMotion(np.array([0.8, 0.0]), np.zeros(2), last_seen, observed=False)
        assert c.update(blind, t).forward_mps >= 0.0
