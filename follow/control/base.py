"""The `Base` protocol every robot base driver provides, and `NullBase` for no robot."""

from __future__ import annotations

import dataclasses
import threading
import time
from collections import deque
from collections.abc import Callable
from typing import Protocol, runtime_checkable

from follow.types import Odometry, VelocityCommand


@runtime_checkable
class Base(Protocol):
    """A mobile base: takes body-frame velocity commands, reports odometry in `odom`."""

    def send(self, cmd: VelocityCommand) -> VelocityCommand:
        """Command a body-frame velocity; the newest command replaces the previous one.
        Returns the command passed on: a zero where the base refused to move (a gate),
        so that the controller speeds up from rest once it may move again."""

    def odometry(self) -> Odometry | None:
        """The newest pose in `odom`, or None when there is none or it is stale."""

    def healthy(self) -> bool:
        """Whether commands currently reach the base and it obeys them."""

    def close(self) -> None:
        """Send a zero velocity, then release the connection."""


# NullBase keeps this many recent commands: enough to inspect, bounded for long runs.
NULL_BASE_HISTORY = 10_000


class NullBase:
    """No robot: records the recent commands and reports a fixed pose (the origin by
    default), stamped with `clock()` when read, so that it is never stale."""

    def __init__(
        self,
        pose: Odometry | None = None,
        clock: Callable[[], float] = time.monotonic,
        history: int = NULL_BASE_HISTORY,
    ):
        self._lock = threading.Lock()
        self._clock = clock
        self.commands: deque[VelocityCommand] = deque(maxlen=history)
        self.pose = pose or Odometry.origin()
        self.closed = False

    def send(self, cmd: VelocityCommand) -> VelocityCommand:
        with self._lock:
            if self.closed:
                raise RuntimeError("NullBase: send() after close()")
            self.commands.append(cmd)
        return cmd

    def odometry(self) -> Odometry | None:
        return dataclasses.replace(self.pose, stamp_s=self._clock())

    def healthy(self) -> bool:
        return not self.closed

    def close(self) -> None:
        with self._lock:
            if not self.closed:
                stamp = self.commands[-1].stamp_s if self.commands else 0.0
                self.commands.append(VelocityCommand.stop(stamp))
                self.closed = True

    @property
    def last_command(self) -> VelocityCommand | None:
        with self._lock:
            return self.commands[-1] if self.commands else None
