"""The simulated rover speaks MAVLink like ArduPilot Rover (driven here by raw pymavlink)."""

import math
import time

import pytest
from pymavlink import mavutil
from waiting import wait_for

from follow.control import mavlink_frames as mf
from follow.sim.rover import RoverLimits, SimRover
from follow.types import Odometry

mavlink = mavutil.mavlink


class Companion:
    """A bare pymavlink link to the rover."""

    def __init__(self, rover):
        self.conn = mavutil.mavlink_connection(
            rover.connection, source_system=1, source_component=191
        )
        self.conn.mav.heartbeat_send(
            mavlink.MAV_TYPE_ONBOARD_CONTROLLER, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0
        )
        self.heartbeat = self.conn.recv_match(type="HEARTBEAT", blocking=True, timeout=2.0)
        assert self.heartbeat is not None, "no heartbeat from the simulated rover"

    def command(self, command, *params):
        params = tuple(params) + (0.0,) * (7 - len(params))
        self.conn.mav.command_long_send(1, 1, command, 0, *params)
        ack = self.conn.recv_match(type="COMMAND_ACK", blocking=True, timeout=2.0)
        assert ack is not None and ack.command == command
        return ack.result

    def setpoint(self, frame, mask, vx=0.0, vy=0.0, yaw=0.0, yaw_rate=0.0):
        self.conn.mav.set_position_target_local_ned_send(
            0, 1, 1, frame, mask, 0, 0, 0, vx, vy, 0, 0, 0, 0, yaw, yaw_rate
        )

    def close(self):
        self.conn.close()


@pytest.fixture
def rover():
    with SimRover(mode=mf.ROVER_MODE_MANUAL) as r:
        yield r


@pytest.fixture
def companion(rover):
    c = Companion(rover)
    yield c
    c.close()


def test_heartbeat_reports_rover_mode_and_armed_bit(rover, companion):
    hb = companion.heartbeat
    assert hb.type == mavlink.MAV_TYPE_GROUND_ROVER
    assert hb.autopilot == mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA
    assert hb.custom_mode == mf.ROVER_MODE_MANUAL
    assert hb.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED
    assert rover.port != 0 and rover.connection.startswith("udpout:127.0.0.1:")


def test_mode_change_is_acknowledged_and_unknown_modes_refused(rover, companion):
    guided = companion.command(mavlink.MAV_CMD_DO_SET_MODE, 1, mf.ROVER_MODE_GUIDED)
    assert guided == mavlink.MAV_RESULT_ACCEPTED and rover.mode == mf.ROVER_MODE_GUIDED
    bad = companion.command(mavlink.MAV_CMD_DO_SET_MODE, 1, 99)
    assert bad == mavlink.MAV_RESULT_FAILED and rover.mode == mf.ROVER_MODE_GUIDED
    hb = companion.conn.recv_match(type="HEARTBEAT", blocking=True, timeout=2.0)
    assert hb.custom_mode == mf.ROVER_MODE_GUIDED


def test_streams_only_what_was_requested_at_the_requested_rate(rover, companion):
    assert companion.conn.recv_match(type="ATTITUDE", blocking=True, timeout=0.3) is None
    interval_us = 1e6 / 25
    assert (
        companion.command(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, mf.MSG_ID_ATTITUDE, interval_us)
        == 0
    )
    start, count = time.monotonic(), 0
    while time.monotonic() - start < 1.0:
        if companion.conn.recv_match(type="ATTITUDE", blocking=True, timeout=0.1):
            count += 1
    assert 20 <= count <= 30
    assert companion.conn.recv_match(type="LOCAL_POSITION_NED", blocking=False) is None


def test_guided_accepts_only_ardupilot_frames_and_masks(rover, companion):
    mask = mf.TYPE_MASK_VELOCITY_YAW_RATE
    companion.setpoint(mavlink.MAV_FRAME_BODY_OFFSET_NED, mask, vx=1.0)  # not GUIDED yet
    assert wait_for(lambda: rover.setpoints_ignored == 1)
    companion.command(mavlink.MAV_CMD_DO_SET_MODE, 1, mf.ROVER_MODE_GUIDED)
    companion.setpoint(mavlink.MAV_FRAME_GLOBAL, mask, vx=1.0)  # frame ArduPilot rejects
    companion.setpoint(mavlink.MAV_FRAME_BODY_OFFSET_NED, 0x05C0, vx=1.0)  # position + vel
    companion.setpoint(mavlink.MAV_FRAME_BODY_OFFSET_NED, 0x0FFF)  # nothing to use
    assert wait_for(lambda: rover.setpoints_ignored == 4)
    assert rover.setpoints_accepted == 0 and rover.true_velocity() == (0.0, 0.0)
    companion.setpoint(mavlink.MAV_FRAME_BODY_OFFSET_NED, mask, vx=1.0, yaw_rate=-0.5)
    assert wait_for(lambda: rover.setpoints_accepted == 1)
    assert wait_for(lambda: rover.true_velocity()[0] == pytest.approx(1.0), 1.5)
    assert rover.true_velocity()[1] == pytest.approx(0.5)  # NED -0.5 = counter-clockwise


