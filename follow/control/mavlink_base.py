"""`MavlinkBase`: drive an ArduPilot Rover (GUIDED) or a PX4 rover (OFFBOARD) over MAVLink.

Two threads own the link. The receiver drains every message as it arrives and keeps only
the newest of each type (pymavlink would otherwise hand out stale queued ones). The sender
runs at `stream_rate_hz`: it sends the companion HEARTBEAT once a second and, while the
link is up and the vehicle is in the mode we put it in, repeats the newest velocity
command, replacing it by zero once it is older than `command_timeout_s`. It sends no
motion when the vehicle's heartbeat has been silent for `heartbeat_timeout_s` (link lost)
or when the pilot has switched to another mode (we never switch back ourselves).
"""

from __future__ import annotations

import atexit
import enum
import errno
import functools
import logging
import math
import socket
import threading
import time
from collections import deque
from collections.abc import Callable

from pymavlink import mavutil

from follow.config import ConfigError, MavlinkConfig
from follow.control import mavlink_frames as mf
from follow.types import Odometry, VelocityCommand

log = logging.getLogger(__name__)
mavlink = mavutil.mavlink

# How much longer than the settle time (odometry_timeout_s) connecting waits for steady
# telemetry before it leaves the robot to stand until odometry comes.
ODOMETRY_WAIT_MARGIN_S = 1.0
# How long `close` waits for a write under way before each of its zeros (a write that
# hangs longer is given up on: the threads are stopped and the connection closed anyway).
CLOSE_SEND_WAIT_S = 0.5
# Boot-time counters that jump back by more than this are a vehicle reboot, not reordering.
_REBOOT_JUMP_MS = 10_000
# How far the vehicle's clock may seem to run ahead of ours across a window of telemetry
# through receive jitter alone (the window's first message late, its last one early).
_TELEMETRY_JITTER_S = 0.03
# Messages of one type kept for that window, at most (it spans odometry_timeout_s: 400 at
# 200 Hz over 2 s). Past it the oldest go, and a window too short raises nothing.
_TELEMETRY_WINDOW_MAX = 1024
# Vehicles that run Rover firmware (ArduPilot Rover drives boats too; a PX4 rover is a
# ground rover): another type's mode numbers mean other modes (ArduCopter's 15 is
# AUTOTUNE, not GUIDED), so it is refused.
ROVER_TYPES = frozenset({mavlink.MAV_TYPE_GROUND_ROVER, mavlink.MAV_TYPE_SURFACE_BOAT})
# The autopilot each `[mavlink] autopilot` drives: mode numbers are the autopilot's own
# (PX4's OFFBOARD, main mode 6, is ArduPilot Rover's FOLLOW), so another one is refused.
AUTOPILOTS = {"ardupilot": mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA, "px4": mavlink.MAV_AUTOPILOT_PX4}
_ERROR_LOG_S = 5.0  # a failing link is logged at most this often (each direction)
_ACK_RETRIES = 3
# How long a heartbeat may take to show what an accepted command changed (mode, arming),
# at the least: ArduPilot reports it in its next 1 Hz heartbeat, or the one after if one
# is lost.
HEARTBEAT_CONFIRM_S = 2.5


class LinkState(str, enum.Enum):
    CONNECTING = "connecting"
    ACTIVE = "active"  # vehicle in our mode, commands go out
    MODE_OVERRIDDEN = "mode_overridden"  # the pilot chose another mode: we stay quiet
    LINK_LOST = "link_lost"  # no vehicle heartbeat within heartbeat_timeout_s
    CLOSED = "closed"


class MavlinkError(RuntimeError):
    """The vehicle could not be reached or refused what the driver needs."""


def check_mavlink_config(config: MavlinkConfig) -> None:
    """The ranges a loaded configuration is held to (follow/config_bounds.py), for a
    driver built from a MavlinkConfig made in code: a command time-out of minutes would
    let the vehicle drive on a command nobody renews."""
    from follow.config_bounds import section_errors

    if not config.connection:
        raise ConfigError("[mavlink] connection is empty (e.g. 'udpin:0.0.0.0:14550')")
    if errors := section_errors("mavlink", config):
        raise ConfigError("; ".join(errors))


def _datagram_sender(data: bytes) -> tuple[int, int] | None:
    """(system, component) of the first MAVLink message in a datagram, from its header."""
    if len(data) > 6 and data[0] == mavlink.PROTOCOL_MARKER_V2:
        return data[5], data[6]
    if len(data) > 4 and data[0] == mavlink.PROTOCOL_MARKER_V1:
        return data[3], data[4]
    return None


def _message_type(msg) -> str:
    """A message's type for a log line, whatever the message object is."""
    try:
        return str(msg.get_type())
    except Exception:
        return type(msg).__name__


