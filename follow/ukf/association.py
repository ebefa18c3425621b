"""Observation-to-track association: Mahalanobis gate, likelihood cost, global nearest
neighbour."""

from __future__ import annotations

from functools import lru_cache

import numpy as np
from scipy.optimize import linear_sum_assignment
from scipy.stats import chi2

# Cost standing in for "not allowed" in the assignment problem.
_FORBIDDEN = 1e12


@lru_cache(maxsize=64)
def gate_mahalanobis_sq(dim: int, quantile: float) -> float:
    """Squared Mahalanobis distance below which an observation of `dim` dimensions may
    belong to a track (the chi-square quantile)."""
    return float(chi2.ppf(quantile, dim))


class InnovationGate:
    """A predicted measurement's mean and covariance, factored once for scoring many
    observations against it."""

    def __init__(self, mean: np.ndarray, cov: np.ndarray):
        self.mean = np.asarray(mean, dtype=np.float64)
        try:
            self._L = np.linalg.cholesky(cov)
        except np.linalg.LinAlgError:
            self._L = None
            return
        self._log_norm = float(np.log(np.diag(self._L)).sum()) + 0.5 * len(self.mean) * np.log(
            2.0 * np.pi
        )

    def cost(self, z: np.ndarray) -> tuple[float, float]:
        """(squared Mahalanobis distance, negative log-likelihood) of a measurement; (inf,
        inf) when the covariance is not positive definite."""
        d2, nll = self.costs(np.asarray(z, dtype=np.float64)[None, :])
        return float(d2[0]), float(nll[0])

    def costs(self, Z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """`cost` of each row of Z (m, k), with one triangular solve for them all."""
        m = len(Z)
        if self._L is None:
            return np.full(m, np.inf), np.full(m, np.inf)
        w = np.linalg.solve(self._L, (Z - self.mean).T)
        d2 = np.einsum("km,km->m", w, w)
        return d2, 0.5 * d2 + self._log_norm


def mahalanobis_cost(innovation: np.ndarray, S: np.ndarray) -> tuple[float, float]:
    """(squared Mahalanobis distance, negative log-likelihood) of an innovation with
    covariance S; (inf, inf) when S is not positive definite."""
    return InnovationGate(np.zeros(len(innovation)), S).cost(np.asarray(innovation))


def global_nearest_neighbour(cost: np.ndarray) -> list[tuple[int, int]]:
    """Pairs (row, column) minimising the total cost; entries that are inf are never
    paired."""
    if cost.size == 0:
        return []
    finite = np.isfinite(cost)
    if not finite.any():
        return []
    work = np.where(finite, cost, _FORBIDDEN)
    rows, cols = linear_sum_assignment(work)
    return [(int(r), int(c)) for r, c in zip(rows, cols, strict=True) if finite[r, c]]
