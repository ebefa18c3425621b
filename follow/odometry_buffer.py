"""Robot poses by time stamp: the pose at an image's stamp, from stamped odometry.

Images and odometry arrive on their own clocks; the tracker needs the robot's pose at
the instant the image was taken. Between two odometry samples the pose is interpolated
(position linearly, heading along the shorter arc); outside them the nearest sample is
used only within `max_gap_s`, and beyond that there is no pose (never an assumed one).
"""

from __future__ import annotations

import bisect
import math
import threading

from follow.frames import wrap_angle
from follow.types import Odometry


class OdometryBuffer:
    """The latest `capacity` odometry samples in stamp order; safe across threads."""

    def __init__(self, max_gap_s: float, capacity: int = 2000):
        if not max_gap_s > 0:
            raise ValueError(f"max_gap_s must be positive, got {max_gap_s}")
        self.max_gap_s = max_gap_s
        self.capacity = capacity
        self._stamps: list[float] = []
        self._poses: list[Odometry] = []
        self._cond = threading.Condition()

    def add(self, pose: Odometry) -> None:
        with self._cond:
            i = bisect.bisect_right(self._stamps, pose.stamp_s)
            self._stamps.insert(i, pose.stamp_s)
            self._poses.insert(i, pose)
            if len(self._stamps) > self.capacity:
                del self._stamps[0], self._poses[0]
            self._cond.notify_all()

    def __len__(self) -> int:
        return len(self._stamps)

    @property
    def latest(self) -> Odometry | None:
        with self._cond:
            return self._poses[-1] if self._poses else None

    def wait_until(self, stamp_s: float, timeout_s: float) -> bool:
        """Wait (at most `timeout_s`) for a sample at or after `stamp_s`, so that the
        pose at `stamp_s` can be interpolated rather than extrapolated."""
        with self._cond:
            return self._cond.wait_for(
                lambda: bool(self._stamps) and self._stamps[-1] >= stamp_s, timeout=timeout_s
            )

    def at(self, stamp_s: float) -> Odometry | None:
        """The robot's pose at `stamp_s`, or None when no sample is close enough."""
        with self._cond:
            if not self._stamps:
                return None
            i = bisect.bisect_left(self._stamps, stamp_s)
            if i < len(self._stamps) and self._stamps[i] == stamp_s:
                return self._poses[i]
            before = self._poses[i - 1] if i > 0 else None
            after = self._poses[i] if i < len(self._poses) else None
        if before is not None and after is not None:
            span_s = after.stamp_s - before.stamp_s
            if span_s <= 2.0 * self.max_gap_s and not pose_jumped(before, after, span_s):
                return interpolate(before, after, stamp_s)  # (across a jump: the nearer)
        near = min((p for p in (before, after) if p is not None),
                   key=lambda p: abs(p.stamp_s - stamp_s))  # fmt: skip
        if abs(near.stamp_s - stamp_s) > self.max_gap_s:
            return None
        return Odometry(near.x_m, near.y_m, near.yaw_rad, stamp_s)


# A pose change no mobile base makes in the time between two samples is an odometry
# jump (a reset to the origin, an estimator's yaw reset), not motion.
MAX_ROBOT_SPEED_MPS = 3.0
MAX_ROBOT_YAW_RATE_RADPS = 4.0
POSE_JUMP_MARGIN_M = 0.2
POSE_JUMP_MARGIN_RAD = 0.1


def pose_change(before: Odometry, after: Odometry) -> tuple[float, float]:
    """How far (m) and how much (rad, the shorter arc) the pose moved between two samples."""
    moved_m = math.hypot(after.x_m - before.x_m, after.y_m - before.y_m)
    return moved_m, abs(float(wrap_angle(after.yaw_rad - before.yaw_rad)))


def pose_jumped(before: Odometry, after: Odometry, dt_s: float) -> bool:
    """Whether `after` lies farther from `before` than a base drives or turns in `dt_s`."""
    moved_m, turned_rad = pose_change(before, after)
    dt_s = max(0.0, dt_s)
    return (moved_m > MAX_ROBOT_SPEED_MPS * dt_s + POSE_JUMP_MARGIN_M
            or turned_rad > MAX_ROBOT_YAW_RATE_RADPS * dt_s + POSE_JUMP_MARGIN_RAD)  # fmt: skip


def interpolate(before: Odometry, after: Odometry, stamp_s: float) -> Odometry:
    """The pose at `stamp_s` between two samples (linear position, shorter-arc heading)."""
    span = after.stamp_s - before.stamp_s
    w = 0.0 if span <= 0 else (stamp_s - before.stamp_s) / span
    yaw = before.yaw_rad + w * float(wrap_angle(after.yaw_rad - before.yaw_rad))
    return Odometry(
        before.x_m + w * (after.x_m - before.x_m),
        before.y_m + w * (after.y_m - before.y_m),
        float(wrap_angle(yaw)),
        stamp_s,
    )