class MavlinkBase:
    """A `Base` over MAVLink. Connects, sets the mode and starts streaming on construction;
    raises MavlinkError when the vehicle does not answer or refuses the mode."""

    def __init__(self, config: MavlinkConfig, clock: Callable[[], float] = time.monotonic):
        check_mavlink_config(config)
        self.config = config
        self._clock = clock
        self._px4 = config.autopilot == "px4"
        self._lock = threading.Lock()
        self._send_lock = threading.Lock()
        self._changed = threading.Condition(self._lock)
        self._wake = threading.Event()
        self._stop = threading.Event()
        self._state = LinkState.CONNECTING
        self._target: tuple[int, int] | None = None
        self._heartbeat = None  # newest vehicle HEARTBEAT
        self._heartbeat_at_s = -math.inf
        # type -> (message, its time on our clock, received at)
        self._newest: dict[str, tuple[object, float, float]] = {}
        self._boot_offset_s: float | None = None  # our clock minus the vehicle's boot clock
        # type -> (received at, time_boot_ms in s) of its recent messages, oldest first
        self._telemetry_windows: dict[str, deque[tuple[float, float]]] = {}
        self._boot_offset_proven = False  # a steady window came since it was learnt
        self._boot_clock_since_s = -math.inf  # when the vehicle's current clock was learnt
        self._acks: dict[int, tuple[int, float]] = {}  # command id -> (result, received at)
        self._command: tuple[VelocityCommand, float] | None = None
        self._engaged = False  # we have put the vehicle in our mode
        self._lost_while_active = False  # the link went while we were commanding the vehicle
        self._closed = False  # close() has run (emergency_stop leaves it to do)
        self._prestream = False  # PX4: stream setpoints before asking for OFFBOARD
        self.last_error: str | None = None
        self.setpoints_sent = 0
        self._other_vehicle: str | None = None  # why the autopilot heard cannot be driven
        self._receive_error_logged_s = -math.inf
        self._send_error_logged_s = -math.inf
        self._send_unlogged = 0  # failed sender ticks not reported yet
        self._arm_sent = False  # we asked the vehicle to arm (a failed connect disarms it)
        # UDP: (system, component) -> the address it last sent a datagram from
        self._udp_senders: dict[tuple[int, int], tuple[str, int]] = {}
        try:
            # autoreconnect: a TCP peer or USB serial adapter that goes and comes back
            # (a router or SITL restart, a loose cable) is reopened by pymavlink instead
            # of failing every read for good.
            self._conn = mavutil.mavlink_connection(
                config.connection,
                source_system=config.source_system,
                source_component=config.source_component,
                autoreconnect=True,
            )
        except (OSError, ValueError, OverflowError) as exc:  # unknown host, port in use, no
            # such device, a malformed string ("udpin:0.0.0.0" without a port), a port
            # beyond 65535 (the socket's OverflowError)
            raise MavlinkError(f"MAVLink connection {config.connection!r}: {exc}") from exc
        self._install_transport()
        self._receiver = threading.Thread(target=self._receive_loop, name="mavlink-rx", daemon=True)
        self._sender = threading.Thread(target=self._send_loop, name="mavlink-tx", daemon=True)
        self._receiver.start()
        self._sender.start()
        atexit.register(self.close)  # a zero command even if the caller forgets close()
        try:
            self._connect()
        except BaseException:
            try:
                self._disarm_after_failed_connect()
            finally:  # a second Ctrl-C must not keep the threads going
                self.close()
            raise

    # -- Base protocol ----------------------------------------------------------------

    def send(self, cmd: VelocityCommand) -> VelocityCommand:
        """Replace the command being streamed; a stop goes out at once. Returns zero in
        place of a moving command while the vehicle will not move on it (link lost, the
        pilot's mode, disarmed): the controller then speeds up from rest once it may,
        and nothing stale is kept to go out when the vehicle is back."""
        with self._lock:
            if self._state is LinkState.CLOSED:
                raise MavlinkError("send() on a closed MavlinkBase")
            self._check_link_locked()
            if not cmd.is_stop and not (self._state is LinkState.ACTIVE and self._armed_locked()):
                cmd = VelocityCommand.stop(cmd.stamp_s)
            self._command = (cmd, self._clock())
        self._wake.set()
        return cmd

    def odometry(self) -> Odometry | None:
        """Pose from the newest LOCAL_POSITION_NED and ATTITUDE, stamped with the older
        time of the two (their own time, `_telemetry_stamp_locked`); None when either is
        missing, older than odometry_timeout_s or not finite (an estimator without a
        solution), or while the vehicle's clock is not yet known (until telemetry has
        come steadily for odometry_timeout_s, at the start and after a reboot)."""
        with self._lock:
            pos = self._newest.get("LOCAL_POSITION_NED")
            att = self._newest.get("ATTITUDE")
            proven = self._boot_offset_proven
        if pos is None or att is None or not proven:
            return None
        stamp = min(pos[1], att[1])
        if self._clock() - stamp > self.config.odometry_timeout_s:
            return None
        x, y, yaw = mf.ned_pose_to_odom(pos[0].x, pos[0].y, att[0].yaw)
        if not all(math.isfinite(v) for v in (x, y, yaw)):
            return None  # no pose, never an exception that ends the run
        return Odometry(x, y, yaw, stamp)

    def healthy(self) -> bool:
        """Link up, vehicle in our mode and armed."""
        with self._lock:
            self._check_link_locked()
            return self._state is LinkState.ACTIVE and self._armed_locked()

    def close(self) -> None:
        """Send zero velocity (a few times, UDP may drop one), stop the threads, close;
        after `emergency_stop` too."""
        with self._lock:
            if self._closed:
                return
            self._closed = True
            was_connected = self._target is not None
            self._state = LinkState.CLOSED
        atexit.unregister(self.close)
        if was_connected:
            failure = self._send_zeros(
                functools.partial(self._send_setpoint, lock_timeout_s=CLOSE_SEND_WAIT_S),
                pause_s=0.01,
            )
            if failure is not None:  # a port gone: the threads must stop all the same
                self.last_error = f"send failed while closing: {failure}"
                log.error("MAVLink %s", self.last_error)
        self._stop.set()
        self._wake.set()
        for thread in (self._sender, self._receiver):
            if thread.is_alive() and thread is not threading.current_thread():
                thread.join(timeout=1.0)
        self._close_link()

    def _close_link(self) -> None:
        """The link's own close, which must not fail `close` after its zeros went out:
        pymavlink's TCP close raises AttributeError while a failed reconnect left it no
        socket, a port already gone raises OSError."""
        try:
            self._conn.close()
        except (OSError, AttributeError) as exc:
            log.info("MAVLink: the link was already closed (%s)", exc)

    def emergency_stop(self) -> None:
        """Zero setpoints now, from any thread, taking no lock that the interrupted main
        thread may hold (the second signal's path, `follow.shutdown`): from here on the
        sender streams nothing moving, and a few zeros go out at once. A zero that fails
        to send is raised as MavlinkError, after the others were tried. `close` still
        stops the threads and closes the connection afterwards."""
        self._state = LinkState.CLOSED  # read by the sender under its lock: no more motion
        self._command = (VelocityCommand.stop(self._clock()), self._clock())
        if self._target is None:
            return
        got = self._send_lock.acquire(timeout=0.2)  # held by the interrupted code: go on
        try:
            failure = self._send_zeros(self._write_setpoint)
        finally:
            if got:
                self._send_lock.release()
        if failure is not None:
            self.last_error = f"send failed during emergency stop: {failure}"
            raise MavlinkError(self.last_error) from failure

    def __enter__(self) -> MavlinkBase:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # -- status -------------------------------------------------------------------------

    @property
    def state(self) -> LinkState:
        with self._lock:
            self._check_link_locked()
            return self._state

    @property
    def armed(self) -> bool:
        with self._lock:
            return self._armed_locked()

    @property
    def vehicle_mode(self) -> int | None:
        with self._lock:
            return None if self._heartbeat is None else self._heartbeat.custom_mode

    def status(self) -> dict:
        with self._lock:
            self._check_link_locked()
            return {
                "state": self._state.value,
                "vehicle_mode": None if self._heartbeat is None else self._heartbeat.custom_mode,
                "armed": self._armed_locked(),
                "heartbeat_age_s": self._clock() - self._heartbeat_at_s,
                "setpoints_sent": self.setpoints_sent,
                "last_error": self.last_error,
            }

    # -- connection ---------------------------------------------------------------------

    def _connect(self) -> None:
        cfg = self.config
        deadline = self._clock() + cfg.connect_timeout_s
        with self._lock:
            while self._heartbeat is None:
                if self._other_vehicle is not None:
                    raise MavlinkError(f"the autopilot on {cfg.connection} {self._other_vehicle}")
                if not self._changed.wait(timeout=max(0.0, deadline - self._clock())):
                    if self._heartbeat is None and self._other_vehicle is None:
                        # a send that fails (a port or network refused) is why, if any
                        failing = f"; {self.last_error}" if self.last_error else ""
                        raise MavlinkError(
                            f"no vehicle heartbeat on {cfg.connection} within "
                            f"{cfg.connect_timeout_s} s{failing}"
                        )
        log.info("vehicle %s found on %s", self._target, cfg.connection)
        interval_us = 1e6 / cfg.telemetry_rate_hz
        for msg_id in (mf.MSG_ID_LOCAL_POSITION_NED, mf.MSG_ID_ATTITUDE):
            result = self._command_long(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, msg_id, interval_us)
            if result != mavlink.MAV_RESULT_ACCEPTED:
                log.warning("message interval for id %d not accepted (result %s)", msg_id, result)
        if self._px4:
            self._prestream = True  # OFFBOARD needs setpoints flowing before the switch
            time.sleep(1.0)
        custom_mode = (
            mf.px4_custom_mode(mf.PX4_MAIN_MODE_OFFBOARD) if self._px4 else mf.ROVER_MODE_GUIDED
        )
        params = (
            (mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, mf.PX4_MAIN_MODE_OFFBOARD, 0)
            if self._px4
            else (mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, mf.ROVER_MODE_GUIDED)
        )
        self._require(mavlink.MAV_CMD_DO_SET_MODE, "mode change", *params)
        self._await_heartbeat(
            self._in_our_mode_locked,
            lambda: (
                f"mode change acknowledged but the heartbeat still reports mode "
                f"{self._heartbeat.custom_mode}, not {custom_mode}"
            ),
        )
        # Armed only once in our mode: a vehicle that refuses the mode (ArduPilot without a
        # position estimate) is left as it was, not armed in the pilot's mode.
        if cfg.arm and not self.armed:
            self._arm_sent = True
            self._require(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, "arm", 1)
            self._await_heartbeat(
                self._armed_locked,
                lambda: "arming acknowledged but the heartbeat still reports the vehicle disarmed",
            )
        elif not self.armed:
            log.warning(
                "vehicle is disarmed and arm=false: it will not move until the pilot arms it"
            )
        with self._lock:
            self._engaged = True
            self._prestream = False
            self._state = LinkState.ACTIVE
        log.info(
            "vehicle in %s; streaming velocity setpoints", "OFFBOARD" if self._px4 else "GUIDED"
        )
        self._wait_for_odometry()

    def _wait_for_odometry(self) -> None:
        """Wait, at most `odometry_timeout_s` + ODOMETRY_WAIT_MARGIN_S, until the
        vehicle's telemetry has proven its clock (`_telemetry_stamp_locked`), so that the
        caller's first `odometry()` is not None: a control loop started sooner stops the
        robot and reports odometry lost at every start, and sets off behind the target.
        A vehicle that does not stream telemetry is logged and left to the control loop,
        which keeps the robot still without odometry."""
        proven = self._wait_until(
            lambda: self._boot_offset_proven and len(self._newest) == 2,
            self.config.odometry_timeout_s + ODOMETRY_WAIT_MARGIN_S,
        )
        if not proven:
            log.warning(
                "no steady LOCAL_POSITION_NED and ATTITUDE from the vehicle yet: "
                "the robot stays still until there is odometry"
            )

    def _wait_until(self, done: Callable[[], bool], wait_s: float) -> bool:
        """Wait until `done()` (called under the lock) holds, `wait_s` of real time at
        most, whatever clock stamps the telemetry (a test's may stand still); whether it
        held."""
        deadline = time.monotonic() + wait_s
        with self._lock:
            while not done():
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    return False
                self._changed.wait(timeout=remaining)
        return True

    def _await_heartbeat(self, done: Callable[[], bool], failure: Callable[[], str]) -> None:
        """Wait until the vehicle's heartbeat shows what an accepted command asked for
        (`done`, called under the lock), or raise MavlinkError(`failure()`). The wait has
        its own deadline, `connect_timeout_s` but at least HEARTBEAT_CONFIRM_S: lost ACKs
        before the command (retried) must not use it up and fail a change that was made."""
        if not self._wait_until(done, max(self.config.connect_timeout_s, HEARTBEAT_CONFIRM_S)):
            with self._lock:
                raise MavlinkError(failure())

    def _disarm_after_failed_connect(self) -> None:
        """A connect that fails after asking the vehicle to arm (its ACK or heartbeat
        lost, an interrupt) disarms it: nothing is going to command it."""
        if not self._arm_sent:
            return
        try:
            result = self._command_long(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 0)
        except MavlinkError as exc:
            result = exc
        if result == mavlink.MAV_RESULT_ACCEPTED:
            log.warning("connecting failed after asking the vehicle to arm: disarmed it again")
        else:
            reason = "no acknowledgement" if result is None else result
            log.error("connecting failed after asking the vehicle to arm, and disarming it "
                      "failed (%s): it may still be armed", reason)  # fmt: skip

    def _require(self, command: int, what: str, *params: float) -> None:
        result = self._command_long(command, *params)
        if result != mavlink.MAV_RESULT_ACCEPTED:
            reason = "no acknowledgement" if result is None else f"result {result}"
            raise MavlinkError(f"vehicle refused {what} ({reason})")

    def _command_long(self, command: int, *params: float) -> int | None:
        """Send COMMAND_LONG and wait for its COMMAND_ACK, resending on silence. Only an
        ACK received after the command was sent answers it (`_on_message` keeps only
        those addressed to us)."""
        params = tuple(params) + (0.0,) * (7 - len(params))
        per_try_s = self.config.connect_timeout_s / _ACK_RETRIES
        for attempt in range(_ACK_RETRIES):
            sent_s = self._clock()
            try:
                with self._send_lock:
                    self._conn.mav.command_long_send(*self._target, command, attempt, *params)
            except OSError as exc:
                raise MavlinkError(f"sending command {command} failed: {exc}") from exc
            deadline = sent_s + per_try_s
            with self._lock:
                while True:
                    result, received_s = self._acks.get(command, (None, -math.inf))
                    if received_s >= sent_s:
                        del self._acks[command]
                        return result
                    remaining = deadline - self._clock()
                    if remaining <= 0 or self._stop.is_set():
                        break
                    self._changed.wait(timeout=remaining)
        return None

    # -- transport ------------------------------------------------------------------------

    def _install_transport(self) -> None:
        """Writes that raise on failure, so that the sender's log, close()'s log and
        emergency_stop()'s MavlinkError hear of it: pymavlink's UDP and TCP writes drop
        OSError and its serial write returns -1. And a `udpin` link that sends to the
        vehicle only: pymavlink's sends to every address that ever sent it a datagram,
        kept for ever."""
        conn = self._conn
        if isinstance(conn, mavutil.mavudp):
            conn.recv, conn.write = self._udp_recv, self._udp_write
        elif isinstance(conn, mavutil.mavtcp | mavutil.mavtcpin):
            conn.write = self._tcp_write
        elif isinstance(conn, mavutil.mavserial):
            serial_write = conn.write

            def checked_write(buf) -> None:
                written = serial_write(buf)
                if written is not None and written < len(buf):
                    raise OSError(f"write to {conn.device} failed "
                                  f"({written} of {len(buf)} bytes)")  # fmt: skip

            conn.write = checked_write

    def _udp_recv(self, n=None) -> bytes:
        """One datagram (b"" when none waits), noting the address of the sender of its first
        message (at most one per system and component id)."""
        try:
            data, address = self._conn.port.recvfrom(mavutil.UDP_MAX_PACKET_LEN)
        except (BlockingIOError, ConnectionRefusedError):
            return b""
        sender = _datagram_sender(data)
        if sender is not None:
            self._udp_senders[sender] = address
        return data

    def _udp_write(self, buf) -> None:
        """One datagram, raising what the socket raises. `udpin` sends only to the address
        the vehicle sends from (nothing before it is heard), `udpbcast` there
        once it is heard, `udpout` to the address configured."""
        conn, target = self._conn, self._target
        vehicle = None if target is None else self._udp_senders.get(tuple(target))
        if conn.udp_server or (conn.broadcast and vehicle is not None):
            if vehicle is None:
                return
            address = vehicle
        else:
            host, port = conn.destination_addr
            if host != conn.resolved_destination_addr:  # a host name, resolved once
                conn.destination_addr = (socket.gethostbyname(host), port)
                conn.resolved_destination_addr = conn.destination_addr[0]
            address = conn.destination_addr
        conn.port.sendto(buf, address)

    def _tcp_write(self, buf) -> None:
        """All of `buf` on the stream, or raise what the socket raises, a short write
        too (pymavlink's write drops both and a message cut short garbles the next one
        for the vehicle). A connection gone is not reopened here but by the receiver
        (pymavlink's `autoreconnect` on EOF, a reset or no socket): a reconnect from
        this thread too raced it, and held the send lock through seconds of retries.
        `tcpin` (we listen, the vehicle connects) drops a connection whose pipe broke, as
        pymavlink does, so that its receiver accepts the vehicle's next one.
        MSG_DONTWAIT: the socket of a reconnect under way blocks until it connects."""
        conn = self._conn
        port = conn.port
        listening = isinstance(conn, mavutil.mavtcpin)
        if port is None and listening and self._target is None:
            return  # tcpin before any vehicle was heard: nobody to send to (as udpin)
        if port is None:  # tcp: the last reconnect failed; tcpin: the vehicle went away
            why = "no vehicle connected" if listening else "reconnecting"
            raise OSError(errno.ENOTCONN, f"{conn.address} not connected ({why})")
        try:
            sent = port.send(buf, getattr(socket, "MSG_DONTWAIT", 0))
        except BrokenPipeError:
            if listening and conn.port is port:  # not one the receiver accepted since
                port.close()
                conn.port, conn.fd = None, conn.listen.fileno()
            raise
        if sent < len(buf):
            raise OSError(f"write to {conn.address} failed ({sent} of {len(buf)} bytes)")

    # -- receiving ------------------------------------------------------------------------

    def _receive_loop(self) -> None:
        while not self._stop.is_set():
            try:
                msg = self._conn.recv_match(blocking=True, timeout=0.05)
            except Exception as exc:  # socket closed under us, a port gone, pymavlink's
                # TCP reconnect raced by the sender's (AttributeError on a port gone None):
                # the thread must go on, or the link looks lost for good once it is back
                if not self._stop.is_set():
                    now = time.monotonic()
                    if now - self._receive_error_logged_s >= _ERROR_LOG_S:
                        self._receive_error_logged_s = now
                        log.error("MAVLink receive failed (retrying): %s: %s",
                                  type(exc).__name__, exc)  # fmt: skip
                    time.sleep(0.05)
                continue
            if msg is not None:
                self._handle(msg)

    def _handle(self, msg) -> None:
        """One message through `_on_message`; one it cannot handle is dropped with an
        error naming it, and the receiver goes on. An exception here used to end the
        receiver thread: the heartbeat and odometry went stale (the robot stopped) and
        the log said only "link lost" seconds later, for a link still working."""
        try:
            self._on_message(msg)
        except Exception as exc:
            now = time.monotonic()
            if now - self._receive_error_logged_s >= _ERROR_LOG_S:
                self._receive_error_logged_s = now
                log.error("MAVLink message %s not handled, dropped: %s: %s",
                          _message_type(msg), type(exc).__name__, exc)  # fmt: skip

    def _on_message(self, msg) -> None:
        kind = msg.get_type()
        if kind == "BAD_DATA":
            return
        now = self._clock()
        with self._lock:
            if kind == "HEARTBEAT":
                if (
                    msg.autopilot == mavlink.MAV_AUTOPILOT_INVALID
                    or msg.get_srcComponent() != mavlink.MAV_COMP_ID_AUTOPILOT1
                ):
                    return  # a ground station, companion or peripheral, not the autopilot
                if self._target is None and msg.type not in ROVER_TYPES:
                    self._other_vehicle = (
                        f"is no rover (MAV_TYPE {msg.type}; follow drives ArduPilot Rover or "
                        "PX4 rovers: ground rover or boat)"
                    )
                    self._changed.notify_all()
                    return
                if self._target is None and msg.autopilot != AUTOPILOTS[self.config.autopilot]:
                    self._other_vehicle = (
                        f"is not the configured autopilot {self.config.autopilot!r} "
                        f"(MAV_AUTOPILOT {msg.autopilot}; set [mavlink] autopilot)"
                    )
                    self._changed.notify_all()
                    return
                if self._target is None:
                    self._target = (msg.get_srcSystem(), msg.get_srcComponent())
                if (msg.get_srcSystem(), msg.get_srcComponent()) != self._target:
                    return
                was_armed = self._armed_locked()
                self._heartbeat, self._heartbeat_at_s = msg, now
                self._on_heartbeat_locked(was_armed)
            elif (
                self._target is None
                or (msg.get_srcSystem(), msg.get_srcComponent()) != self._target
            ):
                return  # another vehicle, or another component of ours (a gimbal's ATTITUDE)
            elif kind == "COMMAND_ACK":
                # MAVLink 2 names whom an ACK answers: one to a ground station's command
                # (the same command id) is not ours; 0 (MAVLink 1, unset) may be anyone's.
                to = (getattr(msg, "target_system", 0), getattr(msg, "target_component", 0))
                if to[0] not in (0, self.config.source_system) or (
                    to[1] not in (0, self.config.source_component)
                ):
                    return
                self._acks[msg.command] = (msg.result, now)
            elif kind in ("LOCAL_POSITION_NED", "ATTITUDE"):
                previous = self._newest.get(kind)
                if previous is not None:
                    back_ms = previous[0].time_boot_ms - msg.time_boot_ms
                    if 0 <= back_ms < _REBOOT_JUMP_MS:
                        return  # reordered or repeated: keep the newer one
                stamp = self._telemetry_stamp_locked(kind, msg, now, previous)
                self._newest[kind] = (msg, stamp, now)
            else:
                return
            self._changed.notify_all()

    def _telemetry_stamp_locked(self, kind: str, msg, received_s: float, previous) -> float:
        """When `msg` was produced, on our clock: its `time_boot_ms` plus the offset of
        the vehicle's clock to ours (our clock minus its boot clock). Its receipt time
        would make a backlog (messages a link held while it was down) as fresh as live
        data. The offset is
        - learnt from the first message, and anew after a vehicle reboot, but trusted
          (`odometry` gives nothing before) only once a window, as below, has come:
          the first messages heard may be a backlog too;
        - lowered by any message with a smaller offset: it came here a shorter way, so
          the offset is at most that;
        - raised (a vehicle clock slower than ours: a simulator below real time, or
          paused and resumed) only to the smallest offset among the recent messages of
          this type, and only once they make a window that spans at least the settle
          time (`odometry_timeout_s`) on our clock, with no gap longer than
          `odometry_timeout_s` between two of them, across which the vehicle's clock
          advanced no more than ours (plus `_TELEMETRY_JITTER_S`).
        A backlog being drained arrives faster than it was produced, its delay
        shrinking, so no window over it qualifies, whether it comes at once or in bursts
        (a radio packing several messages a frame): a rule over one pair of messages
        was fooled by the first message after each pause between bursts, which looks
        live. The smallest offset of the window is taken, not the newest: the window's
        quickest message counts as undelayed, each other one as late as it was behind
        it. The settle time is `odometry_timeout_s`: the window lags a vehicle clock
        running at a fraction r of our rate by (1 - r) of it, so a simulator at half
        real time stays well within the time-out; a shorter one would let slower drains
        pass (a drain is refused when it outruns our clock by more than
        `_TELEMETRY_JITTER_S` per settle time), a longer one would keep odometry away
        longer after a pause. What is left is what no receiver can tell without a round
        trip (MAVLink TIMESYNC): a link whose delay has stayed steady, or grown, for the
        settle time counts as live, however long the delay."""
        boot_s = msg.time_boot_ms / 1000.0
        offset_s = received_s - boot_s
        settle_s = timeout_s = self.config.odometry_timeout_s
        # A jump back from a message of the current clock; one from a message heard before
        # it was learnt (a position back after the reboot that the attitude told of) is
        # that reboot, already known.
        rebooted = (
            previous is not None
            and previous[0].time_boot_ms > msg.time_boot_ms
            and previous[2] >= self._boot_clock_since_s
        )
        if rebooted:  # a new vehicle clock: no window of the old one proves it
            for window in self._telemetry_windows.values():
                window.clear()
        window = self._telemetry_windows.setdefault(kind, deque(maxlen=_TELEMETRY_WINDOW_MAX))
        if window and received_s - window[-1][0] > timeout_s:
            window.clear()  # a gap: the steady run starts again
        window.append((received_s, boot_s))
        while len(window) > 1 and window[1][0] <= received_s - settle_s:
            window.popleft()  # keep one message at least settle_s old, none older
        if self._boot_offset_s is None or rebooted:
            self._boot_offset_s, self._boot_offset_proven = offset_s, False
            self._boot_clock_since_s = received_s
        elif offset_s < self._boot_offset_s:
            self._boot_offset_s = offset_s
        first_received_s, first_boot_s = window[0]
        ours_s = received_s - first_received_s
        if ours_s >= settle_s and boot_s - first_boot_s <= ours_s + _TELEMETRY_JITTER_S:
            smallest_s = min(r - b for r, b in window)
            self._boot_offset_s = max(self._boot_offset_s, smallest_s)
            self._boot_offset_proven = True
        return boot_s + self._boot_offset_s

    def _on_heartbeat_locked(self, was_armed: bool) -> None:
        if self._state is LinkState.LINK_LOST:
            self._state = LinkState.ACTIVE if self._engaged else LinkState.CONNECTING
            log.warning("vehicle heartbeat back: link restored")
        if not self._engaged:
            return
        # A disarm (the pilot, a failsafe) zeroes what send() passes on: said, not silent.
        armed = self._armed_locked()
        if was_armed and not armed:
            self.last_error = "vehicle disarmed"
            log.warning("%s: only zero setpoints go out until it is armed again",
                        self.last_error)  # fmt: skip
        elif armed and not was_armed:
            log.warning("vehicle armed: commands go out to it again")
        in_mode = self._in_our_mode_locked()
        if self._state is LinkState.ACTIVE and not in_mode:
            self._state = LinkState.MODE_OVERRIDDEN
            self.last_error = f"pilot switched the vehicle to mode {self._heartbeat.custom_mode}"
            log.warning("%s: no longer commanding it", self.last_error)
        elif self._state is LinkState.MODE_OVERRIDDEN and in_mode:
            self._state = LinkState.ACTIVE
            log.warning("vehicle back in our mode: commanding again")

    def _in_our_mode_locked(self) -> bool:
        mode = self._heartbeat.custom_mode
        if self._px4:
            return mf.px4_main_mode(mode) == mf.PX4_MAIN_MODE_OFFBOARD
        return mode == mf.ROVER_MODE_GUIDED

    def _armed_locked(self) -> bool:
        hb = self._heartbeat
        return hb is not None and bool(hb.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED)

    def _check_link_locked(self) -> None:
        if self._state in (LinkState.CLOSED, LinkState.LINK_LOST) or self._heartbeat is None:
            return
        silent_s = self._clock() - self._heartbeat_at_s
        if silent_s > self.config.heartbeat_timeout_s:
            self._lost_while_active = self._state is LinkState.ACTIVE
            self._state = LinkState.LINK_LOST
            self.last_error = f"no vehicle heartbeat for {silent_s:.1f} s: link lost"
            log.error("%s; motion commands stopped", self.last_error)

    # -- sending ------------------------------------------------------------------------

    def _send_loop(self) -> None:
        period_s = 1.0 / self.config.stream_rate_hz
        next_heartbeat_s = -math.inf
        while not self._stop.is_set():
            self._wake.wait(timeout=period_s)
            self._wake.clear()
            if self._stop.is_set():
                break
            now = self._clock()
            try:
                if now >= next_heartbeat_s:
                    next_heartbeat_s = now + 1.0
                    with self._send_lock:
                        self._conn.mav.heartbeat_send(
                            mavlink.MAV_TYPE_ONBOARD_CONTROLLER, mavlink.MAV_AUTOPILOT_INVALID,
                            0, 0, mavlink.MAV_STATE_ACTIVE,
                        )  # fmt: skip
                command = self._command_to_stream(now)
                if command is not None:
                    self._send_setpoint(command)
            except Exception as exc:  # keep the watchdog alive; report and go on
                self.last_error = f"send failed: {exc}"
                self._send_unlogged += 1
                self._report_send_failures(failing=True)
            else:
                if self._send_unlogged:
                    self._report_send_failures(failing=False)

    def _report_send_failures(self, failing: bool) -> None:
        """A link that fails every tick is logged at once, then at most once per
        `_ERROR_LOG_S` with the count of failed ticks since the last report, not once per
        tick; failures left unreported when sending works again are counted then."""
        now = time.monotonic()
        if now - self._send_error_logged_s < _ERROR_LOG_S:
            return
        self._send_error_logged_s = now
        failed, self._send_unlogged = self._send_unlogged, 0
        if not failing:
            log.warning("MAVLink sending works again; %d failed tick(s) since the last "
                        "report, the newest: %s", failed, self.last_error)  # fmt: skip
        elif failed == 1:
            log.error("MAVLink %s", self.last_error)
        else:
            log.error("MAVLink %s (%d failed ticks since the last report)",
                      self.last_error, failed)  # fmt: skip

    def _command_to_stream(self, now: float) -> VelocityCommand | None:
        """The command to send now, or None when we must not command the vehicle."""
        with self._lock:
            self._check_link_locked()
            if self._prestream and self._state is LinkState.CONNECTING:
                return VelocityCommand.stop(now)
            if self._state is LinkState.LINK_LOST and self._lost_while_active:
                # zero, not silence: a vehicle that still hears us (only its heartbeats
                # lost) stops now, not on its last moving setpoint at its own time-out
                return VelocityCommand.stop(now)
            if self._state is not LinkState.ACTIVE:
                return None
            if self._command is None or not self._armed_locked():
                return VelocityCommand.stop(now)  # disarmed: nothing to drive off on arming
            command, received_s = self._command
        if now - received_s > self.config.command_timeout_s:
            return VelocityCommand.stop(now)
        return command

    def _send_zeros(self, send: Callable[[VelocityCommand], None],
                    pause_s: float = 0.0) -> Exception | None:  # fmt: skip
        """Three zero setpoints through `send` (UDP may drop one), each tried whatever
        became of the one before; the last failure, or None."""
        failure = None
        for _ in range(3):
            try:
                send(VelocityCommand.stop(self._clock()))
            except Exception as exc:
                failure = exc
            time.sleep(pause_s)
        return failure

    def _send_setpoint(self, cmd: VelocityCommand, lock_timeout_s: float = -1.0) -> None:
        """One setpoint, after any write under way. `close` waits `lock_timeout_s` at most
        (negative: no limit) and raises MavlinkError past it: a serial port that stopped
        draining holds `_send_lock` for ever, and its threads must still be stopped and
        the connection closed."""
        if self._target is None:
            return
        if not self._send_lock.acquire(timeout=lock_timeout_s):
            raise MavlinkError(f"a write to the vehicle has not returned for "
                               f"{lock_timeout_s:g} s: the setpoint could not be sent")  # fmt: skip
        try:
            # A moving setpoint the sender took just before close() must not follow
            # close()'s zeros: closed is set before they are sent, under this lock.
            if self._state is LinkState.CLOSED and not cmd.is_stop:
                return
            self._write_setpoint(cmd)
        finally:
            self._send_lock.release()

    def _write_setpoint(self, cmd: VelocityCommand) -> None:
        """One SET_POSITION_TARGET_LOCAL_NED (the caller holds `_send_lock`, or cannot)."""
        if self._px4:
            vx, vy = mf.px4_setpoint(cmd, self.config.px4_turn_horizon_s)
            yaw_rate, mask, frame = 0.0, mf.TYPE_MASK_VELOCITY_ONLY, mavlink.MAV_FRAME_BODY_NED
        else:
            vx, vy, yaw_rate = mf.ardupilot_setpoint(cmd)
            mask, frame = mf.TYPE_MASK_VELOCITY_YAW_RATE, mavlink.MAV_FRAME_BODY_OFFSET_NED
        boot_ms = int(self._clock() * 1000) & 0xFFFFFFFF
        self._conn.mav.set_position_target_local_ned_send(
            boot_ms, *self._target, frame, mask,
            0, 0, 0, vx, vy, 0, 0, 0, 0, 0, yaw_rate,
        )  # fmt: skip
        self.setpoints_sent += 1
