"""Odometry jumps are told once, between consecutive odometry samples (`OdometryJumps`),
and the tracker moves its tracks by exactly those: a yaw reset small enough to pass for
a turn over a frame's interval (0.3 rad at 15 fps) still leaves the person where they
stand, and a reset both tests would see is applied once."""

from __future__ import annotations

import numpy as np
import pytest

from follow.camera import CameraModel, CameraPose
from follow.config import TrackerConfig
from follow.control.odometry import OdometryPolicy
from follow.frames import base_to_odom, odom_to_base
from follow.odometry_buffer import OdometryBuffer
from follow.pipeline import Perception, run_offline
from follow.types import Frame, Observation, Odometry
from follow.ukf.tracker import PeopleTracker

FPS = 15.0
ODOMETRY_HZ = 30.0
RESET_S = 3.0
PERSON_BASE_M = np.array([3.0, 0.3])  # where the person stands relative to the still robot
CAMERA = CameraModel.from_fov((640, 480), 70.0, CameraPose(height_m=1.0, pitch_rad=0.1))


def _observe(robot: Odometry, rng) -> Observation:
    """The person as the camera sees them: relative to the robot, whatever odom says."""
    cfg = TrackerConfig()
    x, y = PERSON_BASE_M
    ankle_z = cfg.ankle_height_m + cfg.ankle_height_per_neck_height * 1.45
    uv = CAMERA.project(np.array([[x, y, 1.45], [x, y, ankle_z]])) + rng.normal(0, 1.0, (2, 2))
    return Observation(uv[0], uv[1])


class _Base:
    """A still robot whose odometry jumps from `start` to `reset` at RESET_S."""

    def __init__(self, start: Odometry, reset: Odometry):
        self.start, self.reset, self.now_s = start, reset, 0.0

    def odometry(self) -> Odometry:
        pose = self.start if self.now_s < RESET_S else self.reset
        return Odometry(pose.x_m, pose.y_m, pose.yaw_rad, self.now_s)


def _sample_stamps(until_s: float) -> list[float]:
    return [k / ODOMETRY_HZ for k in range(int(until_s * ODOMETRY_HZ) + 1)]


def _follow_through_policy(start: Odometry, reset: Odometry, seconds: float = 5.0):
    """Frames at FPS, each with the policy's newest 30 Hz sample (as the threaded
    runner); yields (pose, tracks) per frame."""
    rng = np.random.default_rng(0)
    base = _Base(start, reset)
    policy = OdometryPolicy(base)
    tracker = PeopleTracker(CAMERA, TrackerConfig())
    samples = _sample_stamps(seconds)
    for k in range(int(seconds * FPS)):
        stamp_s = k / FPS
        for t in [s for s in samples if base.now_s < s <= stamp_s + 1e-9] or [stamp_s]:
            base.now_s = t
            robot = policy.sample()
        tracks = tracker.update([_observe(robot, rng)], stamp_s, robot, policy.jumps)
        yield robot, tracks


def _follow_through_buffer(start: Odometry, reset: Odometry, offset_s: float):
    """Frames at FPS (shifted by `offset_s`) with their poses from a buffer of 30 Hz
    samples (as a bag and the ROS node)."""
    rng = np.random.default_rng(0)
    base = _Base(start, reset)
    buffer = OdometryBuffer(max_gap_s=0.2)
    for t in _sample_stamps(6.0):
        base.now_s = t
        buffer.add(base.odometry())
    tracker = PeopleTracker(CAMERA, TrackerConfig())
    for k in range(int(5.0 * FPS)):
        stamp_s = k / FPS + offset_s
        robot = buffer.at(stamp_s)
        yield robot, tracker.update([_observe(robot, rng)], stamp_s, robot, buffer.jumps)


def _assert_kept(frames) -> None:
    """The person keeps one track, within 0.2 m of where they stand in odom."""
    ids = set()
    for robot, tracks in frames:
        ids |= {t.track_id for t in tracks}
        if robot.stamp_s >= RESET_S - 0.1:
            (track,) = tracks
            error_m = np.linalg.norm(track.position_m - base_to_odom(PERSON_BASE_M, robot))
            assert error_m < 0.2, f"{error_m:.2f} m off the person at {robot.stamp_s:.3f} s"
    assert ids == {1}


def test_a_small_yaw_reset_told_between_samples_keeps_the_person_and_the_track():
    # 0.3 rad: a jump between 30 Hz samples (bound 0.23 rad), a turn over 1/15 s (0.37)
    _assert_kept(_follow_through_policy(Odometry(0.0, 0.0, 0.0, 0.0), Odometry(0.0, 0.0, 0.3, 0.0)))


