"""Planar transforms between the fixed `odom` frame and the robot's `base` frame."""

from __future__ import annotations

import numpy as np

from follow.types import Odometry


def odom_to_base(points_xy: np.ndarray, robot: Odometry) -> np.ndarray:
    """Ground points (..., 2) given in `odom` expressed in the robot's `base` frame."""
    return vector_odom_to_base(
        np.asarray(points_xy, dtype=np.float64) - (robot.x_m, robot.y_m), robot
    )


def base_to_odom(points_xy: np.ndarray, robot: Odometry) -> np.ndarray:
    """Ground points (..., 2) given in `base` expressed in `odom`."""
    c, s = np.cos(robot.yaw_rad), np.sin(robot.yaw_rad)
    p = np.asarray(points_xy, dtype=np.float64)
    return np.stack(
        [robot.x_m + c * p[..., 0] - s * p[..., 1], robot.y_m + s * p[..., 0] + c * p[..., 1]],
        axis=-1,
    )


def vector_odom_to_base(vectors_xy: np.ndarray, robot: Odometry) -> np.ndarray:
    """Free vectors (velocities) from `odom` to `base`: rotation only."""
    c, s = np.cos(robot.yaw_rad), np.sin(robot.yaw_rad)
    v = np.asarray(vectors_xy, dtype=np.float64)
    return np.stack([c * v[..., 0] + s * v[..., 1], -s * v[..., 0] + c * v[..., 1]], axis=-1)


def rotation_2d(angle_rad: float) -> np.ndarray:
    """The 2x2 matrix turning ground vectors by `angle_rad` (counter-clockwise, seen from
    above: x toward y)."""
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    return np.array([[c, -s], [s, c]])


def odom_jump_transform(before: Odometry, after: Odometry) -> tuple[np.ndarray, np.ndarray]:
    """(rotation 2x2, offset 2) that carry a point of the old `odom` frame into the new one
    when the robot's pose jumped from `before` to `after` (an odometry reset) while the
    robot itself stood still: the point keeps where it stood relative to the robot."""
    rotation = rotation_2d(after.yaw_rad - before.yaw_rad)
    offset = np.array([after.x_m, after.y_m]) - rotation @ [before.x_m, before.y_m]
    return rotation, offset


def wrap_angle(angle_rad: float | np.ndarray) -> float | np.ndarray:
    """Angle wrapped to [-pi, pi)."""
    return (np.asarray(angle_rad) + np.pi) % (2.0 * np.pi) - np.pi
