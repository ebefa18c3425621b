"""`SimRover`: a MAVLink vehicle on UDP loopback that behaves like ArduPilot Rover for
what the following stack needs.

It speaks the default pymavlink dialect on a socket bound to 127.0.0.1 and answers
whoever last sent to it (like a vehicle's `udpin`). It sends a 1 Hz HEARTBEAT (custom
mode + armed bit), changes mode on MAV_CMD_DO_SET_MODE / SET_MODE with a COMMAND_ACK,
arms on MAV_CMD_COMPONENT_ARM_DISARM, streams LOCAL_POSITION_NED and ATTITUDE only at
the intervals requested with MAV_CMD_SET_MESSAGE_INTERVAL, and in GUIDED takes
SET_POSITION_TARGET_LOCAL_NED the way ArduPilot Rover does (the same frames and the
same type_mask combinations; everything else is ignored, silently, as ArduPilot does).
Motion is a unicycle with speed, turn-rate and acceleration limits; it stops when no
setpoint arrives for 3 s, when disarmed and outside GUIDED. Faults: packet loss, latency,
a mode switch by the pilot, a cut link. It runs in real time in a background thread.

With `autopilot="px4"` it models a PX4 differential rover instead: OFFBOARD mode (refused
unless setpoints already stream; left for AUTO.LOITER after 1 s without them), driving
along the direction and length of the body velocity setpoint, ignoring yaw rate.
"""

from __future__ import annotations

import heapq
import itertools
import logging
import math
import random
import socket
import threading
import time
from collections import deque
from dataclasses import dataclass

from pymavlink import mavutil

from follow.control import mavlink_frames as mf
from follow.frames import wrap_angle
from follow.types import Odometry

log = logging.getLogger(__name__)
mavlink = mavutil.mavlink

_ACCEPTED_FRAMES = (
    mavlink.MAV_FRAME_LOCAL_NED, mavlink.MAV_FRAME_LOCAL_OFFSET_NED,
    mavlink.MAV_FRAME_BODY_NED, mavlink.MAV_FRAME_BODY_OFFSET_NED,
)  # fmt: skip
_BODY_FRAMES = (mavlink.MAV_FRAME_BODY_NED, mavlink.MAV_FRAME_BODY_OFFSET_NED)
_STREAMABLE = (mf.MSG_ID_ATTITUDE, mf.MSG_ID_LOCAL_POSITION_NED)
_PX4_FRAMES = (mavlink.MAV_FRAME_LOCAL_NED, *_BODY_FRAMES)
PX4_MAIN_MODE_MANUAL = 1
PX4_MAIN_MODE_AUTO = 4
PX4_SUB_MODE_LOITER = 3  # AUTO.LOITER: PX4's hold, also its offboard-loss failsafe
PX4_MAIN_MODES = (PX4_MAIN_MODE_MANUAL, PX4_MAIN_MODE_AUTO, mf.PX4_MAIN_MODE_OFFBOARD)
PX4_OFFBOARD_STREAM_S = 0.5  # setpoints must have been heard this recently to enter OFFBOARD
PX4_OFFBOARD_LOSS_S = 1.0  # COM_OF_LOSS_T: no setpoint for this long leaves OFFBOARD


@dataclass(frozen=True)
class RoverLimits:
    """The simulated vehicle's own limits (ArduPilot's WP_SPEED, ATC_* and guided timeout)."""

    max_speed_mps: float = 2.0
    max_turn_rate_radps: float = 2.0
    max_accel_mps2: float = 2.0
    max_turn_accel_radps2: float = 8.0
    heading_gain_per_s: float = 2.0  # heading-hold steering when a heading is commanded
    guided_timeout_s: float = 3.0


@dataclass
class _Target:
    speed_mps: float = 0.0
    turn_rate_radps: float = 0.0  # NED, clockwise positive
    heading_ned_rad: float | None = None  # steer to this heading instead of a turn rate