def test_speed_is_capped_and_disarmed_rover_does_not_move():
    with SimRover(mode=mf.ROVER_MODE_GUIDED, limits=RoverLimits(max_speed_mps=0.5)) as rover:
        c = Companion(rover)
        for _ in range(60):
            c.setpoint(mavlink.MAV_FRAME_BODY_OFFSET_NED, mf.TYPE_MASK_VELOCITY_YAW_RATE, vx=3.0)
            time.sleep(0.01)
        assert rover.true_velocity()[0] == pytest.approx(0.5)
        assert c.command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 0) == mavlink.MAV_RESULT_ACCEPTED
        assert wait_for(lambda: rover.true_velocity()[0] == 0.0, 1.0)
        c.close()


def test_stops_three_seconds_after_the_last_setpoint():
    start = Odometry(1.0, 2.0, 0.5, 0.0)
    with SimRover(mode=mf.ROVER_MODE_GUIDED, start_pose=start) as rover:
        assert rover.true_pose().x_m == pytest.approx(
            1.0
        ) and rover.true_pose().yaw_rad == pytest.approx(0.5)
        c = Companion(rover)
        c.setpoint(mavlink.MAV_FRAME_BODY_OFFSET_NED, mf.TYPE_MASK_VELOCITY_YAW_RATE, vx=0.5)
        t0 = time.monotonic()
        assert wait_for(lambda: rover.true_velocity()[0] > 0.4, 1.0)
        assert wait_for(lambda: rover.true_velocity()[0] == 0.0, 4.0)
        stopped_after = time.monotonic() - t0
        assert 2.8 < stopped_after < 3.7
        pose = rover.true_pose()
        heading = math.atan2(pose.y_m - 2.0, pose.x_m - 1.0)
        assert heading == pytest.approx(0.5, abs=0.02)  # drove straight along its yaw
        c.close()


def test_pilot_mode_switch_stops_the_rover(rover, companion):
    companion.command(mavlink.MAV_CMD_DO_SET_MODE, 1, mf.ROVER_MODE_GUIDED)
    for _ in range(30):
        companion.setpoint(
            mavlink.MAV_FRAME_BODY_OFFSET_NED, mf.TYPE_MASK_VELOCITY_YAW_RATE, vx=1.0
        )
        time.sleep(0.02)
    assert rover.true_velocity()[0] > 0.5
    rover.pilot_set_mode(mf.ROVER_MODE_HOLD)
    companion.setpoint(mavlink.MAV_FRAME_BODY_OFFSET_NED, mf.TYPE_MASK_VELOCITY_YAW_RATE, vx=1.0)
    assert wait_for(lambda: rover.true_velocity()[0] == 0.0, 1.5)
    modes = set()
    deadline = time.monotonic() + 2.0
    while mf.ROVER_MODE_HOLD not in modes and time.monotonic() < deadline:
        hb = companion.conn.recv_match(type="HEARTBEAT", blocking=True, timeout=0.2)
        modes.add(hb.custom_mode if hb else None)
    assert mf.ROVER_MODE_HOLD in modes  # announced at once, not at the next 1 Hz beat


def test_px4_flavour_needs_streaming_before_offboard_and_fails_safe_on_loss():
    with SimRover(autopilot="px4") as rover:
        c = Companion(rover)
        assert c.heartbeat.autopilot == mavlink.MAV_AUTOPILOT_PX4
        offboard = (1, mf.PX4_MAIN_MODE_OFFBOARD, 0)
        assert c.command(mavlink.MAV_CMD_DO_SET_MODE, *offboard) == mavlink.MAV_RESULT_FAILED
        for _ in range(10):
            c.setpoint(mavlink.MAV_FRAME_BODY_NED, mf.TYPE_MASK_VELOCITY_ONLY)
            time.sleep(0.02)
        assert c.command(mavlink.MAV_CMD_DO_SET_MODE, *offboard) == mavlink.MAV_RESULT_ACCEPTED
        assert rover.mode == rover.commanded_mode
        # Setpoints stop: after PX4's offboard-loss timeout the vehicle leaves OFFBOARD.
        assert wait_for(lambda: rover.mode != rover.commanded_mode, 1.6)
        assert mf.px4_main_mode(rover.mode) == 4  # AUTO (loiter)
        c.close()


