"""Polling helper for tests that wait on real sockets and threads."""

import time


def wait_for(predicate, timeout_s=2.0):
    """Whether `predicate()` became true within `timeout_s`, checked every 10 ms."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(0.01)
    return False
