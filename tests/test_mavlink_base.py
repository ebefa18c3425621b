"""MavlinkBase against the simulated rover over real UDP sockets on 127.0.0.1."""

import math
import threading
import time

import pytest
from pymavlink import mavutil
from waiting import wait_for

from follow.config import ConfigError, MavlinkConfig
from follow.control import mavlink_frames as mf
from follow.control.base import Base
from follow.control.mavlink_base import LinkState, MavlinkBase, MavlinkError
from follow.sim.rover import RoverLimits, SimRover
from follow.types import Odometry, VelocityCommand

FAST = dict(heartbeat_timeout_s=0.6, connect_timeout_s=2.0, odometry_timeout_s=0.3)


def drive(base, forward, yaw_rate, seconds, period_s=0.05):
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        base.send(VelocityCommand(forward, yaw_rate, time.monotonic()))
        time.sleep(period_s)


@pytest.fixture
def rover():
    with SimRover(heartbeat_rate_hz=5, limits=RoverLimits(guided_timeout_s=3.0)) as r:
        yield r


@pytest.fixture
def base(rover):
    with MavlinkBase(MavlinkConfig(connection=rover.connection, **FAST)) as b:
        yield b


def test_connect_sets_guided_requests_streams_and_never_arms_by_itself():
    with SimRover(heartbeat_rate_hz=5, armed=False) as rover:
        with MavlinkBase(MavlinkConfig(connection=rover.connection, **FAST)) as base:
            assert isinstance(base, Base)
            assert rover.mode == mf.ROVER_MODE_GUIDED and base.vehicle_mode == mf.ROVER_MODE_GUIDED
            assert base.state is LinkState.ACTIVE
            assert set(rover._intervals_s) == {mf.MSG_ID_ATTITUDE, mf.MSG_ID_LOCAL_POSITION_NED}
            assert rover._intervals_s[mf.MSG_ID_ATTITUDE] == pytest.approx(1 / 30)
            assert 400 not in rover.commands_received  # MAV_CMD_COMPONENT_ARM_DISARM
            assert not base.healthy()  # disarmed: commands would not move it
            drive(base, 1.0, 0.0, 0.3)
            assert rover.true_velocity() == (0.0, 0.0) and not rover.armed


def test_connecting_returns_with_odometry_ready():
    """The driver trusts the vehicle's clock only after a settle time of steady
    telemetry; connecting waits for it, so that a control loop started at once does not
    begin with the robot stopped for want of odometry."""
    with SimRover(heartbeat_rate_hz=5) as rover:
        with MavlinkBase(MavlinkConfig(connection=rover.connection, **FAST)) as base:
            assert base.odometry() is not None


def test_connecting_to_a_vehicle_without_telemetry_gives_up_waiting_and_stays_still(caplog):
    with SimRover(heartbeat_rate_hz=5) as rover:
        rover.telemetry_paused = True
        started = time.monotonic()
        with MavlinkBase(MavlinkConfig(connection=rover.connection, **FAST)) as base:
            waited_s = time.monotonic() - started
            assert base.odometry() is None
            assert "no steady LOCAL_POSITION_NED and ATTITUDE" in caplog.text
            assert waited_s < base.config.odometry_timeout_s + 1.0 + 2.0  # the wait is bounded


def test_arms_only_when_configured():
    with SimRover(heartbeat_rate_hz=5, armed=False) as rover:
        cfg = MavlinkConfig(connection=rover.connection, arm=True, **FAST)
        with MavlinkBase(cfg) as base:
            assert rover.armed and wait_for(base.healthy)


def test_streams_velocity_and_yaw_rate_setpoints_at_rate(rover, base):
    # The vehicle beats at 5 Hz in these tests so that a 0.6 s link timeout is meaningful.
    time.sleep(0.1)
    n0, heartbeats0 = len(rover.setpoint_log), rover.companion_heartbeats
    time.sleep(1.05)
    window = list(rover.setpoint_log)[n0:]
    assert len(window) >= 15  # >= 10 Hz with margin; configured 20 Hz
    assert {(frame, mask) for _, frame, mask in window} == {
        (9, 0x05C7)  # MAV_FRAME_BODY_OFFSET_NED, velocity + yaw rate
    }
    assert rover.setpoints_ignored == 0
    assert rover.companion_heartbeats - heartbeats0 in (1, 2)  # 1 Hz


