"""Following controller: keep a set distance to the target and face it.

A proportional law on distance and bearing with feed-forward of the target's own motion
(so a steadily walking person is followed without a standing distance error), turning in
place when the target is far to the side, and speed / yaw-rate / acceleration limits.
Losing the target, or a last observation older than `target_timeout_s`, gives a zero
command at once: the acceleration limits apply to driving, never to stopping. A target
not seen in the newest frame is driven toward only blind: the forward speed limit falls
from the command at its last observation to zero within `max_blind_drive_s` (also
ignoring the braking limit), the same for backing off, and the turn is capped at the
search rate; a target predicted outside the camera's field of view (`view`) gets no
forward command at all.
"""

from __future__ import annotations

import logging
import math

import numpy as np

from follow.config import ConfigError, ControlConfig
from follow.config_bounds import BOUNDS, section_errors
from follow.control.target import TargetMotion, ViewCone
from follow.freshness import is_fresh
from follow.types import InvalidInput, VelocityCommand

log = logging.getLogger(__name__)

# Upper bounds of the safety timeouts (the configuration's, follow.config_bounds): beyond
# them a robot drives too far on stale data.
MAX_BLIND_DRIVE_S = BOUNDS["control"]["max_blind_drive_s"].hi
MAX_WATCHDOG_TIMEOUT_S = BOUNDS["control"]["watchdog_timeout_s"].hi
MIN_CONTROL_RATE_HZ = BOUNDS["control"]["control_rate_hz"].lo


def check_control_config(config: ControlConfig) -> None:
    """Raise ConfigError naming the first value a controller cannot use."""
    positive = (
        "following_distance_m", "max_forward_speed_mps", "max_yaw_rate_radps",
        "max_forward_accel_mps2", "max_forward_decel_mps2", "max_yaw_accel_radps2",
        "target_timeout_s", "control_rate_hz", "turn_in_place_bearing_rad",
        "max_blind_drive_s", "watchdog_timeout_s", "missing_target_warn_s",
    )  # fmt: skip
    non_negative = (
        "max_backward_speed_mps", "distance_gain_per_s", "bearing_gain_per_s",
        "velocity_feedforward_gain", "search_duration_s", "search_yaw_rate_radps",
    )  # fmt: skip
    for name in positive:
        value = getattr(config, name)
        if not (math.isfinite(value) and value > 0):
            raise ConfigError(f"[control] {name} must be > 0, got {value}")
    for name in non_negative:
        value = getattr(config, name)
        if not (math.isfinite(value) and value >= 0):
            raise ConfigError(f"[control] {name} must be >= 0, got {value}")
    for name, most in (("max_blind_drive_s", MAX_BLIND_DRIVE_S),
                       ("watchdog_timeout_s", MAX_WATCHDOG_TIMEOUT_S)):  # fmt: skip
        if getattr(config, name) > most:
            raise ConfigError(
                f"[control] {name} must be <= {most} (a robot must not drive that long on "
                f"stale data), got {getattr(config, name)}"
            )
    if config.control_rate_hz < MIN_CONTROL_RATE_HZ:
        raise ConfigError(
            f"[control] control_rate_hz must be >= {MIN_CONTROL_RATE_HZ:g} (the stop after a "
            f"stall waits for the next tick), got {config.control_rate_hz}"
        )
    if config.search_yaw_rate_radps > config.max_yaw_rate_radps:
        raise ConfigError(
            f"[control] search_yaw_rate_radps ({config.search_yaw_rate_radps}) exceeds "
            f"max_yaw_rate_radps ({config.max_yaw_rate_radps})"
        )
    # the rest of the ranges a loaded configuration is held to, for a ControlConfig made
    # in code: a search or a target time-out of minutes turns the robot long after a loss
    if errors := section_errors("control", config):
        raise ConfigError("; ".join(errors))


# Speeding up counts at most this many control periods since the last command: a
# control thread starved for a second would otherwise jump a second's acceleration in
# one command (0.3 -> 1.5 m/s), though the base spent that second at the old speed.
MAX_RISE_PERIODS = 2.0


