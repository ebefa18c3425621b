"""The simulated world: walkers, gait, robot motion, odometry, determinism."""

from __future__ import annotations

import numpy as np
import pytest

from follow.sim.people import NECK_HEIGHT_PER_STATURE, GaitConfig, Walker, random_walker
from follow.sim.world import SimCameraConfig, World, static_robot
from follow.types import L_ANKLE, NECK, R_ANKLE, Odometry


def test_walker_follows_its_route_with_stops():
    w = Walker(1, 1.7, [[0, 0], [3, 0], [3, 4]], speeds_mps=[1.0, 2.0], pauses_s=[1.5, 0.0])
    np.testing.assert_allclose(w.pose(0.0).position_m, [0, 0])
    np.testing.assert_allclose(w.pose(1.5).position_m, [1.5, 0])
    np.testing.assert_allclose(w.pose(1.5).velocity_mps, [1, 0])
    # Stopped at the corner for 1.5 s, then turns left and walks at 2 m/s.
    np.testing.assert_allclose(w.pose(3.5).position_m, [3, 0])
    np.testing.assert_allclose(w.pose(3.5).velocity_mps, [0, 0])
    np.testing.assert_allclose(w.pose(5.5).position_m, [3, 2])
    assert w.pose(5.5).heading_rad == pytest.approx(np.pi / 2)
    assert w.end_s == pytest.approx(3 + 1.5 + 2)
    np.testing.assert_allclose(w.pose(100.0).position_m, [3, 4])
    assert w.neck_height_m == pytest.approx(NECK_HEIGHT_PER_STATURE * 1.7)


def test_gait_moves_the_ankles_while_walking_and_not_while_standing():
    gait = GaitConfig(ankle_lift_m=0.1)
    w = Walker(1, 1.75, [[0, 0], [20, 0]], speeds_mps=1.2, start_s=2.0, gait=gait)
    times = np.arange(2.5, 12.0, 1 / 30)
    kp = np.array([w.keypoints_m(t) for t in times])
    body_x = np.array([w.pose(t).position_m[0] for t in times])
    forward = kp[:, [R_ANKLE, L_ANKLE], 0] - body_x[:, None]
    lift = kp[:, [R_ANKLE, L_ANKLE], 2] - w.ankle_height_m  # over the standing height
    assert 0.07 < w.ankle_height_m < 0.11  # the malleolus over a shoe sole
    assert forward.max() > 0.25 and forward.min() < -0.25  # back and forth
    assert lift.max() == pytest.approx(0.1, abs=0.01) and lift.min() == pytest.approx(0.0)
    assert (lift.min(axis=1) < 1e-9).all()  # one foot is always on the floor
    # The ankles' midpoint stays with the body on average.
    assert abs(forward.mean()) < 0.03
    np.testing.assert_allclose(kp[:, NECK, 2], w.neck_height_m)
    standing = w.keypoints_m(0.5)
    np.testing.assert_allclose(standing[[R_ANKLE, L_ANKLE], 2], w.ankle_height_m)
    assert np.ptp(standing[[R_ANKLE, L_ANKLE], 0]) < 1e-9


def test_random_walkers_are_people_and_seeded():
    a = [random_walker(i, np.random.default_rng(3), 30.0) for i in range(20)]
    b = [random_walker(i, np.random.default_rng(3), 30.0) for i in range(20)]
    assert all(1.5 <= w.stature_m <= 1.95 for w in a)
    for wa, wb in zip(a, b, strict=True):
        np.testing.assert_array_equal(wa.keypoints_m(7.3), wb.keypoints_m(7.3))
    walker = random_walker(1, np.random.default_rng(4), 60.0, range_m=(2.0, 25.0))
    ranges = [np.hypot(*walker.pose(t).position_m) for t in np.arange(0, 60, 0.5)]
    assert 2.0 <= min(ranges) and max(ranges) <= 25.0
    assert walker.end_s >= 60.0


def test_world_is_deterministic_and_gives_ground_truth():
    def frames(seed):
        rng = np.random.default_rng(seed)
        walkers = [random_walker(i + 1, rng, 10.0) for i in range(3)]
        world = World(walkers, seed=seed, odometry_drift_m_per_m=0.01)
        return list(world.run(20))

    a, b = frames(5), frames(5)
    assert [f.stamp_s for f in a] == pytest.approx([k / 15.0 for k in range(20)])
    for fa, fb in zip(a, b, strict=True):
        assert [p.person_id for p in fa.people] == [1, 2, 3]
        for pa, pb in zip(fa.people, fb.people, strict=True):
            np.testing.assert_array_equal(pa.keypoints_m, pb.keypoints_m)
            assert pa.neck_height_m == pytest.approx(NECK_HEIGHT_PER_STATURE * pa.stature_m)
    assert frames(6)[10].people[0].position_m.tolist() != a[10].people[0].position_m.tolist()
    assert a[3].person(2) is a[3].people[1] and a[3].person(9) is None


