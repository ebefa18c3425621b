"""What the controller is told about the person it follows."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from follow.types import InvalidInput


@dataclass(frozen=True)
class TargetMotion:
    """The target's ground position (m) and ground velocity (m/s, relative to the world,
    not to the robot), both expressed in the robot's `base` frame, estimated at `stamp_s`.
    """

    position_m: np.ndarray  # (2,) x forward, y left
    velocity_mps: np.ndarray  # (2,)
    stamp_s: float

    def __post_init__(self):
        for name in ("position_m", "velocity_mps"):
            arr = np.asarray(getattr(self, name), dtype=np.float64)
            if arr.shape != (2,):
                raise InvalidInput(f"target {name}: expected shape (2,), got {arr.shape}")
            if not np.isfinite(arr).all():
                raise InvalidInput(f"target {name} is not finite: {arr.tolist()}")
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
