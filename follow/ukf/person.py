"""One tracked person: a filterpy unscented Kalman filter over `[x, y, vx, vy, h]`.

The filter is started from a neck+ankle observation (the ankle's ground point and the
neck height where the neck's ray meets the vertical through it) and then predicted with
the real time step and updated with either the 4-d neck+ankle or the 2-d neck-only
measurement model.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from filterpy.kalman import MerweScaledSigmaPoints, UnscentedKalmanFilter
from filterpy.kalman import unscented_transform as filterpy_unscented_transform

from follow.camera import CameraModel
from follow.config import TrackerConfig
from follow.ukf import unscented
from follow.ukf.models import (
    STATE_DIM,
    MeasurementModel,
    constant_velocity,
    population_ankle_height_m,
)

_MIN_EIGENVALUE = 1e-10
# ... and at least this share of the largest: an absolute floor drowns in rounding once a
# long-unseen state's variances reach ~1e10 (Cholesky then fails again on the repair).
_MIN_EIGENVALUE_RATIO = 1e-9


def make_psd(P: np.ndarray) -> np.ndarray:
    """Symmetrise P and lift eigenvalues that rounding pushed to (or below) zero."""
    P = 0.5 * (P + P.T)
    try:
        np.linalg.cholesky(P)
        return P
    except np.linalg.LinAlgError:
        w, V = np.linalg.eigh(P)
        floor = max(_MIN_EIGENVALUE, _MIN_EIGENVALUE_RATIO * float(np.abs(w).max()))
        P = (V * np.maximum(w, floor)) @ V.T
        return 0.5 * (P + P.T)


def _project_ray_onto_vertical(
    camera: CameraModel, pixel: np.ndarray, ground_xy: np.ndarray
) -> float:
    """Height where the ray through `pixel` passes the vertical line at `ground_xy` (base)."""
    ray = camera.pixel_rays_base(pixel)[0]
    c = camera.position_base
    horizontal = ray[:2] @ ray[:2]
    if horizontal < 1e-12:
        return float("nan")
    t = float((ground_xy - c[:2]) @ ray[:2]) / horizontal
    if t <= 0:
        return float("nan")
    return float(c[2] + t * ray[2])


def ground_and_height(
    camera: CameraModel, neck_px: np.ndarray, ankle_px: np.ndarray, ankle_height_m: float = 0.0
) -> np.ndarray:
    """(x, y, h) in `base` from a neck and an ankle pixel; NaN when the ankle has no ground
    point (on or above the horizon) or the neck's ray never passes over it."""
    ground = camera.back_project_to_plane(np.asarray(ankle_px, dtype=np.float64), ankle_height_m)
    if np.isnan(ground).any():
        return np.full(3, np.nan)
    h = _project_ray_onto_vertical(camera, np.asarray(neck_px, dtype=np.float64), ground[:2])
    return np.array([ground[0], ground[1], h])


def initial_state_base(
    camera: CameraModel,
    neck_px: np.ndarray,
    ankle_px: np.ndarray,
    neck_sigma_px: float,
    ankle_sigma_px: float,
    config: TrackerConfig,
) -> tuple[np.ndarray, np.ndarray] | None:
    """Mean and covariance of (x, y, h) in `base` seen at a neck and an ankle pixel.

    The covariance is the pixel noise carried through the back-projection (numerical
    Jacobian), then combined with the population prior on the neck height, which is what
    pins the range of a far person whose ankle pixel alone says little about it.
    Returns None for a geometrically impossible observation.
    """
    z = np.concatenate([neck_px, ankle_px]).astype(np.float64)

    def solve(zz: np.ndarray) -> np.ndarray:
        xyh = ground_and_height(camera, zz[:2], zz[2:], population_ankle_height_m(config))
        if np.isfinite(xyh).all():  # the ankle's height follows the person's: refine once
            ankle_m = config.ankle_height_m + config.ankle_height_per_neck_height * xyh[2]
            xyh = ground_and_height(camera, zz[:2], zz[2:], ankle_m)
        return xyh

    xyh = solve(z)
    if not np.isfinite(xyh).all():
        return None
    if not (config.min_neck_height_m <= xyh[2] <= config.max_neck_height_m):
        return None
    J = np.zeros((3, 4))
    step_px = 0.5
    for i in range(4):
        dz = np.zeros(4)
        dz[i] = step_px
        plus, minus = solve(z + dz), solve(z - dz)
        if not (np.isfinite(plus).all() and np.isfinite(minus).all()):
            return None
        J[:, i] = (plus - minus) / (2 * step_px)
    R = np.diag([neck_sigma_px**2] * 2 + [ankle_sigma_px**2] * 2)
    P = J @ R @ J.T + np.eye(3) * 1e-6
    # Linear fusion with the prior h ~ N(default_neck_height_m, init_height_std_m^2).
    s = P[2, 2] + config.init_height_std_m**2
    gain = P[:, 2] / s
    mean = xyh + gain * (config.default_neck_height_m - xyh[2])
    P = P - np.outer(gain, P[2, :])
    return mean, make_psd(P)


