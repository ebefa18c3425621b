"""Skeleton -> observation rules: neck required, ankle averaging, border flag."""

from __future__ import annotations

import numpy as np

from follow.config import PoseConfig
from follow.pose.observations import skeletons_to_observations
from follow.types import L_ANKLE, NECK, R_ANKLE, Skeleton

CONFIG = PoseConfig(keypoint_min_confidence=0.2, border_margin_px=4.0)


def skeleton(points: dict[int, tuple[float, float, float]]) -> Skeleton:
    kps = np.full((18, 2), np.nan)
    conf = np.zeros(18)
    for k, (x, y, c) in points.items():
        kps[k] = (x, y)
        conf[k] = c
    return Skeleton(kps, conf)


def test_both_ankles_are_averaged():
    s = skeleton({NECK: (100, 50, 0.9), R_ANKLE: (90, 200, 0.8), L_ANKLE: (110, 204, 0.5)})
    (obs,) = skeletons_to_observations([s], (640, 480), CONFIG)
    assert np.allclose(obs.neck_px, (100, 50))
    assert np.allclose(obs.ankle_px, (100, 202))
    assert obs.skeleton is s and not obs.touches_border


def test_the_single_confident_ankle_is_used():
    s = skeleton({NECK: (100, 50, 0.9), R_ANKLE: (90, 200, 0.1), L_ANKLE: (110, 204, 0.5)})
    (obs,) = skeletons_to_observations([s], (640, 480), CONFIG)
    assert np.allclose(obs.ankle_px, (110, 204))


def test_no_confident_ankle_gives_none():
    s = skeleton({NECK: (100, 50, 0.9), R_ANKLE: (90, 200, 0.1)})
    (obs,) = skeletons_to_observations([s], (640, 480), CONFIG)
    assert obs.ankle_px is None and not obs.has_ankle


def test_skeletons_without_a_confident_neck_are_dropped():
    weak_neck = skeleton({NECK: (100, 50, 0.1), R_ANKLE: (90, 200, 0.9)})
    no_neck = skeleton({R_ANKLE: (90, 200, 0.9), L_ANKLE: (95, 200, 0.9)})
    good = skeleton({NECK: (300, 60, 0.5)})
    obs = skeletons_to_observations([weak_neck, no_neck, good], (640, 480), CONFIG)
    assert len(obs) == 1 and np.allclose(obs[0].neck_px, (300, 60))


def test_border_flag_when_any_keypoint_is_near_an_edge():
    inside = skeleton({NECK: (100, 50, 0.9), R_ANKLE: (100, 474, 0.9)})
    at_bottom = skeleton({NECK: (100, 50, 0.9), R_ANKLE: (100, 476, 0.9)})
    at_left = skeleton({NECK: (3, 50, 0.9)})
    flags = [o.touches_border for o in skeletons_to_observations(
        [inside, at_bottom, at_left], (640, 480), CONFIG)]  # fmt: skip
    assert flags == [False, True, True]
