"""BLAS limited to one thread: idle OpenBLAS workers must not spin on the network's cores."""

from __future__ import annotations

import numpy as np
from threadpoolctl import threadpool_info, threadpool_limits

from follow.blas_threads import limit_blas_threads


def _blas_threads() -> dict[str, int]:
    return {i["filepath"]: i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"}


def test_every_blas_library_of_numpy_and_scipy_runs_one_thread():
    before = {i["prefix"]: i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"}
    try:
        limit_blas_threads()
        after = _blas_threads()
        assert after, "numpy and scipy load at least one BLAS library"
        assert set(after.values()) == {1}
        a = np.random.default_rng(0).normal(size=(300, 300))
        np.testing.assert_allclose(a @ np.linalg.inv(a), np.eye(300), atol=1e-8)  # still right
    finally:
        threadpool_limits(limits=before)


def test_the_command_line_limits_blas_before_running_a_command(monkeypatch):
    from follow import cli

    calls = []
    monkeypatch.setattr("follow.blas_threads.limit_blas_threads", lambda: calls.append(1))
    assert cli.main(["models", "list"]) == 0
    assert calls == [1]
