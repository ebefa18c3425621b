"""The node's safety rules, without ROS: the `[ros]` limits checked at start-up, its
velocity output, a `Base` for the shared ControlLoop that publishes cmd_vel and refuses
to move on stale odometry or while following is stopped, and its controller, which
forgets the target an operator chose against.

The ControlLoop already stops on stale images (its perception time-out) and the
controller on a lost target; this gate adds the rules that only the node knows: no
fresh odometry (by its stamp, on the node's clock; a stamp ahead of that clock is not
fresh either, `follow.freshness`) means stop, and so does an operator's stop request.
A node clock that stops advancing (`use_sim_time` with the simulator paused or gone:
/clock no longer published) would leave every stamp as fresh as when it stopped, so no
odometry counts as fresh once that clock has stood still for `max_odometry_age_s` of
wall time.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable

from follow.config import ConfigError, ControlConfig, RosConfig
from follow.control.controller import FollowingController
from follow.control.target import TargetMotion
from follow.freshness import is_ahead, is_fresh
from follow.types import Odometry, VelocityCommand

log = logging.getLogger(__name__)


class CmdVelGate:
    """`send` forwards a command to `publish`, replaced by zero when it must not move."""

    def __init__(
        self,
        publish: Callable[[VelocityCommand], None],
        clock: Callable[[], float],
        max_odometry_age_s: float,
    ):
        self.publish = publish
        self.clock = clock
        self.max_odometry_age_s = max_odometry_age_s
        self.following = True
        self.blocked = 0  # moving commands replaced by zero
        self.last_sent: VelocityCommand | None = None
        self._odometry: Odometry | None = None
        self._lock = threading.Lock()  # the newest pose, the clock's last reading
        self._clock_read = clock()
        self._clock_moved_wall_s = time.monotonic()  # when `clock` last gave a new reading
        self._clock_stalled = False
        self._send_lock = threading.Lock()  # a command's check and its publishing

    def update_odometry(self, pose: Odometry) -> None:
        """Keep the newest pose; one stamped ahead of the clock is not kept (it would
        make every later, correct pose look older and block the base for good)."""
        now, _ = self._now()
        if is_ahead(now, pose.stamp_s):
            return
        with self._lock:
            if self._odometry is None or pose.stamp_s >= self._odometry.stamp_s:
                self._odometry = pose

    def odometry(self) -> Odometry | None:
        """The newest pose if it is fresh, else None (never an assumed one); None too
        while the clock stands still."""
        now, stalled = self._now()
        with self._lock:
            pose = self._odometry
        if stalled or pose is None or not is_fresh(now, pose.stamp_s, self.max_odometry_age_s):
            return None
        return pose

    def _now(self) -> tuple[float, bool]:
        """The clock's reading, and whether it has given the same reading for longer
        than `max_odometry_age_s` of wall time."""
        now, wall = self.clock(), time.monotonic()
        with self._lock:
            if now != self._clock_read:
                self._clock_read, self._clock_moved_wall_s = now, wall
            stalled = wall - self._clock_moved_wall_s > self.max_odometry_age_s
            if stalled and not self._clock_stalled:
                log.warning("the node's clock has not advanced for %.1f s (use_sim_time with "
                            "/clock stopped?): cmd_vel is zero until it does",
                            wall - self._clock_moved_wall_s)  # fmt: skip
            self._clock_stalled = stalled
        return now, stalled

    def healthy(self) -> bool:
        return self.odometry() is not None

    def send(self, command: VelocityCommand) -> VelocityCommand:
        # The check and the publishing as one: a command checked before an operator's
        # stop cannot be published after its zero.
        with self._send_lock:
            if not command.is_stop and not (self.following and self.healthy()):
                self.blocked += 1
                command = VelocityCommand.stop(command.stamp_s)
            self.last_sent = command
            self.publish(command)
        return command

    def stop_following(self, stamp_s: float) -> None:
        """An operator's stop: zero now, and zero for every command until `following`."""
        with self._send_lock:
            self.following = False
            self.last_sent = VelocityCommand.stop(stamp_s)
            self.publish(self.last_sent)

    def close(self) -> None:
        self.send(VelocityCommand.stop(self.clock()))


class ReselectableController(FollowingController):
    """A FollowingController that an operator's new choice of target (`~/select_target`,
    resuming after `~/stop_following` too) clears: its lost-target search would turn the
    base toward the last bearing of the person just deselected. From `forget_target`
    until `target_tracked` every update forgets the old target and commands zero, so a
    tick that was computing from the old target while the choice was made leaves
    nothing behind either (ticks run one after another)."""

    def __init__(self, config: ControlConfig):
        super().__init__(config)
        self.awaiting_target = False

    def forget_target(self) -> None:
        self.awaiting_target = True

    def target_tracked(self) -> None:
        """A frame concluded with the new choice tracks its target: follow it."""
        self.awaiting_target = False

    def update(self, target: TargetMotion | None, stamp_s: float) -> VelocityCommand:
        if self.awaiting_target:
            self.reset()
            target = None
        return super().update(target, stamp_s)


def check_ros_config(ros: RosConfig) -> None:
    """The node's time limits must be positive and finite: they are its safety rules."""
    for name in ("max_image_age_s", "max_odometry_age_s", "diagnostics_period_s"):
        value = getattr(ros, name)
        if not (0.0 < value < float("inf")):
            raise ConfigError(f"[ros] {name} must be positive and finite, got {value}")
    if not ros.image_topic:
        raise ConfigError("[ros] image_topic must name the camera's image topic")
    if ros.publish_cmd_vel and not ros.odom_topic:
        raise ConfigError("[ros] publish_cmd_vel needs odom_topic: no odometry, no driving")
