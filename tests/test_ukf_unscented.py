"""The array-at-once UKF steps against filterpy's stock UnscentedKalmanFilter."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.linalg
from filterpy.kalman import MerweScaledSigmaPoints, UnscentedKalmanFilter

from follow.camera import CameraModel, CameraPose
from follow.config import TrackerConfig
from follow.types import Odometry
from follow.ukf import unscented
from follow.ukf.models import STATE_DIM, MeasurementModel, constant_velocity, process_noise
from follow.ukf.person import PersonFilter, make_psd, project_sigma_points

TOL = 1e-9


@pytest.fixture
def camera() -> CameraModel:
    return CameraModel.from_fov((640, 360), 70.0, CameraPose(height_m=0.6, pitch_rad=0.02))


def random_state(rng) -> tuple[np.ndarray, np.ndarray]:
    """A person 3-15 m ahead with a random, well-conditioned covariance."""
    x = np.array([rng.uniform(3, 15), rng.uniform(-3, 3), *rng.normal(0, 0.7, 2), 1.45])
    A = rng.normal(0, 1, (STATE_DIM, STATE_DIM)) * [0.3, 0.3, 0.2, 0.2, 0.05]
    return x, A @ A.T + 1e-3 * np.eye(STATE_DIM)


def stock_ukf(x, P, config: TrackerConfig) -> UnscentedKalmanFilter:
    points = MerweScaledSigmaPoints(
        STATE_DIM, alpha=config.sigma_alpha, beta=config.sigma_beta, kappa=config.sigma_kappa
    )
    ukf = UnscentedKalmanFilter(
        dim_x=STATE_DIM, dim_z=4, dt=0.0, hx=None, fx=constant_velocity, points=points
    )
    ukf.x, ukf.P = x.copy(), P.copy()
    return ukf


def test_cholesky_upper_is_scipys_factor():
    rng = np.random.default_rng(0)
    for _ in range(20):
        A = rng.normal(size=(5, 5))
        S = A @ A.T + 0.1 * np.eye(5)
        np.testing.assert_array_equal(unscented.cholesky_upper(S), scipy.linalg.cholesky(S))
    with pytest.raises(np.linalg.LinAlgError, match="not positive definite"):
        unscented.cholesky_upper(np.diag([1.0, -1.0, 1.0]))
    with pytest.raises(ValueError, match="infs or NaNs"):
        unscented.cholesky_upper(np.diag([1.0, np.nan]))


def test_sigma_points_are_filterpys():
    rng = np.random.default_rng(1)
    for alpha, kappa in ((1.0, 0.0), (0.3, 1.0), (0.8, 3.0 - STATE_DIM)):
        points = MerweScaledSigmaPoints(STATE_DIM, alpha=alpha, beta=2.0, kappa=kappa)
        x, P = random_state(rng)
        np.testing.assert_array_equal(
            unscented.merwe_sigma_points(points, x, P), points.sigma_points(x, P)
        )


def test_predict_and_update_match_filterpy(camera):
    """One predict and one update on random states, against filterpy calling fx and hx
    point by point."""
    rng = np.random.default_rng(2)
    cfg = TrackerConfig()
    for trial in range(50):
        x, P = random_state(rng)
        dt = rng.uniform(0.02, 0.5)
        Q = process_noise(dt, cfg.accel_noise_mps2, cfg.height_noise_mps)
        model = MeasurementModel(camera, Odometry(*rng.normal(0, 0.5, 3), 0.0), 0.08, 0.03)
        stock, ours = stock_ukf(x, P, cfg), stock_ukf(x, P, cfg)
        stock.Q = Q
        stock.predict(dt=dt)
        unscented.predict(ours, dt, Q)
        np.testing.assert_allclose(ours.x, stock.x, rtol=0, atol=TOL)
        np.testing.assert_allclose(ours.P, stock.P, rtol=0, atol=TOL)
        np.testing.assert_allclose(ours.sigmas_f, stock.sigmas_f, rtol=0, atol=TOL)

        with_ankle = trial % 3 != 0
        hx = model.hx_neck_ankle if with_ankle else model.hx_neck
        project = model.neck_ankle if with_ankle else model.neck_only
        z = hx(stock.x) + rng.normal(0, 3.0, 4 if with_ankle else 2)
        R = np.diag(rng.uniform(4, 30, len(z)))
        x_post, P_post = unscented.update(ours, z, R, project(ours.sigmas_f))
        stock.update(z, R=R, hx=hx)
        assert not np.allclose(x_post, ours.x)  # the update moved the state ...
        np.testing.assert_allclose(x_post, stock.x, rtol=0, atol=TOL)  # ... as filterpy's
        np.testing.assert_allclose(P_post, stock.P, rtol=0, atol=TOL)


class StockPersonFilter:
    """The person filter on filterpy's own predict and update (fx and hx called point by
    point, sigma points drawn by filterpy), the reference for PersonFilter."""

    def __init__(self, x, P, config):
        self.ukf = stock_ukf(x, make_psd(P), config)
        self.lift_at_mean_speed = config.gait_lift_at_mean_speed
        self.refresh()

    def refresh(self):
        self.ukf.P = make_psd(self.ukf.P)
        self.ukf.sigmas_f = self.ukf.points_fn.sigma_points(self.ukf.x, self.ukf.P)

    def predict(self, dt, Q):
        if dt > 0:
            self.ukf.Q = Q
            self.ukf.predict(dt=dt)
        self.refresh()

    def _mean_speed(self, n: int) -> np.ndarray | None:
        """The gait lift's speed for `n` points: the mean's with gait_lift_at_mean_speed,
        else None (each point's own)."""
        if not self.lift_at_mean_speed:
            return None
        return np.full(n, np.hypot(self.ukf.x[2], self.ukf.x[3]))

    def expected(self, model):
        Z = model.neck_ankle(self.ukf.sigmas_f, self._mean_speed(len(self.ukf.sigmas_f)))
        zp = self.ukf.Wm @ Z
        d = Z - zp
        return zp, d.T @ (self.ukf.Wc[:, None] * d)

    def update(self, z, R, model):
        speed = self._mean_speed(1)  # the prior mean's, for every point filterpy projects

        def hx_neck_ankle(state):
            return model.neck_ankle(state[None], speed)[0]

        self.ukf.update(z, R=R, hx=hx_neck_ankle if len(z) == 4 else model.hx_neck)
        self.refresh()


@pytest.mark.parametrize("lift_at_mean_speed", [False, True])
def test_person_filter_follows_filterpy_over_a_track(camera, lift_at_mean_speed):
    """Many frames of predict, gate (expected measurement), update and report on one
    measurement model per frame: PersonFilter's state and expected measurements stay
    with the stock filter's."""
    rng = np.random.default_rng(3)
    cfg = TrackerConfig(gait_lift_at_mean_speed=lift_at_mean_speed)
    x, P = random_state(rng)
    ours, stock = PersonFilter(x, P, cfg), StockPersonFilter(x, P, cfg)
    truth = np.array([x[0], x[1], 0.3, 0.05, x[4]])  # walking away, the robot behind
    zero = np.zeros((4, 4))
    t = 0.0
    for frame in range(60):
        dt = 0.0 if frame % 10 == 5 else rng.uniform(0.03, 0.2)
        t += dt
        truth = constant_velocity(truth, dt)
        Q = process_noise(dt, cfg.accel_noise_mps2, cfg.height_noise_mps)
        robot = Odometry(0.3 * t, 0.0, 0.05 * np.sin(t), t)
        model = MeasurementModel(camera, robot, 0.08, 0.03, 0.6, 0.3, 0.05)
        ours.predict(dt, Q)
        stock.predict(dt, Q)
        gate_mean, gate_cov = ours.expected_measurement(model, zero, True)
        np.testing.assert_allclose(gate_mean, stock.expected(model)[0], rtol=TOL, atol=TOL)
        if frame % 4 != 3:  # some frames without a measurement
            z = model.hx_neck_ankle(truth) + rng.normal(0, 2.0, 4)
            z = z if frame % 3 else z[:2]
            R = np.diag(np.full(len(z), 9.0))
            assert ours.update(z, R, model)
            stock.update(z, R, model)
        np.testing.assert_allclose(ours.mean, stock.ukf.x, rtol=0, atol=TOL)
        np.testing.assert_allclose(ours.cov, stock.ukf.P, rtol=0, atol=TOL)
        mean, cov = ours.expected_measurement(model, zero, True)  # after the update
        stock_mean, stock_cov = stock.expected(model)
        assert camera.in_image(mean[None, :2])[0]
        np.testing.assert_allclose(mean, stock_mean, rtol=TOL, atol=TOL)
        np.testing.assert_allclose(cov, stock_cov, rtol=TOL, atol=TOL)  # px^2, up to 1e4


def test_failed_update_leaves_the_filter_as_it_was(camera):
    cfg = TrackerConfig()
    x, P = random_state(np.random.default_rng(4))
    f = PersonFilter(x, P, cfg)
    model = MeasurementModel(camera, Odometry.origin())
    mean, cov, sigmas = f.mean.copy(), f.cov.copy(), f.ukf.sigmas_f.copy()
    singular = np.full((4, 4), np.nan)
    assert not f.update(model.hx_neck_ankle(x), singular, model)
    np.testing.assert_array_equal(f.mean, mean)
    np.testing.assert_array_equal(f.cov, cov)
    np.testing.assert_array_equal(f.ukf.sigmas_f, sigmas)


def test_projecting_many_tracks_at_once_is_projecting_each(camera):
    """A frame's tracks are projected in one call; each track's pixels are those it
    gets alone, also when another track's sigma points come near the camera."""
    rng = np.random.default_rng(5)
    cfg = TrackerConfig()
    model = MeasurementModel(camera, Odometry(0.5, 0.2, 0.1, 0.0), 0.08, 0.03, 0.6, 0.3, 0.05)
    filters = [PersonFilter(*random_state(rng), cfg) for _ in range(4)]
    near = np.array([0.8, 0.0, 0.0, 0.0, 1.45])  # its spread reaches behind the camera plane
    filters.append(PersonFilter(near, np.diag([0.5, 0.5, 0.1, 0.1, 0.01]), cfg))
    project_sigma_points(filters, model)
    assert all(f.has_projection(model) for f in filters)
    for f in filters:
        alone = model.neck_ankle(f.ukf.sigmas_f, f.gait_speeds_mps())  # its own mean speed
        np.testing.assert_array_equal(f.expected_measurement(model, np.zeros((4, 4)), True)[0],
                                      f.ukf.Wm @ alone)  # fmt: skip
        np.testing.assert_array_equal(f._measurement_sigmas(model, True), alone)
    assert not filters[0].has_projection(MeasurementModel(camera, Odometry.origin()))


def test_a_covariance_that_lost_definiteness_is_repaired_before_drawing_points():
    cfg = TrackerConfig()
    x, P = random_state(np.random.default_rng(6))
    f = PersonFilter(x, P, cfg)
    v = np.array([1.0, -1.0, 0.0, 0.0, 0.0]) / np.sqrt(2.0)
    broken = P - (v @ P @ v + 1e-9) * np.outer(v, v)  # one eigenvalue just below zero
    with pytest.raises(np.linalg.LinAlgError):
        np.linalg.cholesky(broken)
    f.ukf.P = broken
    f._refresh_sigmas()
    np.testing.assert_array_equal(f.cov, make_psd(broken))
    assert np.linalg.eigvalsh(f.cov)[0] > 0
    np.testing.assert_array_equal(f.ukf.sigmas_f, f.ukf.points_fn.sigma_points(x, f.cov))
