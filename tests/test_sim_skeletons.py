"""The synthetic skeleton detector and the neck/ankle extraction."""

from __future__ import annotations

import numpy as np
import pytest

from follow.frames import odom_to_base
from follow.sim.people import Walker
from follow.sim.skeletons import (
    DetectorNoiseConfig,
    SyntheticDetector,
    neck_ankle_observation,
    observations_with_ids,
)
from follow.sim.world import SimCameraConfig, World
from follow.types import L_ANKLE, NECK, NUM_KEYPOINTS, R_ANKLE, Odometry, Skeleton

NOISELESS = DetectorNoiseConfig(
    neck_sigma_px=0.0, ankle_sigma_px=0.0, joint_sigma_px=0.0, miss_probability=0.0
)


def one_frame(walkers, noise=NOISELESS, robot=(0.0, 0.0, 0.0), seed=0, pitch_rad=0.0):
    world = World(walkers, SimCameraConfig(pitch_rad=pitch_rad))
    world.set_robot_pose(robot)
    frame = world.step()
    camera = world.camera_config.detection_camera()
    return frame, camera, SyntheticDetector(camera, noise, seed=seed).detect(frame)


def test_noiseless_detections_are_the_projected_joints():
    robot = (1.0, -0.5, 0.3)
    frame, camera, dets = one_frame([Walker(4, 1.8, [[8.0, 2.0]])], robot=robot)
    assert [d.person_id for d in dets] == [4]
    truth = frame.people[0].keypoints_m
    base = np.column_stack([odom_to_base(truth[:, :2], Odometry(*robot, 0.0)), truth[:, 2]])
    np.testing.assert_allclose(dets[0].skeleton.keypoints_px, camera.project(base), atol=1e-9)
    assert (dets[0].skeleton.confidences > 0).all()


def test_pixel_noise_and_misses_have_the_configured_size():
    noise = DetectorNoiseConfig(neck_sigma_px=2.0, ankle_sigma_px=3.0, occlusion=False)
    world = World([Walker(1, 1.7, [[10.0, 0.0]])], SimCameraConfig())
    camera = world.camera_config.detection_camera()
    detector = SyntheticDetector(camera, noise, seed=1)
    frame = world.step()
    _, _, exact = one_frame([Walker(1, 1.7, [[10.0, 0.0]])])
    ideal = exact[0].skeleton.keypoints_px
    neck_err, ankle_err, missing = [], [], []
    for _ in range(600):
        kp = detector.detect(frame)[0].skeleton.keypoints_px
        neck_err.append(kp[NECK] - ideal[NECK])
        ankle_err.append(kp[R_ANKLE] - ideal[R_ANKLE])
        missing.append(np.isnan(kp[:, 0]))
    assert np.nanstd(neck_err) == pytest.approx(2.0, rel=0.15)
    assert np.nanstd(ankle_err) == pytest.approx(3.0, rel=0.15)
    assert np.mean(missing) == pytest.approx(0.05, abs=0.015)


def test_ankles_are_lost_outside_the_image_and_near_its_border():
    # 2.5 m away the feet are below the bottom of a camera tilted up by 0.2 rad.
    _, _, close = one_frame([Walker(1, 1.7, [[2.5, 0.0]])], pitch_rad=-0.2)
    kp = close[0].skeleton.keypoints_px
    assert np.isnan(kp[[R_ANKLE, L_ANKLE]]).all() and not np.isnan(kp[NECK]).any()
    assert neck_ankle_observation(close[0].skeleton).ankle_px is None
    # Far enough to be fully seen, but the ankles are within the border margin.
    margin = DetectorNoiseConfig(
        neck_sigma_px=0.0, ankle_sigma_px=0.0, joint_sigma_px=0.0, miss_probability=0.0,
        ankle_border_margin_px=80.0,
    )  # fmt: skip
    _, camera, near_border = one_frame([Walker(1, 1.7, [[2.1, 0.0]])], noise=margin)
    _, _, plain = one_frame([Walker(1, 1.7, [[2.1, 0.0]])])
    ankle_v = plain[0].skeleton.keypoints_px[R_ANKLE, 1]
    assert camera.image_size[1] - 80 < ankle_v < camera.image_size[1]
    assert np.isnan(near_border[0].skeleton.keypoints_px[[R_ANKLE, L_ANKLE]]).all()
    # A person behind the camera is not detected at all.
    _, _, behind = one_frame([Walker(1, 1.7, [[-5.0, 0.0]])])
    assert behind == []


def test_a_person_behind_another_is_occluded():
    front, back = Walker(1, 1.8, [[5.0, 0.0]]), Walker(2, 1.7, [[9.0, 0.05]])
    _, _, dets = one_frame([back, front])
    assert [d.person_id for d in dets] == [1]  # nearest first; the other is hidden
    side = Walker(2, 1.7, [[9.0, 2.5]])
    _, _, dets = one_frame([side, front])
    assert sorted(d.person_id for d in dets) == [1, 2]
    no_occlusion = DetectorNoiseConfig(
        neck_sigma_px=0.0, ankle_sigma_px=0.0, joint_sigma_px=0.0, miss_probability=0.0,
        occlusion=False,
    )  # fmt: skip
    _, _, dets = one_frame([back, front], noise=no_occlusion)
    assert sorted(d.person_id for d in dets) == [1, 2]


def _skeleton(neck=True, r_ankle=True, l_ankle=True):
    kp = np.full((NUM_KEYPOINTS, 2), np.nan)
    conf = np.zeros(NUM_KEYPOINTS)
    for index, present, xy in ((NECK, neck, (100, 50)), (R_ANKLE, r_ankle, (90, 200)),
                               (L_ANKLE, l_ankle, (110, 210))):  # fmt: skip
        if present:
            kp[index], conf[index] = xy, 0.8
    return Skeleton(kp, conf)


def test_neck_and_ankle_extraction_rule():
    both = neck_ankle_observation(_skeleton())
    np.testing.assert_allclose(both.neck_px, [100, 50])
    np.testing.assert_allclose(both.ankle_px, [100, 205])
    np.testing.assert_allclose(neck_ankle_observation(_skeleton(l_ankle=False)).ankle_px, [90, 200])
    np.testing.assert_allclose(
        neck_ankle_observation(_skeleton(r_ankle=False)).ankle_px, [110, 210]
    )
    assert neck_ankle_observation(_skeleton(r_ankle=False, l_ankle=False)).ankle_px is None
    assert neck_ankle_observation(_skeleton(neck=False)) is None
    assert neck_ankle_observation(_skeleton(), min_confidence=0.9) is None


def test_observations_carry_their_people():
    walkers = [Walker(3, 1.7, [[6.0, 1.5]]), Walker(8, 1.6, [[12.0, -2.0]])]
    _, _, dets = one_frame(walkers)
    observations, ids = observations_with_ids(dets)
    assert ids == [3, 8]
    assert all(o.has_ankle for o in observations)
    assert observations[0].skeleton is dets[0].skeleton
