"""Where the robot is, for every runner: one policy for missing odometry.

A connected base that gives no fresh odometry (`Base.odometry()` returns None) leaves
the robot's pose unknown: tracks cannot be placed in `odom` and bearings cannot be
turned into the robot frame, so there is no target motion and the robot stops. The
pose is never guessed (the origin substituted for a moving robot sends it the wrong
way). The loss is logged once as a warning and the return once. Only a runner with no
base (`NullBase`: the camera is assumed still) uses a fixed pose.
"""

from __future__ import annotations

import dataclasses
import logging
import threading

from follow.odometry_buffer import OdometryJumps, pose_change
from follow.types import Odometry

log = logging.getLogger(__name__)

# The stamp a pose that moved at the last sample's stamp is given after it (`_ordered`).
TIED_STAMP_STEP_S = 1e-6


class OdometryPolicy:
    """Samples the base's odometry; None means stop. Safe to share between threads.

    It also watches consecutive samples for a jump no base drives (an estimator's reset):
    `last_jump_s` is the odometry stamp of the newest, so that a frame whose pose came
    before it is not driven toward (`pipeline.target_motion`); between samples a few
    tens of milliseconds apart a reset is plain, where over a frame's age it may not be.
    `jumps` logs each (before, after) pair, for the tracker to move its tracks by exactly
    those (`PeopleTracker.update`)."""

    def __init__(self, base):
        self.base = base
        self._lock = threading.Lock()
        self._missing = False
        self.losses = 0  # how many times fresh odometry went away
        self._previous: Odometry | None = None
        self.jumps = OdometryJumps()

    def sample(self) -> Odometry | None:
        """The base's newest pose, or None (and a warning the first time) when it has
        none that is fresh."""
        pose = self.base.odometry()
        with self._lock:
            if pose is None and not self._missing:
                self._missing = True
                self.losses += 1
                log.warning("no fresh odometry from the base: no target motion, stopping")
            elif pose is not None and self._missing:
                self._missing = False
                log.warning("odometry from the base is back: resuming")
            if pose is not None:
                pose = self._ordered(pose)
                self._note_jump(pose)
        return pose

    def _ordered(self, pose: Odometry) -> Odometry:
        """`pose`, stamped after the last sample where it moved at that sample's stamp.

        A base may stamp a new pose with the time of the last: `MavlinkBase` stamps a pose
        with the older of its position and attitude messages, so an attitude that comes
        before its cycle's position changes the pose, not the stamp. An estimator's reset
        arriving so would pass unseen, and a frame taken before it could not be told from
        one taken after (`pipeline.target_motion` compares stamps): such a pose is given
        a stamp a microsecond after the last. The same pose at the same (or the original)
        stamp is the last sample again."""
        previous = self._previous
        if previous is None or pose.stamp_s > previous.stamp_s:
            return pose
        same_place = (pose.x_m, pose.y_m, pose.yaw_rad) == (
            previous.x_m, previous.y_m, previous.yaw_rad)  # fmt: skip
        if same_place:
            return previous
        if pose.stamp_s == previous.stamp_s:
            return dataclasses.replace(pose, stamp_s=previous.stamp_s + TIED_STAMP_STEP_S)
        return pose  # an older sample (threads sampling out of turn): not a reference

    def _note_jump(self, pose: Odometry) -> None:
        previous = self._previous
        if previous is not None and pose.stamp_s <= previous.stamp_s:
            return  # the same sample again, or an older one: nothing moved after the last
        self._previous = pose
        if previous is None:
            return
        if self.jumps.note(previous, pose):
            log.warning("the base's odometry jumped (%.2f m, %.2f rad in %.3f s: a reset?): "
                        "no target motion from frames before it", *pose_change(previous, pose),
                        pose.stamp_s - previous.stamp_s)  # fmt: skip

    @property
    def last_jump_s(self) -> float | None:
        """The odometry stamp of the newest jump seen (None: none)."""
        return self.jumps.newest_s

    @property
    def missing(self) -> bool:
        with self._lock:
            return self._missing