def test_commands_move_the_rover_and_odometry_follows_in_odom_frame():
    start = Odometry(2.0, -1.0, 0.3, 0.0)
    with SimRover(heartbeat_rate_hz=5, start_pose=start) as rover:
        with MavlinkBase(MavlinkConfig(connection=rover.connection, **FAST)) as base:
            odo = base.odometry()
            assert wait_for(lambda: base.odometry() is not None, 1.0)
            odo = base.odometry()
            assert (odo.x_m, odo.y_m, odo.yaw_rad) == pytest.approx((2.0, -1.0, 0.3), abs=1e-4)
            drive(base, 0.8, 0.4, 1.5)  # forward and counter-clockwise (left)
            forward, yaw_rate = rover.true_velocity()
            assert forward == pytest.approx(0.8) and yaw_rate == pytest.approx(0.4)
            truth, odo = rover.true_pose(), base.odometry()
            assert truth.yaw_rad > 0.3 + 0.4 and truth.y_m > -1.0  # turned and drove left
            assert math.hypot(truth.x_m - odo.x_m, truth.y_m - odo.y_m) < 0.1
            assert abs(truth.yaw_rad - odo.yaw_rad) < 0.1
            assert time.monotonic() - odo.stamp_s < base.config.odometry_timeout_s


def test_a_stale_command_is_replaced_by_zero(rover, base):
    drive(base, 1.0, 0.0, 1.0)
    assert rover.true_velocity()[0] == pytest.approx(1.0)
    # No new command: after command_timeout_s the driver streams zero, long before the
    # vehicle's own 3 s timeout would stop it.
    assert wait_for(lambda: rover.true_velocity()[0] == 0.0, 1.5)


class _WakeOnly(threading.Event):
    """The sender's wake-up with its stream period taken away: while the sender waits on
    it, a setpoint goes out only when someone wakes the sender, never on the next tick."""

    def __init__(self):
        super().__init__()
        self.waiting = threading.Event()

    def wait(self, timeout=None):
        self.waiting.set()
        return super().wait()


def test_a_stop_goes_out_at_once(rover, base):
    """A stop does not wait for the next tick of the setpoint stream (up to 50 ms at
    20 Hz, the length of a control period): send() wakes the sender for it."""
    drive(base, 1.0, 0.5, 1.0)
    base._wake = wake = _WakeOnly()
    assert wake.waiting.wait(1.0)  # the sender waits for a wake-up; no tick will come
    sent = len(rover.setpoint_log)
    base.send(VelocityCommand.stop(time.monotonic()))
    assert wait_for(lambda: rover._target.speed_mps == 0.0 and len(rover.setpoint_log) > sent)


def test_link_cut_stops_motion_reports_it_and_odometry_goes_stale():
    # The vehicle stops on its own 1 s after its last setpoint here (ArduPilot: 3 s, checked
    # in the rover's own tests) to keep this test short.
    with SimRover(heartbeat_rate_hz=5, limits=RoverLimits(guided_timeout_s=1.0)) as rover:
        with MavlinkBase(MavlinkConfig(connection=rover.connection, **FAST)) as base:
            drive(base, 1.0, 0.0, 0.8)
            assert base.healthy() and base.odometry() is not None
            rover.cut_link()
            t0 = time.monotonic()
            assert wait_for(lambda: base.odometry() is None, 1.0)  # stale odometry not returned
            assert wait_for(lambda: base.state is LinkState.LINK_LOST, 2.0)
            assert time.monotonic() - t0 < base.config.heartbeat_timeout_s + 0.3
            assert not base.healthy() and "link lost" in base.status()["last_error"]
            written, write = [], base._write_setpoint
            base._write_setpoint = lambda cmd: (written.append(cmd), write(cmd))
            drive(base, 1.0, 0.0, 0.3)
            assert written and all(c.is_stop for c in written)  # zero, no motion, into a lost link
            assert wait_for(lambda: rover.true_velocity()[0] == 0.0, 1.5)
            rover.cut_link(False)
            assert wait_for(lambda: base.state is LinkState.ACTIVE, 1.0)


def test_pilot_mode_switch_is_not_fought(rover, base):
    drive(base, 1.0, 0.0, 0.5)
    rover.pilot_set_mode(mf.ROVER_MODE_MANUAL)
    assert wait_for(lambda: base.state is LinkState.MODE_OVERRIDDEN, 1.0)
    assert not base.healthy() and "pilot" in base.status()["last_error"]
    sent = base.setpoints_sent
    drive(base, 1.0, 0.0, 0.5)
    assert base.setpoints_sent == sent
    assert rover.commands_received.count(176) == 1  # never asked for GUIDED again
    assert rover.mode == mf.ROVER_MODE_MANUAL and rover.true_velocity()[0] == 0.0