def test_robot_moved_from_outside_with_odometry():
    world = World([], SimCameraConfig(fps=10.0))
    first = world.step()
    assert first.robot == Odometry(0.0, 0.0, 0.0, 0.0)
    for k in range(1, 11):  # drive a quarter circle of radius 2 m
        yaw = k * np.pi / 20
        world.set_robot_pose(Odometry(2 * np.sin(yaw), 2 - 2 * np.cos(yaw), yaw, 0.0))
        frame = world.step()
    assert frame.robot.x_m == pytest.approx(2.0) and frame.robot.y_m == pytest.approx(2.0)
    assert frame.stamp_s == pytest.approx(1.0)
    # Without drift, odometry is exact.
    assert (frame.odometry.x_m, frame.odometry.y_m, frame.odometry.yaw_rad) == pytest.approx(
        (2.0, 2.0, np.pi / 2)
    )
    with pytest.raises(ValueError, match="finite"):
        world.set_robot_pose((np.nan, 0.0, 0.0))


def test_odometry_drifts_when_asked_and_scripted_paths_refuse_outside_poses():
    world = World([], robot_path=lambda t: (t, 0.0, 0.0), odometry_drift_m_per_m=0.05, seed=2)
    frames = list(world.run(150))
    assert frames[-1].robot.x_m == pytest.approx(149 / 15)
    assert 0.0 < abs(frames[-1].odometry.x_m - frames[-1].robot.x_m) < 1.0
    with pytest.raises(RuntimeError):
        world.set_robot_pose((0.0, 0.0, 0.0))
    still = World([], robot_path=static_robot(1.0, 2.0, 0.5))
    assert still.step().robot == Odometry(1.0, 2.0, 0.5, 0.0)


def test_walker_ids_are_unique_and_bad_routes_rejected():
    world = World([Walker(1, 1.7, [[1, 1]])])
    with pytest.raises(ValueError, match="already"):
        world.add_walker(Walker(1, 1.8, [[2, 2]]))
    with pytest.raises(ValueError, match="stature"):
        Walker(2, 3.5, [[0, 0]])
    with pytest.raises(ValueError, match="speeds"):
        Walker(2, 1.7, [[0, 0], [1, 0]], speeds_mps=0.0)


def test_camera_set_up_scales_to_the_detector():
    cfg = SimCameraConfig()
    full, det = cfg.camera(), cfg.detection_camera()
    assert full.image_size == (1920, 1080) and det.image_size == (640, 360)
    hfov = 2 * np.degrees(np.arctan(0.5 * det.image_size[0] / det.K[0, 0]))
    assert hfov == pytest.approx(70.0, abs=0.2)
    assert det.position_base[2] == pytest.approx(0.6)


def test_odometry_drift_is_per_metre_travelled_whatever_the_frame_rate():
    # 0.05 m of std per metre: after 4 m, independent errors per metre add up to
    # 0.05 * sqrt(4) = 0.1 m, at 15 frames per second as at 60.
    for fps in (15.0, 60.0):
        errors = []
        for seed in range(300):
            world = World([], SimCameraConfig(fps=fps), robot_path=lambda t: (t, 0.0, 0.0),
                          seed=seed, odometry_drift_m_per_m=0.05)  # fmt: skip
            last = list(world.run(int(4 * fps) + 1))[-1]
            errors.append(last.odometry.x_m - last.robot.x_m)
        assert np.std(errors) == pytest.approx(0.1, rel=0.15), fps
        errors = []  # and 0.05 rad per radian turned
        for seed in range(300):
            world = World([], SimCameraConfig(fps=fps), robot_path=lambda t: (0.0, 0.0, t / 2),
                          seed=seed, odometry_drift_rad_per_rad=0.05)  # fmt: skip
            last = list(world.run(int(8 * fps) + 1))[-1]
            errors.append(last.odometry.yaw_rad - last.robot.yaw_rad)
        assert np.std(errors) == pytest.approx(0.1, rel=0.15), fps
