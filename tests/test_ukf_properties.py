"""Property tests: whatever the observations, the tracker goes on and its covariances stay
symmetric positive definite."""

from __future__ import annotations

import logging

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from follow.camera import CameraModel, CameraPose
from follow.config import Config, ConfigError, TrackerConfig
from follow.types import InvalidInput, Observation, Odometry
from follow.ukf.direct import DirectBaseline
from follow.ukf.tracker import PeopleTracker

CAMERA = CameraModel.from_fov((640, 360), 70.0, CameraPose(height_m=0.6))

in_u = st.floats(-5.0, 645.0)
in_v = st.floats(-5.0, 365.0)
extreme = st.floats(-1e12, 1e12, allow_nan=False, allow_infinity=False)
pixel = st.one_of(st.tuples(in_u, in_v), st.tuples(extreme, extreme), st.tuples(in_u, extreme))
observation = st.builds(
    lambda neck, ankle: Observation(np.array(neck), None if ankle is None else np.array(ankle)),
    pixel,
    st.one_of(st.none(), pixel),
)
# Plausible people mixed in, so that tracks are born, updated and starved.
person = st.builds(
    lambda d, bearing, h, noise: _person(d, bearing, h, noise),
    st.floats(1.0, 40.0),
    st.floats(-0.7, 0.7),
    st.floats(0.2, 2.8),
    st.floats(-30.0, 30.0),
)


def _person(distance_m, bearing_rad, neck_m, noise_px):
    xy = distance_m * np.array([np.cos(bearing_rad), np.sin(bearing_rad)])
    cfg = TrackerConfig()
    ankle_z = cfg.ankle_height_m + cfg.ankle_height_per_neck_height * neck_m
    uv = CAMERA.project(np.array([[*xy, neck_m], [*xy, ankle_z]])) + noise_px
    if not np.isfinite(uv).all():
        return Observation(np.array([320.0, 100.0]), np.array([320.0, 300.0]))
    return Observation(uv[0], uv[1])


frame = st.tuples(
    st.lists(st.one_of(observation, person, person), max_size=5),
    st.floats(-0.5, 2.0),  # time step, sometimes backwards
    st.tuples(st.floats(-5, 5), st.floats(-5, 5), st.floats(-4, 4)),
)


def assert_spd(cov: np.ndarray) -> None:
    np.testing.assert_allclose(cov, cov.T, rtol=0, atol=1e-9 * max(1.0, np.abs(cov).max()))
    np.linalg.cholesky(cov)


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(frame, min_size=1, max_size=25))
def test_tracker_survives_any_observations(frames):
    logging.disable(logging.WARNING)
    try:
        tracker = PeopleTracker(CAMERA)
        baseline = DirectBaseline(CAMERA)
        stamp = 0.0
        for obs, dt, (x, y, yaw) in frames:
            stamp += dt
            robot = Odometry(x, y, yaw, stamp)
            states = tracker.update(obs, stamp, robot)
            assert len(baseline.update(obs, stamp, robot)) == len(obs)
            ids = [s.track_id for s in states]
            assert len(ids) == len(set(ids))
            for s in states:
                assert np.isfinite(s.mean).all()
                assert_spd(s.cov)
                if s.expected_neck_cov is not None:
                    assert_spd(s.expected_neck_cov + 1e-9 * np.eye(2))
    finally:
        logging.disable(logging.NOTSET)


@given(st.sampled_from([np.nan, np.inf, -np.inf]), st.integers(0, 3))
def test_non_finite_keypoints_never_reach_the_tracker(bad, index):
    values = np.array([320.0, 100.0, 320.0, 300.0])
    values[index] = bad
    with pytest.raises(InvalidInput):
        Observation(values[:2], values[2:])


def test_ids_are_never_reused():
    logging.disable(logging.WARNING)
    try:
        tracker = PeopleTracker(CAMERA)
        seen = []
        for k in range(40):
            # A person appears for two frames, then vanishes long enough to be dropped.
            obs = [_person(6.0, 0.1, 1.4, 0.0)] if k % 20 < 2 else []
            for s in tracker.update(obs, k * 0.1):
                if s.track_id not in seen:
                    seen.append(s.track_id)
        assert seen == [1, 2]
    finally:
        logging.disable(logging.NOTSET)


@settings(max_examples=60, deadline=None)
@given(st.floats(1e-300, 10.0), st.floats(-10.0, 10.0))
def test_every_sigma_point_spread_the_config_accepts_runs(alpha, kappa):
    """A sigma_alpha / sigma_kappa the configuration accepts gives a filter that runs; one
    that leaves the sigma points no spread (alpha^2 (5 + kappa) <= 0, or lost to rounding)
    is refused naming the keys, not met by a ZeroDivisionError at the first person."""
    try:
        config = Config().replace("tracker", sigma_alpha=alpha, sigma_kappa=kappa)
    except ConfigError as exc:
        assert "sigma_alpha" in str(exc) and "sigma_kappa" in str(exc)
        return
    logging.disable(logging.WARNING)
    try:
        tracker = PeopleTracker(CAMERA, config.tracker)
        for k in range(4):
            states = tracker.update([_person(6.0 - 0.1 * k, 0.1, 1.4, 0.0)], k * 0.1)
    finally:
        logging.disable(logging.NOTSET)
    assert states and all(np.isfinite(s.mean).all() for s in states)