@pytest.mark.parametrize("offset_s", [0.0, 0.0567])  # 0.0567: a frame at 2.99 s, nearer
def test_a_small_yaw_reset_in_a_buffer_keeps_the_person_and_the_track(offset_s):  # the reset
    _assert_kept(_follow_through_buffer(Odometry(0.0, 0.0, 0.0, 0.0), Odometry(0.0, 0.0, 0.3, 0.0),
                                        offset_s))  # fmt: skip


def test_a_reset_both_tests_see_is_applied_once():
    # to the origin from 11 m away: a jump over the frame interval too
    _assert_kept(_follow_through_policy(Odometry(10.0, 5.0, 1.0, 0.0), Odometry(0.0, 0.0, 0.0, 0.0)))


def test_a_late_sample_between_two_is_no_jump():
    buffer = OdometryBuffer(max_gap_s=0.2)
    for k in range(31):  # turning at 2 rad/s: no jump between consecutive samples
        buffer.add(Odometry(0.0, 0.0, 2.0 * k / ODOMETRY_HZ, k / ODOMETRY_HZ))
    buffer.add(Odometry(0.0, 0.0, 2.0 * 0.85, 0.85))  # arrives after the one at 1 s
    assert buffer.jumps.between(-1.0, 2.0) == []
    assert not buffer.jumps.seen_near(-1.0, 2.0)


class _Identifier:
    def update(self, image, tracks, stamp_s, robot):
        return None


def test_offline_runs_give_the_tracker_the_policys_jumps():
    """run_offline with a base's policy (sampled at 30 Hz between frames, as the control
    loop does): the tracker follows the reset the policy told."""
    rng = np.random.default_rng(0)
    base = _Base(Odometry(0.0, 0.0, 0.0, 0.0), Odometry(0.0, 0.0, 0.3, 0.0))
    policy = OdometryPolicy(base)
    tracker = PeopleTracker(CAMERA, TrackerConfig())
    perception = Perception(lambda frame: [], lambda skeletons: [], tracker, _Identifier())

    def frames():
        for k in range(int(5.0 * FPS)):
            base.now_s = k / FPS - 0.5 / ODOMETRY_HZ
            policy.sample()  # the control loop's sample between two frames
            base.now_s = k / FPS
            observation = _observe(policy.sample(), rng)
            perception.to_observations = lambda skeletons, o=observation: [o]
            yield Frame(np.zeros((8, 8, 3), np.uint8), k / FPS)  # sampled again: the same

    out = run_offline(perception, frames(), odometry=policy)
    _assert_kept([(result.robot, result.tracks) for _frame, result, _command in out])


def test_a_pose_before_the_reset_sample_came_gets_the_jump_once():
    """A frame's pose taken before the sample after a reset arrived (the ROS node's wait
    ran out) is the one before it; the log later places the reset before that frame:
    the next frame's own test must not move the tracks by it again. (That one frame is
    placed in the wrong frame and may start a track of its own.)"""
    rng = np.random.default_rng(0)
    buffer = OdometryBuffer(max_gap_s=0.2)
    tracker = PeopleTracker(CAMERA, TrackerConfig())
    start, reset = Odometry(10.0, 5.0, 1.0, 0.0), Odometry(0.0, 0.0, 0.0, 0.0)
    for k in range(31):
        stamp_s = k / FPS
        buffer.add(Odometry(start.x_m, start.y_m, start.yaw_rad, stamp_s))
        robot = buffer.at(stamp_s)
        tracker.update([_observe(robot, rng)], stamp_s, robot, buffer.jumps)
    late = buffer.at(2.09)  # before the reset, with no sample after it yet
    buffer.add(Odometry(reset.x_m, reset.y_m, reset.yaw_rad, 2.1))  # the reset, late
    tracker.update([_observe(late, rng)], 2.09, late, buffer.jumps)
    for k in range(4):
        stamp_s = 2.1 + k / FPS
        buffer.add(Odometry(reset.x_m, reset.y_m, reset.yaw_rad, stamp_s))
        robot = buffer.at(stamp_s)
        tracks = tracker.update([_observe(robot, rng)], stamp_s, robot, buffer.jumps)
    (track,) = [t for t in tracks if t.observation is not None]
    assert track.track_id == 1
    assert np.linalg.norm(odom_to_base(track.position_m, robot) - PERSON_BASE_M) < 0.3


def test_the_threaded_runner_gives_the_tracker_its_policys_jumps():
    from follow.capture import LatestSlot
    from follow.config import ControlConfig
    from follow.control.base import NullBase
    from follow.control.controller import FollowingController
    from follow.pipeline import ControlLoop, ThreadedRunner

    base = NullBase()
    loop = ControlLoop(FollowingController(ControlConfig()), base, LatestSlot(), 15.0, 0.5)
    perception = Perception(lambda frame: [], lambda skeletons: [], None, _Identifier())
    ThreadedRunner(perception, loop, base).run(iter([]))
    assert perception.odometry_jumps is loop.odometry.jumps
