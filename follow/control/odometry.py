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

from follow.types import Odometry

log = logging.getLogger(__name__)


class OdometryPolicy:
    """Samples the base's odometry; None means stop. Safe to share between threads."""

    def __init__(self, base):
        self.base = base
        self._lock = threading.Lock()
        self._missing = False
        self.losses = 0  # how many times fresh odometry went away

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
        return pose

    @property
    def missing(self) -> bool:
        with self._lock:
            return self._missing