def test_paused_telemetry_makes_the_base_report_no_odometry_and_last_setpoint_is_kept():
    import dataclasses

    from follow.config import MavlinkConfig
    from follow.control.mavlink_base import MavlinkBase
    from follow.types import VelocityCommand

    with SimRover(seed=4) as rover:
        config = dataclasses.replace(MavlinkConfig(), connection=rover.connection)
        with MavlinkBase(config) as base:
            assert wait_for(lambda: base.odometry() is not None, 2.0)
            base.send(VelocityCommand(0.4, -0.2, time.monotonic()))
            assert wait_for(lambda: (rover.last_setpoint or (0, 0, 0))[1] == pytest.approx(0.4))
            assert rover.last_setpoint[2] == pytest.approx(0.2)  # NED: clockwise positive
            rover.pause_telemetry()
            assert wait_for(lambda: base.odometry() is None, 2.0)
            assert rover.mode == mf.ROVER_MODE_GUIDED  # the link itself stays up
            rover.pause_telemetry(False)
            assert wait_for(lambda: base.odometry() is not None, 2.0)


def test_the_true_pose_is_stamped_at_the_instant_it_describes():
    """Figures (the safety evaluation's time to stand still, the following error) pair the
    true pose with its stamp: stamped at the call instead of at the physics step that
    computed it, a pose up to a step old passed for the pose now."""
    with SimRover(mode=mf.ROVER_MODE_GUIDED, physics_rate_hz=5.0) as rover:
        c = Companion(rover)
        c.setpoint(mavlink.MAV_FRAME_BODY_OFFSET_NED, mf.TYPE_MASK_VELOCITY_YAW_RATE, vx=1.0)
        assert wait_for(lambda: rover.true_velocity()[0] == 1.0, 2.0)
        time.sleep(0.25)  # a step at 1 m/s from start to end
        samples = []
        for _ in range(80):
            samples.append(rover.true_pose())
            time.sleep(0.01)
        c.close()
    first = samples[0]
    assert len({p.stamp_s for p in samples}) >= 3  # several steps
    for pose in samples:  # straight along x at 1 m/s
        assert pose.x_m - first.x_m == pytest.approx(pose.stamp_s - first.stamp_s, abs=1e-9)


def test_a_non_finite_setpoint_is_ignored_not_driven_past_the_speed_limit():
    """min(nan, limit) is nan: a NaN speed accelerated the simulated vehicle for ever. A
    NaN in a field the type_mask ignores is what some senders fill unused fields with."""
    with SimRover(mode=mf.ROVER_MODE_GUIDED) as rover:
        c = Companion(rover)
        mask = mf.TYPE_MASK_VELOCITY_YAW_RATE
        for bad in (dict(vx=math.nan), dict(vx=1.0, yaw_rate=math.inf), dict(vy=math.nan)):
            c.setpoint(mavlink.MAV_FRAME_BODY_OFFSET_NED, mask, **bad)
        assert wait_for(lambda: rover.setpoints_ignored == 3, 1.0)
        time.sleep(0.2)
        assert rover.setpoints_accepted == 0 and rover.true_velocity() == (0.0, 0.0)
        c.setpoint(mavlink.MAV_FRAME_BODY_OFFSET_NED, mask, vx=0.5, yaw=math.nan)
        assert wait_for(lambda: rover.setpoints_accepted == 1, 1.0)
        c.close()


def test_a_command_with_a_non_finite_parameter_is_denied(rover, companion):
    nan_mode = companion.command(mavlink.MAV_CMD_DO_SET_MODE, 1, math.nan)
    assert nan_mode == mavlink.MAV_RESULT_DENIED and rover.mode == mf.ROVER_MODE_MANUAL
    assert companion.command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, math.nan) == (
        mavlink.MAV_RESULT_DENIED
    )
    assert rover.armed and rover._thread.is_alive()


def test_a_message_the_simulator_cannot_handle_is_logged(rover, companion, monkeypatch, caplog):
    def broken(msg):
        raise ValueError("injected")

    monkeypatch.setattr(rover, "_command", broken)
    companion.conn.mav.command_long_send(1, 1, mavlink.MAV_CMD_DO_SET_MODE, 0, 1, 4, 0, 0, 0, 0, 0)
    assert wait_for(lambda: "sim rover: COMMAND_LONG not handled" in caplog.text, 1.0)
    monkeypatch.undo()
    guided = companion.command(mavlink.MAV_CMD_DO_SET_MODE, 1, mf.ROVER_MODE_GUIDED)
    assert guided == mavlink.MAV_RESULT_ACCEPTED  # the vehicle still answers
