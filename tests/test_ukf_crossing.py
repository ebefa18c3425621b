"""Association through people crossing in the simulated world."""

from __future__ import annotations

import logging
from collections import Counter

import numpy as np
import pytest

from follow.config import TrackerConfig
from follow.sim.people import Walker
from follow.sim.skeletons import SyntheticDetector, observations_with_ids
from follow.sim.world import SimCameraConfig, World, turning_robot
from follow.ukf.tracker import PeopleTracker


def run_crossing(nearer_m: float, farther_m: float, robot_path=None, seconds: float = 9.0):
    """Two people walk across in front of the robot in opposite directions and pass each
    other in the middle of the image; returns, per person, the track ids given to their
    observations before and after the crossing."""
    a = Walker(1, 1.80, [[nearer_m, 3.0], [nearer_m, -3.0]], 0.9, start_s=1.0)
    b = Walker(2, 1.60, [[farther_m, -3.4], [farther_m, 3.4]], 1.0, start_s=1.0)
    world = World([a, b], SimCameraConfig(), robot_path=robot_path, seed=7)
    camera = world.camera_config.detection_camera()
    detector = SyntheticDetector(camera, seed=8)
    tracker = PeopleTracker(camera)
    order_rng = np.random.default_rng(9)
    crossing_s = 1.0 + 3.0 / 0.95
    ids = {
        1: {"before": Counter(), "after": Counter()},
        2: {"before": Counter(), "after": Counter()},
    }
    for frame in world.run(int(seconds * world.camera_config.fps)):
        detections = detector.detect(frame)
        order_rng.shuffle(detections)  # the detector's order must not matter
        observations, owners = observations_with_ids(detections)
        owner = {id(o): pid for o, pid in zip(observations, owners, strict=True)}
        for state in tracker.update(observations, frame.stamp_s, frame.odometry):
            if state.observation is None or not state.confirmed:
                continue
            when = "before" if frame.stamp_s < crossing_s - 1.0 else None
            when = "after" if frame.stamp_s > crossing_s + 1.0 else when
            if when:
                ids[owner[id(state.observation)]][when][state.track_id] += 1
    return ids


def dominant(counter: Counter) -> int:
    ((track_id, n),) = counter.most_common(1)
    assert n >= 0.8 * sum(counter.values()), f"mixed ids {dict(counter)}"
    return track_id


@pytest.mark.parametrize("nearer_m, farther_m", [(6.0, 8.0), (9.0, 10.0)])
def test_identities_survive_two_people_crossing(nearer_m, farther_m):
    logging.disable(logging.WARNING)
    try:
        ids = run_crossing(nearer_m, farther_m)
    finally:
        logging.disable(logging.NOTSET)
    a_before, a_after = dominant(ids[1]["before"]), dominant(ids[1]["after"])
    b_before, b_after = dominant(ids[2]["before"]), dominant(ids[2]["after"])
    assert a_before != b_before
    assert (a_after, b_after) == (a_before, b_before)


def test_identities_survive_a_crossing_seen_from_a_turning_robot():
    logging.disable(logging.WARNING)
    try:
        ids = run_crossing(6.0, 8.0, robot_path=turning_robot(0.25, 4.0))
    finally:
        logging.disable(logging.NOTSET)
    assert dominant(ids[1]["before"]) == dominant(ids[1]["after"])
    assert dominant(ids[2]["before"]) == dominant(ids[2]["after"])
    assert dominant(ids[1]["after"]) != dominant(ids[2]["after"])


def count_tracks_for_a_near_walker(config: TrackerConfig) -> int:
    walker = Walker(1, 1.75, [[3.0, -1.5], [6.0, 1.5], [3.5, 1.0], [3.0, -1.5]], 1.2)
    world = World([walker], SimCameraConfig(), seed=3)
    camera = world.camera_config.detection_camera()
    detector = SyntheticDetector(camera, seed=4)
    tracker = PeopleTracker(camera, config)
    ids = set()
    for frame in world.run(int(12 * world.camera_config.fps)):
        observations, _ = observations_with_ids(detector.detect(frame))
        ids.update(s.track_id for s in tracker.update(observations, frame.stamp_s, frame.odometry))
    return len(ids)


def test_a_near_walker_keeps_one_track_despite_the_gait():
    # Near the camera the swinging, lifting ankles move many pixels; the measurement
    # noise must allow for it or the walker falls out of its own gate again and again.
    logging.disable(logging.WARNING)
    try:
        assert count_tracks_for_a_near_walker(TrackerConfig()) == 1
        pixel_noise_only = TrackerConfig(
            neck_position_noise_m=0.0,
            ankle_position_noise_m=0.0,
            single_ankle_position_noise_m=0.0,
        )
        assert count_tracks_for_a_near_walker(pixel_noise_only) > 1
    finally:
        logging.disable(logging.NOTSET)
