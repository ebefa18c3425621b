"""filterpy's unscented Kalman filter steps with the sigma points handled as one array.

`UnscentedKalmanFilter.predict` calls `fx` once per sigma point, `update` calls `hx` once
per sigma point and sums the cross-covariance point by point, and
`MerweScaledSigmaPoints.sigma_points` fills the points one row at a time behind
`scipy.linalg.cholesky`'s input checks. With a constant-velocity `fx` that takes all
points at once and a measurement model that projects them all at once, those Python
loops are most of a track's time per frame. The steps here are the same arithmetic, on
the filter's own state, weights and sigma point object and with filterpy's
`unscented_transform`; only the loops are gone.
"""

from __future__ import annotations

import numpy as np
from filterpy.kalman import MerweScaledSigmaPoints, UnscentedKalmanFilter
from filterpy.kalman import unscented_transform as filterpy_unscented_transform
from scipy.linalg.lapack import dpotrf


def cholesky_upper(a: np.ndarray) -> np.ndarray:
    """The upper Cholesky factor U (a = U.T @ U): `scipy.linalg.cholesky`'s default, from
    the same LAPACK call, without its per-call argument handling (a square float64
    matrix is all the sigma points ever pass)."""
    a = np.asarray(a, dtype=np.float64)
    if not np.isfinite(a).all():
        raise ValueError("array must not contain infs or NaNs")
    u, info = dpotrf(a, lower=0, clean=1, overwrite_a=0)
    if info > 0:
        raise np.linalg.LinAlgError(
            f"{info}-th leading minor of the array is not positive definite"
        )
    if info < 0:
        raise ValueError(f"LAPACK reported an illegal value in argument {-info} of POTRF")
    return u


def merwe_sigma_points(points: MerweScaledSigmaPoints, x: np.ndarray, P: np.ndarray) -> np.ndarray:
    """`points.sigma_points(x, P)` as one array expression: x, then x + each row of U,
    then x - each row of U, with U = points.sqrt((lambda + n) P) (the state must be a
    plain vector: `points.subtract` is np.subtract)."""
    n = points.n
    lambda_ = points.alpha**2 * (n + points.kappa) - n
    U = points.sqrt((lambda_ + n) * P)
    return np.vstack([x[None, :], x + U, x - U])


def predict(
    ukf: UnscentedKalmanFilter, dt: float, Q: np.ndarray, sigmas: np.ndarray | None = None
) -> None:
    """`ukf.predict(dt)` with process noise Q for an `fx` that moves an (N, n) array of
    states at once. `sigmas`: the sigma points of the current (x, P) when the caller has
    them already (they are drawn otherwise). Leaves the moved points in `ukf.sigmas_f`."""
    if sigmas is None:
        sigmas = merwe_sigma_points(ukf.points_fn, ukf.x, ukf.P)
    ukf.sigmas_f = ukf.fx(sigmas, dt)
    ukf.Q = Q
    ukf.x, ukf.P = filterpy_unscented_transform(ukf.sigmas_f, ukf.Wm, ukf.Wc, Q)


def update(
    ukf: UnscentedKalmanFilter, z: np.ndarray, R: np.ndarray, sigmas_h: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """The posterior (x, P) of `ukf.update(z, R)` given the measurement sigma points
    `sigmas_h` (hx of each row of `ukf.sigmas_f`); the filter itself is not changed, so
    the caller decides whether to keep the result. Raises LinAlgError for a singular
    innovation covariance, as filterpy does."""
    zp, S = filterpy_unscented_transform(sigmas_h, ukf.Wm, ukf.Wc, R)
    SI = ukf.inv(S)
    Pxz = (ukf.sigmas_f - ukf.x).T @ (ukf.Wc[:, None] * (sigmas_h - zp))
    K = Pxz @ SI
    x = ukf.x + K @ (z - zp)
    P = ukf.P - K @ (S @ K.T)
    return x, P