def test_close_sends_zero_velocity(rover):
    base = MavlinkBase(MavlinkConfig(connection=rover.connection, **FAST))
    drive(base, 1.0, 0.0, 0.6)
    base.close()
    assert rover._target.speed_mps == 0.0 or wait_for(lambda: rover._target.speed_mps == 0.0, 0.2)
    assert wait_for(lambda: rover.true_velocity()[0] == 0.0, 1.0)  # not the 3 s timeout
    with pytest.raises(MavlinkError, match="closed"):
        base.send(VelocityCommand.stop(0.0))
    base.close()  # idempotent


def test_a_moving_setpoint_taken_before_close_never_follows_its_zeros(rover):
    """The sender read a moving command just before close(), and lost the CPU (widened
    here to 0.1 s) before sending it: it must not go out after close()'s zeros."""
    base = MavlinkBase(MavlinkConfig(connection=rover.connection, **FAST))
    read_command = base._command_to_stream
    armed, in_hand = threading.Event(), threading.Event()

    def preempted_after_reading(now):
        command = read_command(now)
        if armed.is_set() and command is not None and not command.is_stop:
            in_hand.set()
            time.sleep(0.1)
        return command

    base._command_to_stream = preempted_after_reading
    drive(base, 1.0, 0.0, 0.6)
    armed.set()
    assert in_hand.wait(1.0)
    base.close()
    time.sleep(0.3)
    assert rover.last_setpoint[1] == 0.0  # the last forward speed it heard
    assert wait_for(lambda: rover.true_velocity()[0] == 0.0, 1.0)


def test_close_after_an_emergency_stop_still_closes_and_sends_only_zeros(rover):
    """emergency_stop (a second signal) marks the base closed; a close() after it must not
    take that for done: it neither raises nor sends anything moving, and it still stops
    the threads and closes the connection (they ran on, the socket open)."""
    base = MavlinkBase(MavlinkConfig(connection=rover.connection, **FAST))
    drive(base, 1.0, 0.0, 0.6)
    base.emergency_stop()
    base.close()
    assert not base._sender.is_alive() and not base._receiver.is_alive()
    time.sleep(0.2)
    assert rover.last_setpoint[1] == 0.0  # the last forward speed it heard
    assert wait_for(lambda: rover.true_velocity()[0] == 0.0, 1.0)
    base.close()  # idempotent


def test_one_failed_zero_neither_cancels_the_others_nor_goes_unreported(rover):
    """emergency_stop and close send three zeros (UDP may drop one): one that fails to
    send (a full buffer, a port that hiccups) must not end the stop there, and the
    failure is reported: emergency_stop raises it as MavlinkError, close logs it."""
    base = MavlinkBase(MavlinkConfig(connection=rover.connection, **FAST))
    drive(base, 1.0, 0.0, 0.6)
    write = base._conn.mav.set_position_target_local_ned_send
    written, failing = [], [True]

    def fails_once(*args):
        if threading.current_thread() is not threading.main_thread():
            return write(*args)  # the sender thread's own stream
        if failing[0]:
            failing[0] = False
            raise OSError("no buffer space")
        written.append(args)
        return write(*args)

    base._conn.mav.set_position_target_local_ned_send = fails_once
    with pytest.raises(MavlinkError, match="emergency stop: no buffer space"):
        base.emergency_stop()
    assert len(written) == 2 and "no buffer space" in base.last_error
    failing[0] = True
    base.close()
    assert len(written) == 4 and "while closing" in base.last_error
    assert all(args[8] == 0.0 and args[15] == 0.0 for args in written)  # vx, yaw rate
    assert wait_for(lambda: rover.true_velocity()[0] == 0.0, 1.0)


def test_close_returns_when_a_write_hangs(rover):
    """A serial port that stops draining blocks the sender in a write while it holds the
    send lock; close() waited for that lock for ever (and with it the run's cleanup). It
    now gives up on its zeros after a bounded wait, says so, and still stops its
    threads."""
    base = MavlinkBase(MavlinkConfig(connection=rover.connection, **FAST))
    drive(base, 0.5, 0.0, 0.3)
    wedged, release = threading.Event(), threading.Event()

    def hanging_write(buf):
        wedged.set()
        release.wait(30.0)

    base._conn.write = hanging_write
    assert wedged.wait(2.0) and base._send_lock.locked()
    closer = threading.Thread(target=base.close, daemon=True)
    started = time.monotonic()
    closer.start()
    closer.join(10.0)
    try:
        assert not closer.is_alive() and time.monotonic() - started < 5.0
        assert "has not returned" in base.last_error and "while closing" in base.last_error
    finally:
        release.set()


