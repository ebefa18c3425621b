"""Where the robot is, for every runner: one policy for missing odometry.

A connected base that gives no fresh odometry (`Base.odometry()` returns None) leaves
the robot's pose unknown: tracks cannot be placed in `odom` and bearings cannot be
turned into the robot frame, so there is no target motion and the robot stops. The
pose is never guessed (the origin substituted for a moving robot sends it the wrong
way). The loss is logged once as a warning and the return once. Only a runner with no
base (`NullBase`: the camera is assumed still) uses a fixed pose.
"""

from __future__ import annotations

import logging
import threading

from follow.odometry_buffer import OdometryJumps, pose_change
from follow.types import Odometry

log = logging.getLogger(__name__)


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
                self._note_jump(pose)
        return pose

    def _note_jump(self, pose: Odometry) -> None:
        previous, self._previous = self._previous, pose
        if previous is None or pose.stamp_s <= previous.stamp_s:
            return  # the same sample again (or an older one): nothing moved between them
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

