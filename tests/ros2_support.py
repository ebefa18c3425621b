"""What the ROS 2 tests share: a skip where rclpy does not import (a failure instead with
FOLLOW_REQUIRE_ROS2=1, as in CI), and an rclpy context on a DDS domain of its own."""

from __future__ import annotations

import os
import random

import pytest


def skip_without_ros2(exc: ImportError) -> None:
    """Called with the ImportError of a test module's ROS 2 imports."""
    if os.environ.get("FOLLOW_REQUIRE_ROS2") == "1":
        raise exc
    pytest.skip(f"rclpy not importable (the ros2 extra): {exc}", allow_module_level=True)


def isolated_rclpy():
    """rclpy initialised for the fixture's scope, on a random domain: nothing else on the
    network hears the test's node. Declare it with the scope a module needs."""
    import rclpy

    rclpy.init(domain_id=random.randint(100, 200))
    yield
    rclpy.shutdown()