class SimRover:
    """A simulated ArduPilot Rover on 127.0.0.1. Use `with SimRover() as rover:` and give
    `rover.connection` to a MavlinkBase."""

    def __init__(
        self,
        port: int = 0,
        *,
        armed: bool = True,
        mode: int | None = None,
        autopilot: str = "ardupilot",
        limits: RoverLimits = RoverLimits(),  # noqa: B008 (frozen)
        start_pose: Odometry | None = None,
        physics_rate_hz: float = 100.0,
        heartbeat_rate_hz: float = 1.0,
        system_id: int = 1,
        seed: int = 0,
    ):
        if autopilot not in ("ardupilot", "px4"):
            raise ValueError(
                f"sim rover: autopilot must be 'ardupilot' or 'px4', got {autopilot!r}"
            )
        self.autopilot = autopilot
        self._px4 = autopilot == "px4"
        if mode is None:
            mode = mf.px4_custom_mode(PX4_MAIN_MODE_MANUAL) if self._px4 else mf.ROVER_MODE_MANUAL
        self.limits = limits
        self._lock = threading.Lock()
        self._sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self._sock.bind(("127.0.0.1", port))
        self._sock.setblocking(False)
        self.port = self._sock.getsockname()[1]
        self._mav = mavlink.MAVLink(None, srcSystem=system_id, srcComponent=1)
        self._mav.robust_parsing = True
        self._system_id = system_id
        self._period_s = 1.0 / physics_rate_hz
        self._heartbeat_period_s = 1.0 / heartbeat_rate_hz
        self._rng = random.Random(seed)
        self._seq = itertools.count()
        self._inbox: list = []  # heap of (due, seq, bytes, address)
        self._outbox: list = []  # heap of (due, seq, bytes)
        self._peer: tuple[str, int] | None = None
        self._thread: threading.Thread | None = None
        self._running = threading.Event()
        self._boot_s = time.monotonic()
        pose = start_pose or Odometry.origin()
        self._north, self._east, self._yaw = mf.odom_pose_to_ned(pose.x_m, pose.y_m, pose.yaw_rad)
        self._state_s = self._boot_s  # when the pose and speeds below were computed
        self._speed = 0.0  # forward, m/s
        self._turn_rate = 0.0  # NED, rad/s
        self._target = _Target()
        self._last_setpoint_s = -math.inf  # last setpoint obeyed
        self._last_setpoint_heard_s = -math.inf  # last one received, in any mode (PX4)
        self._intervals_s: dict[int, float] = {}
        self._next_stream_s: dict[int, float] = {}
        self._next_heartbeat_s = 0.0
        # State visible to tests.
        self.mode = mode
        self.armed = armed
        self.packet_loss = 0.0
        self.latency_s = 0.0
        self.link_cut = False
        self.telemetry_paused = False
        self.setpoints_accepted = 0
        self.setpoints_ignored = 0
        self.setpoint_log: deque[tuple[float, int, int]] = deque(maxlen=10_000)  # (t, frame, mask)
        # The newest setpoint heard: (monotonic time, vx m/s, yaw rate rad/s), any mode.
        self.last_setpoint: tuple[float, float, float] | None = None
        self.commands_received: list[int] = []
        self.companion_heartbeats = 0

    # -- lifecycle ----------------------------------------------------------------------

    @property
    def connection(self) -> str:
        """The pymavlink connection string a companion uses to reach this vehicle."""
        return f"udpout:127.0.0.1:{self.port}"

    def start(self) -> SimRover:
        if self._thread is None:
            self._running.set()
            self._thread = threading.Thread(target=self._run, name="sim-rover", daemon=True)
            self._thread.start()
        return self

    def stop(self) -> None:
        self._running.clear()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
            self._thread = None
        self._sock.close()

    def __enter__(self) -> SimRover:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()

    # -- truth and faults -----------------------------------------------------------------

    def true_pose(self) -> Odometry:
        """The vehicle's exact pose in `odom`, stamped (monotonic clock) at the physics
        step that computed it: up to a step before the call."""
        with self._lock:
            x, y, yaw = mf.ned_pose_to_odom(self._north, self._east, self._yaw)
            stamp_s = self._state_s
        return Odometry(x, y, yaw, stamp_s)

    def true_velocity(self) -> tuple[float, float]:
        """(forward m/s, yaw rate rad/s counter-clockwise) now."""
        with self._lock:
            return self._speed, -self._turn_rate

    def pilot_set_mode(self, mode: int) -> None:
        """The pilot flips the mode switch (e.g. to MANUAL or HOLD)."""
        with self._lock:
            self._set_mode_locked(mode)

    def pause_telemetry(self, paused: bool = True) -> None:
        """Stop streaming LOCAL_POSITION_NED and ATTITUDE (heartbeats go on) until
        called with False: an odometry source that fails while the link stays up."""
        self.telemetry_paused = paused

    def cut_link(self, cut: bool = True) -> None:
        """Drop every packet both ways (radio out of range) until called with False."""
        self.link_cut = cut

    # -- the loop -----------------------------------------------------------------------

    def _run(self) -> None:
        last = time.monotonic()
        while self._running.is_set():
            now = time.monotonic()
            self._receive(now)
            with self._lock:
                self._handle_due(now)
                self._step(now - last, now)
                self._emit(now)
            self._flush(now)
            last = now
            time.sleep(max(0.0, self._period_s - (time.monotonic() - now)))

    def _lost(self) -> bool:
        return self.link_cut or (self.packet_loss > 0 and self._rng.random() < self.packet_loss)

    def _receive(self, now: float) -> None:
        while True:
            try:
                data, address = self._sock.recvfrom(65535)
            except (BlockingIOError, OSError):
                return
            if not self._lost():
                heapq.heappush(self._inbox, (now + self.latency_s, next(self._seq), data, address))

    def _handle_due(self, now: float) -> None:
        while self._inbox and self._inbox[0][0] <= now:
            _, _, data, address = heapq.heappop(self._inbox)
            if address != self._peer:
                self._peer = address
                self._next_heartbeat_s = 0.0  # a new companion hears from us at once
            try:
                messages = self._mav.parse_buffer(data) or []
            except mavlink.MAVError as exc:
                log.debug("sim rover: bad packet: %s", exc)
                continue
            for msg in messages:
                try:
                    self._handle(msg, now)
                except Exception:  # one bad message must not end the vehicle's thread
                    log.exception("sim rover: %s not handled", msg.get_type())

    def _send(self, msg, now: float) -> None:
        if self._peer is None:
            return
        data = msg.pack(self._mav)
        if not self._lost():
            heapq.heappush(self._outbox, (now + self.latency_s, next(self._seq), data))

    def _flush(self, now: float) -> None:
        while self._outbox and self._outbox[0][0] <= now:
            _, _, data = heapq.heappop(self._outbox)
            try:
                self._sock.sendto(data, self._peer)
            except OSError as exc:
                log.debug("sim rover: send failed: %s", exc)

    # -- message handling (called with the lock held) -------------------------------------

    def _handle(self, msg, now: float) -> None:
        kind = msg.get_type()
        if kind == "HEARTBEAT":
            self.companion_heartbeats += 1
        elif kind == "COMMAND_LONG" and msg.target_system in (0, self._system_id):
            self.commands_received.append(msg.command)
            result = self._command(msg)
            ack = mavlink.MAVLink_command_ack_message(msg.command, result)
            self._send(ack, now)
        elif kind == "SET_MODE" and msg.target_system == self._system_id:
            ok = bool(msg.base_mode & mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED)
            ok = ok and self._set_mode_locked(msg.custom_mode)
            result = mavlink.MAV_RESULT_ACCEPTED if ok else mavlink.MAV_RESULT_FAILED
            self._send(
                mavlink.MAVLink_command_ack_message(mavlink.MAVLINK_MSG_ID_SET_MODE, result), now
            )
        elif kind == "SET_POSITION_TARGET_LOCAL_NED" and msg.target_system == self._system_id:
            self.setpoint_log.append((now, msg.coordinate_frame, msg.type_mask))
            self.last_setpoint = (now, float(msg.vx), float(msg.yaw_rate))
            self._last_setpoint_heard_s = now
            if self._setpoint_px4(msg) if self._px4 else self._setpoint(msg):
                self.setpoints_accepted += 1
                self._last_setpoint_s = now
            else:
                self.setpoints_ignored += 1

    def _command(self, msg) -> int:
        # The commands simulated read param1 to param3 (int(nan) raises).
        if not all(math.isfinite(p) for p in (msg.param1, msg.param2, msg.param3)):
            return mavlink.MAV_RESULT_DENIED
        if msg.command == mavlink.MAV_CMD_DO_SET_MODE:
            if not int(msg.param1) & mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED:
                return mavlink.MAV_RESULT_UNSUPPORTED
            mode = int(msg.param2)
            if self._px4:  # param2 = main mode, param3 = sub mode
                mode = mf.px4_custom_mode(int(msg.param2), int(msg.param3))
            ok = self._set_mode_locked(mode)
            return mavlink.MAV_RESULT_ACCEPTED if ok else mavlink.MAV_RESULT_FAILED
        if msg.command == mavlink.MAV_CMD_COMPONENT_ARM_DISARM:
            self.armed = msg.param1 == 1
            return mavlink.MAV_RESULT_ACCEPTED
        if msg.command == mavlink.MAV_CMD_SET_MESSAGE_INTERVAL:
            msg_id, interval_us = int(msg.param1), msg.param2
            if msg_id not in _STREAMABLE:
                return mavlink.MAV_RESULT_DENIED
            if interval_us < 0 or interval_us == 0:  # -1 off; 0 = default (off here)
                self._intervals_s.pop(msg_id, None)
            else:
                self._intervals_s[msg_id] = interval_us * 1e-6
            return mavlink.MAV_RESULT_ACCEPTED
        return mavlink.MAV_RESULT_UNSUPPORTED

    @property
    def commanded_mode(self) -> int:
        """The mode in which a companion drives the vehicle: GUIDED, or PX4 OFFBOARD."""
        return mf.px4_custom_mode(mf.PX4_MAIN_MODE_OFFBOARD) if self._px4 else mf.ROVER_MODE_GUIDED

    def _set_mode_locked(self, mode: int) -> bool:
        if self._px4:
            if mf.px4_main_mode(mode) not in PX4_MAIN_MODES:
                return False
            # PX4 refuses OFFBOARD unless setpoints are already streaming.
            heard_s = time.monotonic() - self._last_setpoint_heard_s
            if mode == self.commanded_mode and heard_s > PX4_OFFBOARD_STREAM_S:
                return False
        elif mode not in mf.ROVER_MODES:
            return False
        if mode != self.mode:
            self.mode = mode
            self._target = _Target()  # a new mode starts from a standstill target
            self._last_setpoint_s = -math.inf
            self._next_heartbeat_s = 0.0  # announce the change at once
        return True

    def _setpoint_px4(self, msg) -> bool:
        """A PX4 differential rover in OFFBOARD: it drives along the velocity setpoint
        (direction and length) and ignores yaw and yaw rate."""
        if self.mode != self.commanded_mode or msg.coordinate_frame not in _PX4_FRAMES:
            return False
        if not _used_fields_finite(msg):
            return False
        if not msg.type_mask & mf.MASK_POSITION_IGNORE or msg.type_mask & mf.MASK_VELOCITY_IGNORE:
            return False  # only velocity setpoints are simulated
        speed = min(math.hypot(msg.vx, msg.vy), self.limits.max_speed_mps)
        heading = math.atan2(msg.vy, msg.vx)
        if msg.coordinate_frame in _BODY_FRAMES:
            heading += self._yaw
        self._target = _Target(speed, 0.0, heading if speed > 0 else self._yaw)
        return True

    def _setpoint(self, msg) -> bool:
        """ArduPilot Rover's GUIDED handling of SET_POSITION_TARGET_LOCAL_NED (velocity,
        heading and turn-rate targets; position targets are counted but not simulated)."""
        if self.mode != mf.ROVER_MODE_GUIDED or msg.coordinate_frame not in _ACCEPTED_FRAMES:
            return False
        if not _used_fields_finite(msg):
            return False
        mask = msg.type_mask
        pos_ignore = bool(mask & mf.MASK_POSITION_IGNORE)
        vel_ignore = bool(mask & mf.MASK_VELOCITY_IGNORE)
        acc_ignore = bool(mask & mf.MASK_ACCELERATION_IGNORE)
        yaw_ignore = bool(mask & mf.MASK_YAW_IGNORE)
        rate_ignore = bool(mask & mf.MASK_YAW_RATE_IGNORE)
        if not pos_ignore:
            return False  # position targets: not part of this simulation
        body = msg.coordinate_frame in _BODY_FRAMES
        speed, heading = 0.0, 0.0
        if not vel_ignore:
            speed = min(math.hypot(msg.vx, msg.vy), self.limits.max_speed_mps)
            heading = math.atan2(msg.vy, msg.vx) + (self._yaw if body else 0.0)
        if not yaw_ignore:
            heading = msg.yaw + (self._yaw if body else 0.0)
        if not vel_ignore and (not yaw_ignore or not rate_ignore) and msg.vx < 0:
            speed = -speed
        if not vel_ignore and acc_ignore and yaw_ignore and not rate_ignore:
            self._target = _Target(speed, msg.yaw_rate)
        elif not vel_ignore and acc_ignore and rate_ignore:
            self._target = _Target(speed, 0.0, heading)
        elif vel_ignore and acc_ignore and not yaw_ignore and rate_ignore:
            self._target = _Target(0.0, 0.0, heading)
        elif vel_ignore and acc_ignore and yaw_ignore and not rate_ignore:
            self._target = _Target(0.0, msg.yaw_rate)
        else:
            return False
        return True

    # -- physics and telemetry (called with the lock held) --------------------------------

    def _step(self, dt_s: float, now: float) -> None:
        lim = self.limits
        silent_s = now - self._last_setpoint_s
        unheard_s = now - self._last_setpoint_heard_s
        if self._px4 and self.mode == self.commanded_mode and unheard_s > PX4_OFFBOARD_LOSS_S:
            self._set_mode_locked(mf.px4_custom_mode(PX4_MAIN_MODE_AUTO, PX4_SUB_MODE_LOITER))
        driving = self.armed and self.mode == self.commanded_mode
        driving = driving and silent_s <= lim.guided_timeout_s
        target = self._target if driving else _Target()
        turn = target.turn_rate_radps
        if target.heading_ned_rad is not None:
            turn = lim.heading_gain_per_s * float(wrap_angle(target.heading_ned_rad - self._yaw))
        turn = max(-lim.max_turn_rate_radps, min(lim.max_turn_rate_radps, turn))
        speed = target.speed_mps
        if self._px4 and target.heading_ned_rad is not None:  # turn before driving off
            speed *= max(0.0, math.cos(target.heading_ned_rad - self._yaw))
        self._speed += _towards(self._speed, speed, lim.max_accel_mps2 * dt_s)
        self._turn_rate += _towards(self._turn_rate, turn, lim.max_turn_accel_radps2 * dt_s)
        self._north += self._speed * math.cos(self._yaw) * dt_s
        self._east += self._speed * math.sin(self._yaw) * dt_s
        self._yaw = float(wrap_angle(self._yaw + self._turn_rate * dt_s))
        self._state_s = now

    def _emit(self, now: float) -> None:
        boot_ms = int((now - self._boot_s) * 1000)
        if now >= self._next_heartbeat_s:
            self._next_heartbeat_s = now + self._heartbeat_period_s
            base_mode = mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
            if self.armed:
                base_mode |= mavlink.MAV_MODE_FLAG_SAFETY_ARMED
            if self.mode in (self.commanded_mode, mf.ROVER_MODE_AUTO):
                base_mode |= mavlink.MAV_MODE_FLAG_GUIDED_ENABLED
            state = mavlink.MAV_STATE_ACTIVE if self.armed else mavlink.MAV_STATE_STANDBY
            hb = mavlink.MAVLink_heartbeat_message(
                mavlink.MAV_TYPE_GROUND_ROVER,
                mavlink.MAV_AUTOPILOT_PX4 if self._px4 else mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA,
                base_mode, self.mode, state, 3,
            )  # fmt: skip
            self._send(hb, now)
        for msg_id, interval_s in self._intervals_s.items():
            if self.telemetry_paused or now < self._next_stream_s.get(msg_id, 0.0):
                continue
            self._next_stream_s[msg_id] = max(
                self._next_stream_s.get(msg_id, now) + interval_s, now
            )
            self._send(self._stream_message(msg_id, boot_ms), now)

    def _stream_message(self, msg_id: int, boot_ms: int):
        if msg_id == mf.MSG_ID_ATTITUDE:
            return mavlink.MAVLink_attitude_message(
                boot_ms, 0.0, 0.0, self._yaw, 0.0, 0.0, self._turn_rate
            )
        v_north = self._speed * math.cos(self._yaw)
        v_east = self._speed * math.sin(self._yaw)
        return mavlink.MAVLink_local_position_ned_message(
            boot_ms, self._north, self._east, 0.0, v_north, v_east, 0.0
        )


def _used_fields_finite(msg) -> bool:
    """Whether the velocity, yaw and yaw rate a setpoint's type_mask uses are finite: a
    NaN speed passes min() with the speed limit and accelerates the vehicle for ever."""
    used = {
        mf.MASK_VELOCITY_IGNORE: (msg.vx, msg.vy),
        mf.MASK_YAW_IGNORE: (msg.yaw,),
        mf.MASK_YAW_RATE_IGNORE: (msg.yaw_rate,),
    }
    return all(
        math.isfinite(value)
        for ignore, values in used.items()
        if not msg.type_mask & ignore
        for value in values
    )


def _towards(current: float, wanted: float, max_step: float) -> float:
    return max(-max_step, min(max_step, wanted - current))
