"""Shared test fixtures.

Tests that need the real models or data ask for them through the `model_path` and
`data_path` fixtures, which read `$FOLLOW_MODEL_DIR` / `$FOLLOW_DATA_DIR`. A missing
asset skips the test with the reason, or fails it when `FOLLOW_REQUIRE_ASSETS=1`.
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest


def _asset(env_var: str, relpath: str) -> Path:
    root = os.environ.get(env_var)
    if not root:
        reason = f"${env_var} is not set (needed for {relpath})"
    else:
        path = Path(root) / relpath
        if path.exists():
            return path
        reason = f"{relpath} not found under ${env_var}={root}"
    if os.environ.get("FOLLOW_REQUIRE_ASSETS") == "1":
        pytest.fail(f"required asset missing: {reason}")
    pytest.skip(reason)


@pytest.fixture(scope="session", autouse=True)
def isolated_cache(tmp_path_factory):
    """Tests never read or write the user's model and evaluation cache."""
    old = os.environ.get("FOLLOW_CACHE_DIR")
    os.environ["FOLLOW_CACHE_DIR"] = str(tmp_path_factory.mktemp("cache") / "models")
    yield
    if old is None:
        os.environ.pop("FOLLOW_CACHE_DIR", None)
    else:
        os.environ["FOLLOW_CACHE_DIR"] = old


@pytest.fixture
def model_path():
    """Callable: relative path under $FOLLOW_MODEL_DIR -> Path (or skip/fail)."""
    return lambda relpath: _asset("FOLLOW_MODEL_DIR", relpath)


@pytest.fixture
def data_path():
    """Callable: relative path under $FOLLOW_DATA_DIR -> Path (or skip/fail)."""
    return lambda relpath: _asset("FOLLOW_DATA_DIR", relpath)