def test_exception_in_the_with_block_still_stops(rover):
    with pytest.raises(KeyError):
        with MavlinkBase(MavlinkConfig(connection=rover.connection, **FAST)) as base:
            drive(base, 1.0, 0.0, 0.8)
            raise KeyError("boom")
    assert wait_for(lambda: rover.true_velocity()[0] == 0.0, 1.0)


def test_survives_packet_loss_and_latency():
    with SimRover(heartbeat_rate_hz=5) as rover:
        rover.packet_loss, rover.latency_s = 0.2, 0.05
        with MavlinkBase(MavlinkConfig(connection=rover.connection, **FAST)) as base:
            drive(base, 0.6, 0.0, 1.0)
            assert rover.true_velocity()[0] == pytest.approx(0.6)
            assert base.state is LinkState.ACTIVE


def test_a_connection_that_cannot_be_opened_is_named():
    with pytest.raises(MavlinkError, match=r"MAVLink connection 'udpin:999\.0\.0\.1:14550'"):
        MavlinkBase(MavlinkConfig(connection="udpin:999.0.0.1:14550", **FAST))


def test_no_vehicle_and_bad_config_are_clear_errors():
    with SimRover(heartbeat_rate_hz=5) as rover:
        port = rover.port
    t0 = time.monotonic()
    with pytest.raises(MavlinkError, match="no vehicle heartbeat"):
        MavlinkBase(MavlinkConfig(connection=f"udpout:127.0.0.1:{port}", connect_timeout_s=0.5))
    assert time.monotonic() - t0 < 2.0
    with pytest.raises(ConfigError, match="connection is empty"):
        MavlinkBase(MavlinkConfig())
    with pytest.raises(ConfigError, match="stream_rate_hz"):
        MavlinkBase(MavlinkConfig(connection="udpout:127.0.0.1:1", stream_rate_hz=5.0))
    with pytest.raises(ConfigError, match="autopilot"):
        MavlinkBase(MavlinkConfig(connection="udpout:127.0.0.1:1", autopilot="pixhawk"))
    # a driver built in code is held to the loaded configuration's ranges: a command
    # time-out of minutes would let the vehicle drive on a command nobody renews
    with pytest.raises(ConfigError, match=r"command_timeout_s = 1000000000.0 is out of range"):
        MavlinkBase(MavlinkConfig(connection="udpout:127.0.0.1:1", command_timeout_s=1e9))


def test_only_the_newest_telemetry_is_used(rover, base):
    assert wait_for(lambda: base.odometry() is not None, 1.0)
    newest = base._newest["LOCAL_POSITION_NED"][0]
    late = mavutil.mavlink.MAVLink_local_position_ned_message(
        newest.time_boot_ms - 500, 50.0, 50.0, 0.0, 0.0, 0.0, 0.0
    )  # a delayed packet from half a second ago
    late._header = newest._header
    base._on_message(late)
    odo = base.odometry()
    assert abs(odo.x_m) < 1.0 and abs(odo.y_m) < 1.0


def test_px4_offboard_flow_against_a_px4_flavoured_rover():
    # The simulated PX4 rover refuses OFFBOARD unless setpoints already stream, ignores yaw
    # rate and drives along the velocity direction; this is a model of PX4, not PX4.
    with SimRover(heartbeat_rate_hz=5, autopilot="px4") as rover:
        cfg = MavlinkConfig(connection=rover.connection, autopilot="px4", **FAST)
        with MavlinkBase(cfg) as base:
            assert rover.mode == rover.commanded_mode and base.state is LinkState.ACTIVE
            assert {(f, m) for _, f, m in rover.setpoint_log} == {(8, 0x0DC7)}  # BODY_NED
            start = rover.true_pose()
            drive(base, 0.8, 0.6, 1.5)  # forward, turning left
            end = rover.true_pose()
            assert end.yaw_rad - start.yaw_rad > 0.2
            assert math.hypot(end.x_m - start.x_m, end.y_m - start.y_m) > 0.5
            rover.pilot_set_mode(mf.px4_custom_mode(1))  # MANUAL
            assert wait_for(lambda: base.state is LinkState.MODE_OVERRIDDEN, 1.0)
