"""A connected base for `follow run` tests: it records every command it is sent, in order,
and reports the origin as a fresh pose. Unlike NullBase it sends no stop of its own on
close, so a test sees only what the stack sent."""

from __future__ import annotations

import time

from follow.types import Odometry


class RecordingBase:
    def __init__(self):
        self.commands = []

    def send(self, cmd):
        self.commands.append(cmd)

    def odometry(self):
        return Odometry(0.0, 0.0, 0.0, time.monotonic())

    def close(self):
        pass
