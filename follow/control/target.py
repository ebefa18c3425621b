"""What the controller is told about the person it follows."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from follow.types import InvalidInput

# Far past any person a camera sees or any walking speed; beyond them a target is a
# fault upstream (and the controller's squares of it would overflow).
TARGET_MAGNITUDE_LIMITS = {"position_m": 1e4, "velocity_mps": 1e3}


@dataclass(frozen=True)
class TargetMotion:
    """The target's ground position (m) and ground velocity (m/s, relative to the world,
    not to the robot), both expressed in the robot's `base` frame.

    `stamp_s` is when the target was last observed (not when the estimate was
    predicted), so that a track coasting without observations ages and goes stale.
    `observed` says whether the newest frame saw it; when not, the position is the
    tracker's prediction and the controller only drives blind for a bounded time.
    `late` says the frame is one a control step already took and is older than a frame
    in flight (perception gave nothing newer: a frozen camera): the target is driven on
    at the speed of the last step before, never faster, until the watchdog trips.
    """

    position_m: np.ndarray  # (2,) x forward, y left
    velocity_mps: np.ndarray  # (2,)
    stamp_s: float
    observed: bool = True
    late: bool = False

    def __post_init__(self):
        for name in ("position_m", "velocity_mps"):
            arr = np.asarray(getattr(self, name), dtype=np.float64)
            if arr.shape != (2,):
                raise InvalidInput(f"target {name}: expected shape (2,), got {arr.shape}")
            if not np.isfinite(arr).all():
                raise InvalidInput(f"target {name} is not finite: {arr.tolist()}")
            if np.abs(arr).max() > TARGET_MAGNITUDE_LIMITS[name]:
                raise InvalidInput(f"target {name} {arr.tolist()} is beyond "
                                   f"{TARGET_MAGNITUDE_LIMITS[name]:g}: no person a camera "
                                   "sees (a fault upstream)")  # fmt: skip
            arr = arr.copy()
            arr.flags.writeable = False
            object.__setattr__(self, name, arr)
        if not math.isfinite(self.stamp_s):
            raise InvalidInput(f"target stamp_s is not finite: {self.stamp_s}")

    @property
    def distance_m(self) -> float:
        return float(np.hypot(*self.position_m))

    @property
    def bearing_rad(self) -> float:
        """Angle of the target from the robot's forward axis, positive to the left."""
        return float(math.atan2(self.position_m[1], self.position_m[0]))


@dataclass(frozen=True)
class ViewCone:
    """The bearings (in `base`, from the camera's position) that the camera sees: a
    target predicted outside them is not where the robot may drive blind."""

    left_rad: float  # bearing of the image's left edge (positive = left)
    right_rad: float  # bearing of the image's right edge (negative = right)
    origin_m: tuple[float, float] = (0.0, 0.0)  # the camera's x, y on the robot

    @classmethod
    def from_camera(cls, camera) -> ViewCone:
        """The horizontal field of view of a `CameraModel` (edges of its image)."""
        fx, cx = float(camera.K[0, 0]), float(camera.K[0, 2])
        width = camera.image_size[0]
        yaw = camera.pose.yaw_rad
        left = yaw + math.atan2(cx + 0.5, fx)
        right = yaw - math.atan2(width - 0.5 - cx, fx)
        return cls(left, right, (camera.pose.x_m, camera.pose.y_m))

    @property
    def horizontal_fov_rad(self) -> float:
        return self.left_rad - self.right_rad

    def contains(self, position_m: np.ndarray) -> bool:
        """Whether a ground point (in `base`) lies inside the horizontal field of view."""
        dx = float(position_m[0]) - self.origin_m[0]
        dy = float(position_m[1]) - self.origin_m[1]
        bearing = math.atan2(dy, dx)
        mid = 0.5 * (self.left_rad + self.right_rad)
        off = math.remainder(bearing - mid, math.tau)
        return abs(off) <= 0.5 * self.horizontal_fov_rad
