"""An odometry jump (the base's pose reset to the origin, an estimator's yaw reset)
is not motion: the tracks stay where they stood relative to the robot, the target keeps
its track, and no pose between the two samples is made up."""

from __future__ import annotations

import numpy as np

from follow.camera import CameraModel, CameraPose
from follow.config import TrackerConfig
from follow.frames import base_to_odom, odom_to_base
from follow.odometry_buffer import OdometryBuffer, pose_jumped
from follow.types import Observation, Odometry
from follow.ukf.tracker import PeopleTracker

FPS = 15.0
CAMERA = CameraModel.from_fov((640, 360), 70.0, CameraPose(height_m=0.6, pitch_rad=0.02))


def _observe(robot: Odometry, person_odom, rng) -> Observation:
    cfg = TrackerConfig()
    x, y = odom_to_base(np.asarray(person_odom, dtype=float), robot)
    ankle_z = cfg.ankle_height_m + cfg.ankle_height_per_neck_height * 1.45
    uv = CAMERA.project(np.array([[x, y, 1.45], [x, y, ankle_z]])) + rng.normal(0, 1.0, (2, 2))
    return Observation(uv[0], uv[1])


def _tracked(robot: Odometry, rng) -> tuple[PeopleTracker, int]:
    """A tracker that has followed a person standing 3 m ahead of `robot` for 2 s."""
    tracker = PeopleTracker(CAMERA, TrackerConfig())
    person = base_to_odom(np.array([3.0, 0.0]), robot)
    for k in range(30):
        pose = Odometry(robot.x_m, robot.y_m, robot.yaw_rad, k / FPS)
        (track,) = tracker.update([_observe(pose, person, rng)], k / FPS, pose)
    return tracker, track.track_id


def test_a_reset_to_the_origin_keeps_the_person_where_they_stand():
    rng = np.random.default_rng(0)
    tracker, target = _tracked(Odometry(10.0, 5.0, 1.0, 0.0), rng)
    reset = Odometry(0.0, 0.0, 0.0, 30 / FPS)
    tracks = tracker.update([_observe(reset, (3.0, 0.0), rng)], 30 / FPS, reset)
    (track,) = tracks
    assert track.track_id == target and track.observation is not None
    assert np.linalg.norm(odom_to_base(track.position_m, reset) - [3.0, 0.0]) < 0.3


def test_a_yaw_reset_keeps_the_target_track():
    rng = np.random.default_rng(0)
    robot = Odometry(2.0, 1.0, 0.3, 0.0)
    tracker, target = _tracked(robot, rng)
    for k in range(30, 33):  # the heading steps by 0.5 rad; the robot did not turn
        jumped = Odometry(2.0, 1.0, 0.8, k / FPS)
        person = base_to_odom(np.array([3.0, 0.0]), jumped)
        tracks = tracker.update([_observe(jumped, person, rng)], k / FPS, jumped)
    assert [t.track_id for t in tracks if t.observation is not None] == [target]


def test_driving_is_no_jump_and_a_reset_is():
    start = Odometry(0.0, 0.0, 0.0, 0.0)
    assert not pose_jumped(start, Odometry(0.1, 0.0, 0.2, 0.1), 0.1)  # 1 m/s, 2 rad/s
    assert pose_jumped(start, Odometry(5.0, 0.0, 0.0, 0.1), 0.1)
    assert pose_jumped(start, Odometry(0.0, 0.0, 0.6, 0.1), 0.1)


def test_the_odometry_buffer_makes_up_no_pose_across_a_jump():
    buffer = OdometryBuffer(max_gap_s=0.2)
    buffer.add(Odometry(10.0, 5.0, 1.0, 0.0))
    buffer.add(Odometry(0.0, 0.0, 0.0, 0.1))  # reset to the origin
    assert (buffer.at(0.04).x_m, buffer.at(0.06).x_m) == (10.0, 0.0)  # the nearer sample
