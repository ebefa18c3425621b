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


@pytest.fixture
def model_path():
    """Callable: relative path under $FOLLOW_MODEL_DIR -> Path (or skip/fail)."""
    return lambda relpath: _asset("FOLLOW_MODEL_DIR", relpath)


@pytest.fixture
def data_path():
    """Callable: relative path under $FOLLOW_DATA_DIR -> Path (or skip/fail)."""
    return lambda relpath: _asset("FOLLOW_DATA_DIR", relpath)
