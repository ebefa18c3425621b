"""Gating, likelihood cost and global nearest neighbour."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import chi2, multivariate_normal

from follow.ukf.association import (
    InnovationGate,
    gate_mahalanobis_sq,
    global_nearest_neighbour,
    mahalanobis_cost,
)


def test_gate_is_the_chi_square_quantile_per_dimension():
    assert gate_mahalanobis_sq(2, 0.99) == pytest.approx(9.21, abs=0.01)
    assert gate_mahalanobis_sq(4, 0.99) == pytest.approx(13.28, abs=0.01)
    assert gate_mahalanobis_sq(4, 0.95) == pytest.approx(chi2.ppf(0.95, 4))


def test_cost_is_the_negative_log_likelihood():
    rng = np.random.default_rng(0)
    A = rng.normal(size=(4, 4))
    S = A @ A.T + np.eye(4)
    mean, z = rng.normal(size=4), rng.normal(size=4)
    d2, nll = InnovationGate(mean, S).cost(z)
    assert d2 == pytest.approx((z - mean) @ np.linalg.solve(S, z - mean))
    assert nll == pytest.approx(-multivariate_normal(mean, S).logpdf(z))
    assert mahalanobis_cost(z - mean, S) == pytest.approx((d2, nll))
    assert InnovationGate(mean, -S).cost(z) == (np.inf, np.inf)


def test_costs_score_many_measurements_at_once():
    rng = np.random.default_rng(1)
    A = rng.normal(size=(4, 4))
    S = A @ A.T + np.eye(4)
    mean, Z = rng.normal(size=4), rng.normal(size=(7, 4))
    gate = InnovationGate(mean, S)
    d2, nll = gate.costs(Z)
    assert d2.shape == nll.shape == (7,)
    np.testing.assert_allclose(d2, [(z - mean) @ np.linalg.solve(S, z - mean) for z in Z])
    np.testing.assert_allclose(nll, -multivariate_normal(mean, S).logpdf(Z))
    assert np.isinf(InnovationGate(mean, -S).costs(Z)).all()


def test_global_nearest_neighbour_minimises_the_total_and_respects_the_gate():
    # Greedy would give row 0 its best (column 0) and leave row 1 with a poor match.
    cost = np.array([[1.0, 2.0], [1.5, 10.0]])
    assert sorted(global_nearest_neighbour(cost)) == [(0, 1), (1, 0)]
    gated = np.array([[np.inf, 3.0], [np.inf, np.inf], [0.5, np.inf]])
    assert sorted(global_nearest_neighbour(gated)) == [(0, 1), (2, 0)]
    assert global_nearest_neighbour(np.full((2, 3), np.inf)) == []
    assert global_nearest_neighbour(np.zeros((0, 3))) == []
