"""The planar transforms between `odom` and `base` agree with one another."""

import math

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from follow.frames import base_to_odom, odom_to_base, rotation_2d, vector_odom_to_base
from follow.types import Odometry

finite = st.floats(-50.0, 50.0, allow_nan=False)
angle = st.floats(-10.0, 10.0, allow_nan=False)


@given(finite, finite, angle, finite, finite)
def test_base_to_odom_is_the_rotation_then_the_robots_position(x, y, yaw, px, py):
    robot = Odometry(x, y, yaw, 0.0)
    point = np.array([px, py])
    expected = rotation_2d(yaw) @ point + [x, y]
    np.testing.assert_allclose(base_to_odom(point, robot), expected, atol=1e-9)
    np.testing.assert_allclose(odom_to_base(expected, robot), point, atol=1e-9)
    np.testing.assert_allclose(vector_odom_to_base(rotation_2d(yaw) @ point, robot), point,
                               atol=1e-9)  # fmt: skip


def test_a_quarter_turn_takes_x_to_y():
    np.testing.assert_allclose(rotation_2d(math.pi / 2) @ [1.0, 0.0], [0.0, 1.0], atol=1e-12)