class PersonFilter:
    """The UKF of one person, in `odom`.

    A filterpy `UnscentedKalmanFilter` holds the state, the weights and the sigma points;
    `follow.ukf.unscented` runs its steps on all sigma points at once. `ukf.sigmas_f`
    always holds the sigma points of the current (x, P), and their projection into the
    image is kept for the frame's measurement model, so that gating, the update and the
    reported track share one projection.
    """

    def __init__(self, mean: np.ndarray, cov: np.ndarray, config: TrackerConfig):
        points = MerweScaledSigmaPoints(
            STATE_DIM,
            alpha=config.sigma_alpha,
            beta=config.sigma_beta,
            kappa=config.sigma_kappa,
            sqrt_method=unscented.cholesky_upper,
        )
        self.ukf = UnscentedKalmanFilter(
            dim_x=STATE_DIM, dim_z=4, dt=0.0, hx=None, fx=constant_velocity, points=points
        )
        self.ukf.x = np.asarray(mean, dtype=np.float64).copy()
        self.ukf.P = make_psd(np.asarray(cov, dtype=np.float64))
        self._projected_model: MeasurementModel | None = None
        self._projected: dict[bool, np.ndarray] = {}
        self._lift_at_mean_speed = config.gait_lift_at_mean_speed
        self._refresh_sigmas()

    def gait_speeds_mps(self) -> np.ndarray | None:
        """The speed each sigma point's gait lift is taken at: the mean's, for all of
        them (`gait_lift_at_mean_speed`), else None (each point's own). At each point's
        own, the velocity spread of a person standing still (about 0.7 m/s along the
        viewing ray) lifted their expected ankle by 40 % of `walking_ankle_lift_m` and
        they read about 4 % nearer than they stood."""
        if not self._lift_at_mean_speed:
            return None
        speed = float(np.hypot(self.ukf.x[2], self.ukf.x[3]))
        return np.full(len(self.ukf.sigmas_f), speed)

    @property
    def mean(self) -> np.ndarray:
        return self.ukf.x

    @property
    def cov(self) -> np.ndarray:
        return self.ukf.P

    def _refresh_sigmas(self) -> None:
        """Symmetrise P and draw its sigma points; the Cholesky factor they need is also
        the test for positive definiteness, so only a P that fails it is repaired (by
        `make_psd`) and factored again."""
        ukf = self.ukf
        ukf.P = 0.5 * (ukf.P + ukf.P.T)
        try:
            ukf.sigmas_f = unscented.merwe_sigma_points(ukf.points_fn, ukf.x, ukf.P)
        except np.linalg.LinAlgError:
            ukf.P = make_psd(ukf.P)
            ukf.sigmas_f = unscented.merwe_sigma_points(ukf.points_fn, ukf.x, ukf.P)
        self._projected_model, self._projected = None, {}

    def has_projection(self, model: MeasurementModel, with_ankle: bool = True) -> bool:
        """Whether the current sigma points' projection by `model` is kept."""
        return model is self._projected_model and with_ankle in self._projected

    def keep_projection(
        self, model: MeasurementModel, projected: np.ndarray, with_ankle: bool = True
    ) -> None:
        """Keep `projected`, the current sigma points projected by `model`, until they
        change (see `project_sigma_points`)."""
        if model is not self._projected_model:
            self._projected_model, self._projected = model, {}
        self._projected[with_ankle] = projected

    def _measurement_sigmas(self, model: MeasurementModel, with_ankle: bool) -> np.ndarray:
        """The sigma points projected by `model` (neck+ankle or neck only), computed once
        per set of sigma points and model."""
        if not self.has_projection(model, with_ankle):
            sigmas = self.ukf.sigmas_f
            projected = (model.neck_ankle(sigmas, self.gait_speeds_mps()) if with_ankle
                         else model.neck_only(sigmas))  # fmt: skip
            self.keep_projection(model, projected, with_ankle)
        return self._projected[with_ankle]

    def move_frame(self, rotation: np.ndarray, offset_m: np.ndarray) -> None:
        """Express the state in another ground frame: position -> rotation @ position +
        offset, velocity rotated alike, the covariance with them (the height stays)."""
        J = np.eye(5)
        J[0:2, 0:2] = J[2:4, 2:4] = rotation
        self.ukf.x = J @ self.ukf.x
        self.ukf.x[0:2] += offset_m
        self.ukf.P = J @ self.ukf.P @ J.T
        self._refresh_sigmas()

    def predict(self, dt_s: float, Q: np.ndarray) -> None:
        """Move forward by `dt_s` seconds (nothing to do for dt = 0)."""
        if dt_s > 0:
            unscented.predict(self.ukf, dt_s, Q, sigmas=self.ukf.sigmas_f)
            # Draw fresh sigma points from the prior, so that they include Q.
            self._refresh_sigmas()

    def expected_measurement(
        self, model: MeasurementModel, R: np.ndarray, with_ankle: bool
    ) -> tuple[np.ndarray, np.ndarray] | None:
        """Mean and covariance of the measurement by the unscented transform, or None when
        the person is behind the camera or part of the distribution projects to no pixel."""
        if not model.in_front(self.ukf.x):
            return None
        Z = self._measurement_sigmas(model, with_ankle)
        if not np.isfinite(Z).all():
            return None
        zp, S = filterpy_unscented_transform(Z, self.ukf.Wm, self.ukf.Wc, R)
        return zp, 0.5 * (S + S.T)

    def update(
        self, z: np.ndarray, R: np.ndarray, model: MeasurementModel, ankle_only: bool = False
    ) -> bool:
        """Fuse a 4-d neck+ankle or a 2-d neck-only measurement (with `ankle_only`, a 2-d
        ankle-only one); False (and no change) if the update would not give a finite
        state."""
        projected = self._measurement_sigmas(model, len(z) == 4 or ankle_only)
        if ankle_only:
            projected = projected[:, 2:4]
        if not np.isfinite(projected).all():
            return False
        try:
            x, P = unscented.update(self.ukf, np.asarray(z, dtype=np.float64), R, projected)
        except (np.linalg.LinAlgError, ValueError):
            return False
        if not (np.isfinite(x).all() and np.isfinite(P).all()):
            return False
        before = self.ukf.x, self.ukf.P, self.ukf.sigmas_f
        self.ukf.x, self.ukf.P = x, P
        try:
            self._refresh_sigmas()
        except np.linalg.LinAlgError:  # no sigma points for it: keep the state before
            self.ukf.x, self.ukf.P, self.ukf.sigmas_f = before
            self._projected_model, self._projected = None, {}
            return False
        return True


def project_sigma_points(filters: Sequence[PersonFilter], model: MeasurementModel) -> None:
    """Project the sigma points of every filter not yet projected by `model` to the neck
    and ankle pixels in one call (a frame's tracks share the camera and robot pose, and
    one call on all their points costs little more than one on a single track's)."""
    todo = [f for f in filters if not f.has_projection(model)]
    if not todo:
        return
    speeds = [f.gait_speeds_mps() for f in todo]
    projected = model.neck_ankle(
        np.vstack([f.ukf.sigmas_f for f in todo]),
        None if any(v is None for v in speeds) else np.concatenate(speeds),
    )
    for f, block in zip(todo, np.split(projected, len(todo)), strict=True):
        f.keep_projection(model, block)