def slew(previous: float, wanted: float, rise_per_s: float, fall_per_s: float, dt_s: float,
         rise_dt_s: float | None = None):  # fmt: skip
    """`wanted`, reached from `previous` within dt at most at `rise_per_s` while moving
    away from zero and at most at `fall_per_s` while moving toward it (a sign change is
    braking to zero first, then speeding up the other way). Speeding up counts
    `rise_dt_s` of the step where given (braking always counts all of it)."""
    rise_dt_s = dt_s if rise_dt_s is None else min(dt_s, rise_dt_s)
    if previous == 0.0 or (wanted * previous > 0 and abs(wanted) >= abs(previous)):
        step = rise_per_s * rise_dt_s  # speeding up
        return previous + float(np.clip(wanted - previous, -step, step))
    toward_zero = wanted if wanted * previous > 0 else 0.0
    braking = fall_per_s * dt_s
    reached = previous + float(np.clip(toward_zero - previous, -braking, braking))
    if reached != 0.0 or wanted == 0.0:
        return reached
    left_s = min(dt_s - abs(previous) / fall_per_s, rise_dt_s)  # time left after stopping
    return float(np.clip(wanted, -rise_per_s * left_s, rise_per_s * left_s))


class FollowingController:
    """Target motion in, velocity command out; call `update` once per control period."""

    def __init__(
        self,
        config: ControlConfig = ControlConfig(),  # noqa: B008 (frozen)
        view: ViewCone | None = None,
    ):
        check_control_config(config)
        self.config = config
        self.view = view
        self._last: VelocityCommand | None = None
        self._last_bearing_rad: float | None = None
        self._lost_since_s: float | None = None
        self._forward_when_seen_mps = 0.0  # the forward command when last seen (< 0: backing)

    @property
    def period_s(self) -> float:
        return 1.0 / self.config.control_rate_hz

    @property
    def _rise_dt_s(self) -> float:
        return MAX_RISE_PERIODS * self.period_s

    def reset(self) -> None:
        """Forget the previous command and the last seen bearing."""
        self._last = None
        self._last_bearing_rad = None
        self._lost_since_s = None
        self._forward_when_seen_mps = 0.0

    def stopped_elsewhere(self, stamp_s: float) -> None:
        """The base was sent zero at `stamp_s` instead of this controller's command (a
        watchdog, odometry lost): the next command speeds up from rest, within the
        acceleration limits, rather than carrying on from a command the base never got."""
        self._last = VelocityCommand.stop(stamp_s)
        self._forward_when_seen_mps = 0.0

    def update(self, target: TargetMotion | None, stamp_s: float) -> VelocityCommand:
        """The command for time `stamp_s` given the newest target estimate (None = lost)."""
        if not math.isfinite(stamp_s):
            raise InvalidInput(f"controller stamp_s is not finite: {stamp_s}")
        dt_s = self._step_s(stamp_s)
        fresh = target is not None and is_fresh(stamp_s, target.stamp_s,
                                                self.config.target_timeout_s)  # fmt: skip
        if not fresh:
            if target is not None:
                log.debug("target estimate %.3f s old: stopping", stamp_s - target.stamp_s)
            command = self._lost(stamp_s, dt_s)
        else:
            self._lost_since_s = None
            command = self._follow(target, stamp_s, dt_s)
        self._last = command
        return command

    # -- internals ---------------------------------------------------------------------

    def _step_s(self, stamp_s: float) -> float:
        if self._last is None:
            return self.period_s
        dt_s = stamp_s - self._last.stamp_s
        if dt_s < 0:
            log.warning("controller time went backwards by %.3f s", -dt_s)
            if self._lost_since_s is not None:  # a search timed on the old clock would
                self._lost_since_s = -math.inf  # last as long as the step: it ends now
            return 0.0
        return dt_s

    def _lost(self, stamp_s: float, dt_s: float) -> VelocityCommand:
        cfg = self.config
        self._forward_when_seen_mps = 0.0  # stopped: blind driving may not start from rest
        if self._lost_since_s is None:
            self._lost_since_s = stamp_s
        searching = (
            cfg.search_duration_s > 0
            and self._last_bearing_rad is not None
            and stamp_s - self._lost_since_s < cfg.search_duration_s
        )
        if not searching:
            return VelocityCommand.stop(stamp_s)
        previous_yaw = self._last.yaw_rate_radps if self._last is not None else 0.0
        wanted = math.copysign(cfg.search_yaw_rate_radps, self._last_bearing_rad)
        yaw = slew(previous_yaw, wanted, cfg.max_yaw_accel_radps2, cfg.max_yaw_accel_radps2,
                   dt_s, self._rise_dt_s)  # fmt: skip
        return VelocityCommand(0.0, yaw, stamp_s)

    def _follow(self, target: TargetMotion, stamp_s: float, dt_s: float) -> VelocityCommand:
        cfg = self.config
        distance = target.distance_m
        bearing = target.bearing_rad
        self._last_bearing_rad = bearing
        (x, y), (vx, vy) = target.position_m, target.velocity_mps
        ff = cfg.velocity_feedforward_gain

        # Heading: bearing error plus the bearing rate the target's own motion causes.
        bearing_rate = (x * vy - y * vx) / max(distance, 1e-3) ** 2
        yaw = cfg.bearing_gain_per_s * bearing + ff * bearing_rate

        # Distance: error plus the target's speed along the line of sight.
        radial_speed = (x * vx + y * vy) / max(distance, 1e-3)
        forward = cfg.distance_gain_per_s * (distance - cfg.following_distance_m)
        forward += ff * radial_speed
        if abs(bearing) > cfg.turn_in_place_bearing_rad:
            forward = 0.0
        else:  # only the part along the heading: none for a target beside or behind
            forward *= max(0.0, math.cos(bearing))  # (backing off must not reverse into it)
        min_forward = -cfg.max_backward_speed_mps if cfg.allow_backing_off else 0.0
        forward = float(np.clip(forward, min_forward, cfg.max_forward_speed_mps))
        yaw = float(np.clip(yaw, -cfg.max_yaw_rate_radps, cfg.max_yaw_rate_radps))

        previous = self._last or VelocityCommand.stop(stamp_s)
        forward = slew(
            previous.forward_mps, forward, cfg.max_forward_accel_mps2,
            cfg.max_forward_decel_mps2, dt_s, self._rise_dt_s,
        )  # fmt: skip
        yaw = slew(
            previous.yaw_rate_radps, yaw, cfg.max_yaw_accel_radps2, cfg.max_yaw_accel_radps2,
            dt_s, self._rise_dt_s,
        )  # fmt: skip
        if not target.observed:  # blind: speed bounded in time, turning bounded in rate
            yaw = float(np.clip(yaw, -cfg.search_yaw_rate_radps, cfg.search_yaw_rate_radps))
            unseen_s = stamp_s - target.stamp_s
            forward = min(forward, self.blind_forward_limit_mps(unseen_s))
            forward = max(forward, -self.blind_backward_limit_mps(unseen_s))
        elif target.late:  # a frozen frame: no faster than the speed of the step before it
            forward = min(forward, max(0.0, self._forward_when_seen_mps))
            forward = max(forward, min(0.0, self._forward_when_seen_mps))
        if self.view is not None and not self.view.contains(target.position_m):
            forward = min(forward, 0.0)
        if target.observed and not target.late:
            self._forward_when_seen_mps = forward
        return VelocityCommand(forward, yaw, stamp_s)

    def blind_forward_limit_mps(self, unseen_s: float) -> float:
        """The most forward speed allowed `unseen_s` after the target's last observation:
        falling linearly from the forward command of that moment to zero at
        `max_blind_drive_s` (a robot never speeds up towards a target it no longer sees)."""
        return max(0.0, self._forward_when_seen_mps) * self._blind_fraction_left(unseen_s)

    def blind_backward_limit_mps(self, unseen_s: float) -> float:
        """The most backward speed allowed `unseen_s` after the target's last
        observation: the same fall, from the backing-off speed of that moment (zero when
        the robot was not backing off then: blind driving never starts backing off)."""
        return max(0.0, -self._forward_when_seen_mps) * self._blind_fraction_left(unseen_s)

    def _blind_fraction_left(self, unseen_s: float) -> float:
        return max(0.0, 1.0 - max(0.0, unseen_s) / self.config.max_blind_drive_s)
