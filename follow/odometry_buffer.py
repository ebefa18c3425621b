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
from collections import deque

from follow.frames import wrap_angle
from follow.types import Odometry


class OdometryBuffer:
    """The latest `capacity` odometry samples in stamp order; safe across threads.

    `jumps` logs the last `jump_capacity` jumps between a sample and the newest one
    before it, for the tracker to move its tracks by exactly those
    (`PeopleTracker.update`)."""

    def __init__(self, max_gap_s: float, capacity: int = 2000, jump_capacity: int = 32):
        if not max_gap_s > 0:
            raise ValueError(f"max_gap_s must be positive, got {max_gap_s}")
        self.max_gap_s = max_gap_s
        self.capacity = capacity
        self._stamps: list[float] = []
        self._poses: list[Odometry] = []
        self._cond = threading.Condition()
        self.jumps = OdometryJumps(jump_capacity)

    def add(self, pose: Odometry) -> None:
        """Keep `pose`. Only a sample newer than every other is compared (with the newest)
        for a jump: one arriving late, between two, is not, since its neighbours were
        already compared with each other and a late sample has no reset of its own to
        tell (against the newest it would look like one: a false jump)."""
        with self._cond:
            if self._poses and pose.stamp_s > self._stamps[-1]:
                self.jumps.note(self._poses[-1], pose)
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


def past_jump(before: Odometry, after: Odometry, stamp_s: float) -> bool:
    """Whether the pose at `stamp_s` is in the odom frame after a jump from `before` to
    `after`: from `after`'s stamp on, and between the two samples where `after` is the
    strictly nearer (`OdometryBuffer.at` takes the nearer sample across a jump, the
    earlier on a tie), so that the tracker moves its tracks with the frame whose pose
    is the first in the new frame."""
    if stamp_s >= after.stamp_s or stamp_s <= before.stamp_s:
        return stamp_s >= after.stamp_s
    return after.stamp_s - stamp_s < stamp_s - before.stamp_s


class OdometryJumps:
    """The last `capacity` odometry jumps, each the (before, after) pair of consecutive
    samples between which it came; safe across threads. A jump is told between samples
    tens of milliseconds apart, where a reset of a few tenths of a radian is plain; over a
    frame's interval (0.07-0.2 s) a base may turn that far, and the same reset would pass
    for motion: the tracker takes its jumps from here (`between`)."""

    def __init__(self, capacity: int = 32):
        self._pairs: deque[tuple[Odometry, Odometry]] = deque(maxlen=capacity)
        self._lock = threading.Lock()

    def note(self, previous: Odometry, pose: Odometry) -> bool:
        """Log (previous, pose) if the pose jumped between the two samples; whether it did."""
        if not pose_jumped(previous, pose, pose.stamp_s - previous.stamp_s):
            return False
        with self._lock:
            self._pairs.append((previous, pose))
        return True

    @property
    def newest_s(self) -> float | None:
        """The stamp of the sample after the newest jump (None: none logged)."""
        with self._lock:
            return self._pairs[-1][1].stamp_s if self._pairs else None

    def between(self, t0_s: float, t1_s: float) -> list[tuple[Odometry, Odometry]]:
        """The jumps, oldest first, that a pose at `t1_s` is past and one at `t0_s` is not
        (`past_jump`: for poses that are samples, those whose `after` stamp is in
        (t0, t1])."""
        with self._lock:
            pairs = list(self._pairs)
        return [(b, a) for b, a in pairs if past_jump(b, a, t1_s) and not past_jump(b, a, t0_s)]

    def seen_near(self, t0_s: float, t1_s: float) -> bool:
        """Whether a jump was logged between samples that reach into (t0, t1): one
        `between` gives, or one whose `after` sample came too late for a pose at t0."""
        with self._lock:
            pairs = list(self._pairs)
        return any(b.stamp_s < t1_s and a.stamp_s > t0_s for b, a in pairs)


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
