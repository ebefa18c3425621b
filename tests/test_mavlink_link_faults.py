"""The MAVLink base against a vehicle written apart from the project's simulated rover
(tests/fake_mavlink_vehicle.py, straight on pymavlink's encoder): what a real link does
that the simulator never did. A pilot's mode switch or a disarmed vehicle refuses motion
and the controller hears it (it speeds up from rest afterwards); a TCP link that drops
reconnects; only the autopilot component's telemetry is odometry; a vehicle that is no
rover, or a malformed connection string, is refused by name. Conventions (setpoint
frame and mask, yaw-rate sign, NED to odom) are checked by hand-computed examples."""

import math
import random
import re
import time

import numpy as np
import pytest
from fake_mavlink_vehicle import GUIDED, MANUAL, FakeRover, UdpRover
from pymavlink.dialects.v20 import ardupilotmega as mavlink
from waiting import wait_for

from follow.config import ConfigError, ControlConfig, MavlinkConfig
from follow.control import mavlink_frames as mf
from follow.control.controller import FollowingController
from follow.control.mavlink_base import LinkState, MavlinkBase, MavlinkError
from follow.control.target import TargetMotion
from follow.frames import base_to_odom, odom_to_base
from follow.types import Odometry, VelocityCommand

FAST = dict(heartbeat_timeout_s=0.6, connect_timeout_s=2.0, odometry_timeout_s=0.3)


@pytest.fixture
def vehicle():
    v = UdpRover()
    yield v
    v.close()


# -- conventions ------------------------------------------------------------------------


def test_hand_computed_frames():
    # Robot 1 m north, 2 m east, heading east (NED yaw +90 deg).
    x, y, yaw = mf.ned_pose_to_odom(1.0, 2.0, math.pi / 2)
    robot = Odometry(x, y, yaw, 0.0)
    # A person 1 m straight ahead must be 1 m further east: NED (1, 3).
    p_odom = base_to_odom(np.array([1.0, 0.0]), robot)
    n, e, _ = mf.odom_pose_to_ned(p_odom[0], p_odom[1], 0.0)
    assert (n, e) == pytest.approx((1.0, 3.0))
    # A person 1 m to the robot's left (north when facing east): NED (2, 2).
    p_odom = base_to_odom(np.array([0.0, 1.0]), robot)
    n, e, _ = mf.odom_pose_to_ned(p_odom[0], p_odom[1], 0.0)
    assert (n, e) == pytest.approx((2.0, 2.0))
    # A point fixed in the world stays fixed while the robot turns in place: NED yaw 90->60
    # deg is a left (CCW) turn; a person at NED (1, 3) moves to the robot's left.
    person_odom = base_to_odom(np.array([1.0, 0.0]), robot)
    x2, y2, yaw2 = mf.ned_pose_to_odom(1.0, 2.0, math.radians(60))
    rel = odom_to_base(person_odom, Odometry(x2, y2, yaw2, 0.0))
    assert rel[1] < 0  # turned left -> the person is now to the right
    assert rel == pytest.approx([math.cos(math.radians(30)), -math.sin(math.radians(30))])
    # A CCW (left) command becomes a negative (counter-clockwise in NED) yaw rate.
    vx, vy, r = mf.ardupilot_setpoint(VelocityCommand(0.5, 0.3, 0.0))
    assert (vx, vy, r) == (0.5, 0.0, -0.3)
    # type_mask: ArduPilot Rover's "velocity + turn rate" branch (vel used, acc/yaw ignored).
    m = mf.TYPE_MASK_VELOCITY_YAW_RATE
    assert not m & 0b11000 and m & 0b11000000 and m & (1 << 10) and not m & (1 << 11)


def test_gcs_heartbeat_is_not_taken_for_the_vehicle(vehicle):
    gcs = mavlink.MAVLink(vehicle.rover.mav.file, srcSystem=255, srcComponent=190)
    vehicle.extra.append(
        lambda: gcs.heartbeat_send(mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0)
    )
    vehicle.rover.silent = True  # only the GCS is heard
    with pytest.raises(MavlinkError, match="no vehicle heartbeat"):  # no other refusal
        MavlinkBase(MavlinkConfig(connection=vehicle.connection, **FAST))


def test_a_command_ack_addressed_to_another_system_or_sent_before_is_not_ours(vehicle):
    """The vehicle answers a ground station's mode change (refused) just before ours, on
    the same link: that ACK names the ground station as its target and is not taken as the
    answer to our DO_SET_MODE; nor is an ACK that came before our command was sent."""
    rover = vehicle.rover
    handle = rover.handle

    def answer_a_gcs_first(msg):
        if msg.get_type() == "COMMAND_LONG" and msg.command == mavlink.MAV_CMD_DO_SET_MODE:
            rover.mav.command_ack_send(msg.command, mavlink.MAV_RESULT_DENIED, 0, 0, 255, 190)
        handle(msg)

    rover.handle = answer_a_gcs_first
    with MavlinkBase(MavlinkConfig(connection=vehicle.connection, **FAST)) as base:
        assert base.state is LinkState.ACTIVE and rover.mode == GUIDED
        rover.handle = handle
        earlier = mavlink.MAVLink_command_ack_message(mavlink.MAV_CMD_DO_SET_MODE,
                                                      mavlink.MAV_RESULT_DENIED)  # fmt: skip
        earlier._header = base._heartbeat._header
        base._on_message(earlier)  # from the vehicle, before the command below
        result = base._command_long(mavlink.MAV_CMD_DO_SET_MODE,
                                    mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, GUIDED)  # fmt: skip
        assert result == mavlink.MAV_RESULT_ACCEPTED


# -- link faults ------------------------------------------------------------------------


def test_send_reports_a_refused_command_when_the_pilot_took_over(vehicle):
    with MavlinkBase(MavlinkConfig(connection=vehicle.connection, **FAST)) as base:
        assert base.state is LinkState.ACTIVE
        vehicle.rover.mode = MANUAL  # pilot flips the mode switch
        assert wait_for(lambda: base.state is LinkState.MODE_OVERRIDDEN, 2.0)
        sent = base.send(VelocityCommand(1.0, 0.3, time.monotonic()))
        assert sent.is_stop  # the controller hears it: it speeds up from rest afterwards


def test_no_moving_setpoints_to_a_disarmed_vehicle(vehicle):
    vehicle.rover.armed = False
    with MavlinkBase(MavlinkConfig(connection=vehicle.connection, **FAST)) as base:
        assert not base.healthy()
        t0 = time.monotonic()
        while time.monotonic() - t0 < 0.5:
            sent = base.send(VelocityCommand(1.0, 0.0, time.monotonic()))
            time.sleep(0.05)
        moving = [s for s in vehicle.rover.setpoints if s[3] != 0.0]
        assert sent.is_stop and not moving  # arming later must not drive off at once


def test_after_override_the_robot_restarts_from_rest():
    """Through the control loop's own _send (as the runner uses it): the pilot holds the
    robot in MANUAL for 2 s while the target stands 6 m ahead; back in GUIDED the first
    setpoints should ramp from rest (max_forward_accel_mps2), not jump to full speed."""
    from follow.capture import LatestSlot
    from follow.pipeline import ControlLoop

    v = UdpRover()
    try:
        cfg = ControlConfig()
        with MavlinkBase(MavlinkConfig(connection=v.connection, **FAST)) as base:
            ctrl = FollowingController(cfg)
            loop = ControlLoop(ctrl, base, LatestSlot(), 15.0, 0.5)

            def tick():
                now = time.monotonic()
                target = TargetMotion(np.array([6.0, 0.0]), np.zeros(2), now)
                loop._send(ctrl.update(target, now))
                time.sleep(1 / 15)

            for _ in range(3):
                tick()
            v.rover.mode = MANUAL
            assert wait_for(lambda: base.state is LinkState.MODE_OVERRIDDEN, 2.0)
            for _ in range(30):
                tick()
            v.rover.mode = GUIDED
            assert wait_for(lambda: base.state is LinkState.ACTIVE, 2.0)
            n = len(v.rover.setpoints)
            tick()
            time.sleep(0.05)
            first = [s[3] for s in v.rover.setpoints[n:]]
            assert max(first) <= cfg.max_forward_accel_mps2 * 0.2, (
                f"first setpoints after GUIDED returned: {first} m/s (controller never told)"
            )
    finally:
        v.close()


def test_a_link_failing_every_tick_is_logged_once_per_period_not_per_tick(
    vehicle, caplog, monkeypatch
):
    """A write that fails on every sender tick (20 Hz) logs its first error at once, then
    one line per period with the count of ticks failed since, and a last one with the
    count when sending works again; the stale command then goes out as zero."""
    import threading

    from follow.control import mavlink_base

    monkeypatch.setattr(mavlink_base, "_ERROR_LOG_S", 1.0, raising=False)
    with MavlinkBase(MavlinkConfig(connection=vehicle.connection, **FAST)) as base:
        write = base._conn.mav.set_position_target_local_ned_send
        broken = threading.Event()

        def failing(*args):
            if broken.is_set():
                raise OSError("device gone")
            return write(*args)

        base._conn.mav.set_position_target_local_ned_send = failing
        base.send(VelocityCommand(0.5, 0.0, time.monotonic()))
        broken.set()
        with caplog.at_level("WARNING", logger="follow.control.mavlink_base"):
            time.sleep(1.4)  # 28 ticks or so, all failing: two reports
            errors = [r.getMessage() for r in caplog.records if "send failed" in r.getMessage()]
            assert len(errors) == 2 and "device gone" in base.last_error
            assert int(re.search(r"\((\d+) failed ticks since", errors[1]).group(1)) >= 10
            broken.clear()
            assert wait_for(lambda: "works again" in caplog.text, 2.0)
        assert re.search(r"works again; (\d+) failed tick", caplog.text)
        assert int(re.search(r"works again; (\d+)", caplog.text).group(1)) >= 5
        assert wait_for(lambda: vehicle.rover.setpoints[-1][3] == 0.0, 1.0)


def test_heartbeats_lost_while_driving_end_in_zero_setpoints(vehicle):
    # Three heartbeats lost in a row on a lossy radio while setpoints still reach the
    # vehicle (and telemetry still comes): once the link counts as lost, the vehicle
    # must not drive on the last moving setpoint until its own 3 s GUIDED timeout.
    moving = VelocityCommand(1.0, 0.2, 0.0)
    with MavlinkBase(MavlinkConfig(connection=vehicle.connection, **FAST)) as base:
        assert base.state is LinkState.ACTIVE
        for _ in range(5):
            base.send(moving)
            time.sleep(0.05)
        vehicle.rover.heartbeat = lambda: None  # heartbeats lost, nothing else
        deadline = time.monotonic() + 2.0
        while base.state is not LinkState.LINK_LOST and time.monotonic() < deadline:
            base.send(moving)  # the control loop: odometry still fresh
            time.sleep(0.05)
        assert base.state is LinkState.LINK_LOST
        for _ in range(4):
            assert base.send(moving).is_stop
            time.sleep(0.05)
        last = vehicle.rover.setpoints[-1]
        assert (last[3], last[5]) == (0.0, 0.0), f"the vehicle was left on {last[3:]}"


def test_telemetry_held_by_the_link_and_delivered_late_is_not_fresh_odometry(vehicle):
    """A link that holds the vehicle's messages while it is down (a radio, a router) and
    delivers them at once when it is back: by their own time_boot_ms they are 0.6-0.8 s
    old, and they must not count as fresh (they did, stamped by their receipt). Live
    telemetry afterwards is fresh again."""
    rover = vehicle.rover
    with MavlinkBase(MavlinkConfig(connection=vehicle.connection, **FAST)) as base:
        assert wait_for(lambda: base.odometry() is not None, 1.0)
        with rover.lock:
            rover.silent = True  # the link goes down: nothing more arrives
            held = rover.boot_ms()
        time.sleep(0.8)
        with rover.lock:  # back: what it held comes now, 0.2 s of it
            for k in range(1, 7):
                rover.mav.local_position_ned_send(held + 33 * k, 5.0, 0, 0, 0, 0, 0)
                rover.mav.attitude_send(held + 33 * k, 0, 0, 1.0, 0, 0, 0)
        assert wait_for(lambda: base._newest["ATTITUDE"][0].time_boot_ms == held + 198, 1.0)
        assert base.odometry() is None
        rover.silent = False
        assert wait_for(lambda: base.odometry() is not None, 1.0)
        assert base.odometry().x_m == 0.0  # the live pose, the rover's


PERIOD_S = 1 / 30  # telemetry at 30 Hz
SETTLE_S = FAST["odometry_timeout_s"]
SETTLE_FRAMES = math.ceil(SETTLE_S / PERIOD_S) + 1  # frames received after the settle time


class Telemetry:
    """The driver on a fake clock, its LOCAL_POSITION_NED and ATTITUDE handed to it by
    the test as its receiver would (the vehicle sends heartbeats only). `at_s` and
    `boot_ms` are our clock and the vehicle's when the newest frame was produced."""

    def __init__(self, base, now):
        self.base, self.now = base, now
        self.header = base._heartbeat._header
        self.at_s, self.boot_ms = now[0], 600_000.0

    def deliver(self, received_s, boot_ms, north=0.0, position=True):
        """One frame (a LOCAL_POSITION_NED, unless not `position`, and an ATTITUDE of
        vehicle time boot_ms) received at received_s; the odometry then."""
        self.now[0] = received_s
        for msg in (mavlink.MAVLink_local_position_ned_message(round(boot_ms), north, 0, 0, 0, 0, 0),
                    mavlink.MAVLink_attitude_message(round(boot_ms), 0, 0, 0, 0, 0, 0)):  # fmt: skip
            if msg.get_type() == "LOCAL_POSITION_NED" and not position:
                continue
            msg._header = self.header
            self.base._on_message(msg)
        return self.odometry()

    def odometry(self):
        odo = self.base.odometry()
        assert odo is None or odo.stamp_s <= self.now[0]  # never produced after its receipt
        return odo

    def produce(self, seconds, rate=1.0):
        """The vehicle's frames over the next `seconds` of our clock, its clock running at
        `rate` times ours: [(produced at on our clock, boot_ms)]."""
        frames = []
        for _ in range(round(seconds / PERIOD_S)):
            self.at_s += PERIOD_S
            self.boot_ms += rate * PERIOD_S * 1000
            frames.append((self.at_s, self.boot_ms))
        return frames

    def live(self, seconds, rate=1.0, jitter_s=0.0, rng=None, position=True):
        """Live telemetry for `seconds`, each frame received up to jitter_s early or late:
        for each frame, whether odometry was fresh on its receipt and until just before
        the next one's."""
        frames = self.produce(seconds, rate)
        received = [at + (rng.uniform(-jitter_s, jitter_s) if rng else 0.0) for at, _ in frames]
        fresh = []
        for k, (_, boot_ms) in enumerate(frames):
            ok = self.deliver(received[k], boot_ms, position=position) is not None
            if k + 1 < len(frames):
                self.now[0] = received[k + 1] - 1e-6
                ok = ok and self.odometry() is not None
            fresh.append(ok)
        return fresh

    def held_and_delivered_in_bursts(self):
        """The link holds 1.5 s of telemetry and delivers it as 15 radio frames 40 ms
        apart, each packing three frames of telemetry (six messages), the newest 1.4 s to
        0.56 s old; what the vehicle sends meanwhile is lost. Whether odometry came from
        each burst."""
        held = self.produce(1.5)
        back_s = self.at_s
        odometry = []
        for k in range(15):
            received_s = back_s + 0.04 * k
            burst = held[3 * k : 3 * k + 3]
            assert received_s - burst[-1][0] > SETTLE_S  # older than odometry_timeout_s
            odometry.append([self.deliver(received_s, boot_ms, north=5.0) is not None
                             for _, boot_ms in burst])  # fmt: skip
        self.pause(0.56, rate=1.0)
        return [any(burst) for burst in odometry]

    def pause(self, seconds, rate=0.0):
        """Nothing arrives for `seconds`; the vehicle's clock runs at `rate` times ours."""
        self.at_s += seconds
        self.boot_ms += rate * seconds * 1000
        self.now[0] = self.at_s


@pytest.fixture
def telemetry(vehicle):
    vehicle.rover.telemetry = lambda: None  # only what the test hands the driver
    now = [1000.0]
    with MavlinkBase(MavlinkConfig(connection=vehicle.connection, **FAST),
                     clock=lambda: now[0]) as base:  # fmt: skip
        yield Telemetry(base, now)


def test_a_held_backlog_delivered_in_bursts_is_not_fresh_odometry(telemetry):
    """A link holds 1.5 s of telemetry while it is down and delivers it when it is back in
    15 bursts 40 ms apart: none of it may count as fresh (from the second burst on it
    did: its first message after the 40 ms pause looked live and the offset was learnt
    again from it). Live telemetry afterwards is fresh at once: nothing of the backlog
    moved the offset."""
    assert all(telemetry.live(1.0)[SETTLE_FRAMES:])
    assert not any(telemetry.held_and_delivered_in_bursts())
    fresh = telemetry.live(1.0)
    assert all(fresh), fresh
    assert telemetry.odometry().x_m == 0.0  # the live pose


@pytest.mark.parametrize("after_reboot", [False, True])
def test_a_backlog_as_the_first_telemetry_heard_is_not_fresh_odometry(telemetry, after_reboot):
    """The first telemetry the driver hears, or the first after the vehicle rebooted, may
    be a backlog too (a router that kept the vehicle's messages, a radio that held them):
    in bursts it is no odometry (it was, the offset learnt from its first message and
    lowered by each later one), nor are the live messages after it until they have come
    steadily for the settle time."""
    if after_reboot:
        assert all(telemetry.live(1.0)[SETTLE_FRAMES:])
        telemetry.pause(3.0)  # rebooting
        telemetry.boot_ms = 2_000.0  # its boot clock starts again
    assert not any(telemetry.held_and_delivered_in_bursts())
    fresh = telemetry.live(1.0)
    assert not any(fresh[: SETTLE_FRAMES - 2]) and all(fresh[SETTLE_FRAMES:]), fresh
    assert telemetry.odometry().x_m == 0.0


def test_a_vehicle_clock_at_half_our_rate_gives_odometry_throughout(telemetry):
    # A simulator at half real time: the offset of its clock to ours grows all the time,
    # and is followed after at most the settle time from the first message.
    fresh = telemetry.live(5.0, rate=0.5)
    assert all(fresh[SETTLE_FRAMES:]), fresh


def test_a_vehicle_clock_faster_than_ours_gives_no_odometry(telemetry):
    # A simulator above real time delivers telemetry faster than our clock runs, as a
    # backlog being drained does: it never proves the offset, and the robot stays still
    # (docs/control.md) rather than trusting what could be old.
    assert not any(telemetry.live(3.0, rate=2.0))


@pytest.mark.parametrize("jitter_s", [0.0, 0.01])
def test_a_simulator_paused_and_resumed_gives_odometry_again_after_the_settle_time(
    telemetry, jitter_s
):
    """A simulator paused for 2 s: its first messages afterwards could as well be a
    backlog 2 s old, so they are not fresh; once they have come steadily for the settle
    time (odometry_timeout_s, 0.3 s here) they are, at most one frame later (each frame
    received on time, or up to 10 ms early or late)."""
    rng = random.Random(3)
    assert all(telemetry.live(1.0, jitter_s=jitter_s, rng=rng)[SETTLE_FRAMES:])
    telemetry.pause(2.0)
    assert telemetry.odometry() is None
    fresh = telemetry.live(1.0, jitter_s=jitter_s, rng=rng)
    back_after_s = fresh.index(True) * PERIOD_S  # from the first frame after the pause
    assert SETTLE_S - 2 * jitter_s <= back_after_s <= SETTLE_S + PERIOD_S + 0.001, fresh
    assert all(fresh[SETTLE_FRAMES:]), fresh


@pytest.mark.parametrize("rate", [1.0, 0.98, 0.5])
def test_receive_jitter_never_loses_odometry(telemetry, rate):
    # Each frame received up to 10 ms early or late, for 20 s: with the vehicle's clock at
    # our rate, a little slower (raised now and then), or at half of it.
    fresh = telemetry.live(20.0, rate=rate, jitter_s=0.01, rng=random.Random(7))
    assert all(fresh[SETTLE_FRAMES:]), fresh.index(False, SETTLE_FRAMES)


def test_a_vehicle_reboot_learns_the_offset_anew(telemetry):
    # Its boot clock starts again: the offset is learnt from it, and odometry comes back
    # once its telemetry has come steadily for the settle time, stamped on its new clock.
    assert all(telemetry.live(1.0)[SETTLE_FRAMES:])
    telemetry.pause(3.0)  # rebooting
    telemetry.boot_ms = 2_000.0
    fresh = telemetry.live(1.0)
    assert not any(fresh[: SETTLE_FRAMES - 2]) and all(fresh[SETTLE_FRAMES:]), fresh
    assert telemetry.odometry().stamp_s == pytest.approx(telemetry.now[0])


def test_after_a_reboot_a_position_back_later_than_the_attitude_is_fresh_at_once(telemetry):
    """After a reboot the vehicle's attitude comes back before its position (its
    estimator has no position yet): the attitude proves the new clock, and the position
    is fresh from its first message. Its own message before the reboot, of the old
    clock, made that first message a second reboot, and odometry waited the settle time
    again."""
    assert all(telemetry.live(1.0)[SETTLE_FRAMES:])
    telemetry.pause(3.0)  # rebooting
    telemetry.boot_ms = 2_000.0
    assert not any(telemetry.live(2.0, position=False))  # no position: no odometry
    fresh = telemetry.live(1.0)
    assert all(fresh), fresh
    assert telemetry.odometry().stamp_s == pytest.approx(telemetry.now[0])


def test_attitude_from_another_component_is_not_odometry(vehicle):
    # Another component on the vehicle's system (e.g. a gimbal, a second IMU/AHRS board,
    # a companion process) emitting ATTITUDE with its own boot clock.
    other = mavlink.MAVLink(vehicle.rover.mav.file, srcSystem=1, srcComponent=154)
    t_other = [100_000]

    def gimbal():
        t_other[0] += 50
        other.attitude_send(t_other[0], 0, 0, 2.5, 0, 0, 0)

    vehicle.extra.append(gimbal)
    with MavlinkBase(MavlinkConfig(connection=vehicle.connection, **FAST)) as base:
        yaws = set()
        end = time.monotonic() + 1.0
        while time.monotonic() < end:
            odo = base.odometry()
            if odo is not None:
                yaws.add(round(odo.yaw_rad, 2))
            time.sleep(0.01)
        assert yaws == {0.0}, f"odometry yaw took values {yaws} (the autopilot reports 0)"


@pytest.mark.parametrize("field", ["yaw", "north"])
def test_non_finite_telemetry_is_no_odometry(vehicle, field):
    # An estimator without a solution may report NaN: no pose (None, the control loop
    # stops and goes on), never an exception out of odometry() that ends the run.
    with MavlinkBase(MavlinkConfig(connection=vehicle.connection, **FAST)) as base:
        assert wait_for(lambda: base.odometry() is not None, 2.0)
        setattr(vehicle.rover, field, float("nan"))
        assert wait_for(lambda: base.odometry() is None, 2.0)
        setattr(vehicle.rover, field, 0.0)
        assert wait_for(lambda: base.odometry() is not None, 2.0)


def test_malformed_connection_string_is_a_config_or_mavlink_error():
    with pytest.raises((ConfigError, MavlinkError)):
        MavlinkBase(MavlinkConfig(connection="udpin:0.0.0.0", **FAST))


@pytest.mark.parametrize("connection", ["udpin:0.0.0.0:99999", "tcp:127.0.0.1:70000"])
def test_a_port_out_of_range_is_a_mavlink_error_naming_the_connection(connection):
    # the socket raises OverflowError ("port must be 0-65535"), which left the command
    # line with a traceback instead of an error naming the connection string
    with pytest.raises(MavlinkError, match=f"{connection}.*0-65535"):
        MavlinkBase(MavlinkConfig(connection=connection, **FAST))


def test_no_heartbeat_while_every_send_fails_names_the_send_error():
    # udpout opens without sending: the port is refused by each send (the companion's
    # heartbeat), and the vehicle, never reached, cannot answer. "No vehicle heartbeat"
    # alone sent the search to the vehicle's side.
    with pytest.raises(MavlinkError, match=r"no vehicle heartbeat.*send failed.*0-65535"):
        MavlinkBase(MavlinkConfig(connection="udpout:127.0.0.1:70000", **FAST))


class TcpRover:
    """FakeRover behind a TCP server (like SITL's 5760 or mavlink-router's TCP port) that
    can drop the client and accept a new one (a router/SITL restart, a Wi-Fi blip)."""

    def __init__(self):
        import socket
        import threading

        self.srv = socket.socket()
        self.srv.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self.srv.bind(("127.0.0.1", 0))
        self.srv.listen(4)
        self.port = self.srv.getsockname()[1]
        self.client = None
        self.accepted = 0
        self.rover = FakeRover(self._write)
        self._stop = threading.Event()
        threading.Thread(target=self._accept, daemon=True).start()
        threading.Thread(target=self._run, daemon=True).start()

    def _write(self, data):
        c = self.client
        if c is not None:
            c.sendall(data)

    def _accept(self):
        while not self._stop.is_set():
            try:
                c, _ = self.srv.accept()
            except OSError:
                return
            c.settimeout(0.01)
            self.client, self.accepted = c, self.accepted + 1

    def _run(self):
        nxt = 0.0
        while not self._stop.is_set():
            c = self.client
            if c is not None:
                try:
                    data = c.recv(4096)
                    if data:
                        self.rover.feed(data)
                except OSError:
                    pass
            else:
                time.sleep(0.01)
            if time.monotonic() >= nxt:
                nxt = time.monotonic() + 0.05
                self.rover.tick()

    def drop_client(self, reset=False):
        """Close the connection: with a FIN, or with a RST (`reset`: a peer that crashed
        or a router that forgot the connection)."""
        import socket
        import struct

        c, self.client = self.client, None
        if reset:
            c.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
        c.close()

    def close(self):
        self._stop.set()
        self.srv.close()
        if self.client:
            self.client.close()


@pytest.mark.parametrize("reset", [False, True], ids=["closed", "reset"])
def test_tcp_link_recovers_after_the_peer_restarts(capfd, reset):
    # The receiver reopens the connection (the sender's writes only report their failures)
    v = TcpRover()
    try:
        with MavlinkBase(MavlinkConfig(connection=f"tcp:127.0.0.1:{v.port}", **FAST)) as base:
            assert base.state is LinkState.ACTIVE
            v.drop_client(reset)  # server still listening: a new connection would work
            cpu0 = time.process_time()
            time.sleep(3.0)
            cpu_s = time.process_time() - cpu0
            out = capfd.readouterr().out
            assert v.accepted > 1 and base.state is LinkState.ACTIVE, (
                f"never reconnected: state {base.state}, cpu {cpu_s:.2f} s in 3 s, "
                f"{out.count('EOF on TCP socket')} 'EOF on TCP socket' lines on stdout"
            )
    finally:
        v.close()


def test_a_non_rover_autopilot_is_refused():
    # ArduCopter custom mode 15 is AUTOTUNE, not GUIDED (4): the driver must not assume
    # Rover mode numbers for whatever vehicle answers.
    v = UdpRover(mav_type=mavlink.MAV_TYPE_QUADROTOR)
    try:
        with pytest.raises(MavlinkError, match=r"is no rover \(MAV_TYPE 2;"):
            MavlinkBase(MavlinkConfig(connection=v.connection, **FAST))
        assert mavlink.MAV_CMD_DO_SET_MODE not in v.rover.commands
        assert v.rover.mode == MANUAL and not v.rover.setpoints
    finally:
        v.close()


@pytest.mark.parametrize("configured, heard", [
    ("px4", mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA),  # PX4's OFFBOARD (6) is Rover's FOLLOW
    ("ardupilot", mavlink.MAV_AUTOPILOT_PX4),
])  # fmt: skip
def test_an_autopilot_other_than_the_configured_one_is_refused(configured, heard):
    # Mode numbers are the autopilot's own: asking an ArduPilot Rover for PX4's OFFBOARD
    # (main mode 6) would put it in FOLLOW, which drives after another vehicle.
    v = UdpRover(autopilot=heard)
    try:
        with pytest.raises(MavlinkError, match="autopilot"):
            MavlinkBase(MavlinkConfig(connection=v.connection, autopilot=configured, **FAST))
        assert mavlink.MAV_CMD_DO_SET_MODE not in v.rover.commands
        assert v.rover.mode == MANUAL
    finally:
        v.close()


def test_a_message_the_driver_cannot_handle_is_dropped_and_receiving_goes_on(
    vehicle, monkeypatch, caplog
):
    """Whatever goes wrong handling one message is logged by its type and that message is
    dropped; the receiver thread goes on, so the telemetry after it is odometry again
    (it ended the thread: the link looked lost while it worked)."""
    with MavlinkBase(MavlinkConfig(connection=vehicle.connection, **FAST)) as base:
        assert wait_for(lambda: base.odometry() is not None, 2.0)
        stamp = base._telemetry_stamp_locked
        failures = []

        def fails_once(kind, *args):
            if not failures:
                failures.append(kind)
                raise ZeroDivisionError("injected")
            return stamp(kind, *args)

        monkeypatch.setattr(base, "_telemetry_stamp_locked", fails_once)
        assert wait_for(lambda: failures, 2.0)
        first = base.odometry().stamp_s if base.odometry() else 0.0
        assert wait_for(
            lambda: base.odometry() is not None and base.odometry().stamp_s > first + 0.2, 2.0
        )
        assert base._receiver.is_alive()
        assert f"MAVLink message {failures[0]} not handled" in caplog.text
        assert base.state is LinkState.ACTIVE


def test_a_receive_error_other_than_an_os_error_does_not_end_the_receiver(
    vehicle, monkeypatch, caplog
):
    """pymavlink's TCP reconnect, run by the receiver and the sender at once while the
    peer is away, can fail with AttributeError (one thread's failed attempt leaves the
    port None under the other). The receiver logs it by its type and goes on: it ended
    the thread, and the vehicle, back, stayed "link lost" with no odometry for good."""
    with MavlinkBase(MavlinkConfig(connection=vehicle.connection, **FAST)) as base:
        assert wait_for(lambda: base.odometry() is not None, 2.0)
        recv_match = base._conn.recv_match
        failures = []

        def fails_once(*args, **kwargs):
            if not failures:
                failures.append(1)
                raise AttributeError("'NoneType' object has no attribute 'recv'")
            return recv_match(*args, **kwargs)

        monkeypatch.setattr(base._conn, "recv_match", fails_once)
        assert wait_for(lambda: failures, 2.0)
        first = base.odometry().stamp_s if base.odometry() else 0.0
        assert wait_for(
            lambda: base.odometry() is not None and base.odometry().stamp_s > first + 1.0, 3.0
        ), f"no odometry after the receive error: state {base.state}"
        assert base._receiver.is_alive() and base.state is LinkState.ACTIVE
        assert "MAVLink receive failed (retrying): AttributeError" in caplog.text


# -- connecting, arming, transport --------------------------------------------------------


def _answer_commands(vehicle, answer):
    """The vehicle's COMMAND_LONG handling replaced by `answer(msg)`: the MAV_RESULT to
    acknowledge with, or None for an ACK lost on the way; the rest as before."""
    rover, handle = vehicle.rover, vehicle.rover.handle

    def handle_commands(msg):
        if msg.get_type() != "COMMAND_LONG":
            return handle(msg)
        rover.commands.append(msg.command)
        result = answer(msg)
        if result is not None:
            rover.mav.command_ack_send(msg.command, result)

    rover.handle = handle_commands


def test_a_vehicle_refusing_guided_is_not_left_armed():
    """ArduPilot refuses GUIDED without a position estimate: arming came first, and the
    failed connect left the vehicle armed in the pilot's mode."""
    v = UdpRover(armed=False)
    try:
        _answer_commands(v, lambda msg: mavlink.MAV_RESULT_FAILED
                         if msg.command == mavlink.MAV_CMD_DO_SET_MODE
                         else mavlink.MAV_RESULT_ACCEPTED)  # fmt: skip
        with pytest.raises(MavlinkError, match="refused mode change"):
            MavlinkBase(MavlinkConfig(connection=v.connection, arm=True, **FAST))
        assert mavlink.MAV_CMD_COMPONENT_ARM_DISARM not in v.rover.commands
        assert not v.rover.armed
    finally:
        v.close()


def test_a_connect_failing_after_arming_disarms_the_vehicle(caplog):
    """The vehicle arms but its ACK is lost: connecting fails, and the vehicle, armed by
    us, is told to disarm before the driver lets go of it."""
    v = UdpRover(armed=False)
    rover = v.rover
    try:

        def arm_unanswered(msg):
            if msg.command == mavlink.MAV_CMD_DO_SET_MODE:
                rover.mode = int(msg.param2)
            elif msg.command == mavlink.MAV_CMD_COMPONENT_ARM_DISARM:
                rover.armed = msg.param1 == 1
                return None if rover.armed else mavlink.MAV_RESULT_ACCEPTED
            return mavlink.MAV_RESULT_ACCEPTED

        _answer_commands(v, arm_unanswered)
        fast = dict(FAST, connect_timeout_s=0.6)
        config = MavlinkConfig(connection=v.connection, arm=True, **fast)
        with pytest.raises(MavlinkError, match=r"refused arm \(no acknowledgement\)"):
            MavlinkBase(config)
        assert not rover.armed and "disarmed it again" in caplog.text
    finally:
        v.close()


def test_lost_acknowledgements_before_the_mode_change_do_not_fail_it(caplog):
    """An ArduPilot-like vehicle reports its new mode in its next 1 Hz heartbeat, and
    never acknowledges SET_MESSAGE_INTERVAL: the retries used up the one connect deadline,
    and the mode change, made, was reported failed. A missing interval ACK is a warning."""
    v = UdpRover(rate_hz=30.0)
    rover = v.rover
    next_heartbeat_s = [0.0]

    def tick():  # telemetry at 30 Hz, heartbeats at 1 Hz only
        rover.telemetry()
        if v.peer is not None and time.monotonic() >= next_heartbeat_s[0]:
            next_heartbeat_s[0] = time.monotonic() + 1.0
            rover.heartbeat()

    def answer(msg):
        if msg.command == mavlink.MAV_CMD_DO_SET_MODE:
            rover.mode = int(msg.param2)
        if msg.command != mavlink.MAV_CMD_SET_MESSAGE_INTERVAL:
            return mavlink.MAV_RESULT_ACCEPTED
        return None

    rover.tick = tick
    _answer_commands(v, answer)
    try:
        fast = dict(FAST, connect_timeout_s=0.6, heartbeat_timeout_s=3.0)
        config = MavlinkConfig(connection=v.connection, **fast)
        with MavlinkBase(config) as base:
            assert base.state is LinkState.ACTIVE and rover.mode == GUIDED
        assert "message interval for id 32 not accepted (result None)" in caplog.text
    finally:
        v.close()


def test_a_disarm_while_driving_is_reported(vehicle, caplog):
    with MavlinkBase(MavlinkConfig(connection=vehicle.connection, **FAST)) as base:
        base.send(VelocityCommand(1.0, 0.0, time.monotonic()))
        with caplog.at_level("WARNING", logger="follow.control.mavlink_base"):
            vehicle.rover.armed = False  # the pilot, or a failsafe
            assert wait_for(lambda: "vehicle disarmed" in caplog.text, 1.0)
            assert base.status()["last_error"] == "vehicle disarmed" and not base.healthy()
            assert base.send(VelocityCommand(1.0, 0.0, time.monotonic())).is_stop
            vehicle.rover.armed = True
            assert wait_for(lambda: "vehicle armed" in caplog.text, 1.0)
        assert base.healthy()


class _RouteGone:
    """A UDP or TCP socket whose sends fail while `gone` is set (the route to the vehicle
    gone: ENETUNREACH); receiving goes on."""

    def __init__(self, sock):
        self.sock, self.gone = sock, False

    def __getattr__(self, name):
        return getattr(self.sock, name)

    def _check(self):
        if self.gone:
            raise OSError(101, "Network is unreachable")

    def sendto(self, *args):
        self._check()
        return self.sock.sendto(*args)

    def send(self, *args):
        self._check()
        return self.sock.send(*args)


def test_udp_write_failures_are_reported(vehicle, caplog):
    """pymavlink's UDP write drops OSError: the sender logged nothing, emergency_stop()
    raised nothing and close() logged nothing while no setpoint reached the vehicle."""
    base = MavlinkBase(MavlinkConfig(connection=vehicle.connection, **FAST))
    base._conn.port = port = _RouteGone(base._conn.port)
    base.send(VelocityCommand(1.0, 0.0, time.monotonic()))
    port.gone = True
    assert wait_for(lambda: "MAVLink send failed: [Errno 101]" in caplog.text, 1.0)
    with pytest.raises(MavlinkError, match="emergency stop: .*unreachable"):
        base.emergency_stop()
    base.close()
    assert "send failed while closing: [Errno 101]" in caplog.text


def test_tcp_write_failures_are_reported(caplog):
    """pymavlink's TCP write drops every socket error (and reconnects on a reset only):
    as for UDP, nothing was logged or raised while no setpoint reached the vehicle."""
    v = TcpRover()
    try:
        base = MavlinkBase(MavlinkConfig(connection=f"tcp:127.0.0.1:{v.port}", **FAST))
        base._conn.port = port = _RouteGone(base._conn.port)
        base.send(VelocityCommand(1.0, 0.0, time.monotonic()))
        port.gone = True
        assert wait_for(lambda: "MAVLink send failed: [Errno 101]" in caplog.text, 1.0)
        assert "unreachable" in base.status()["last_error"]
        with pytest.raises(MavlinkError, match="emergency stop: .*unreachable"):
            base.emergency_stop()
        base.close()
        assert "send failed while closing: [Errno 101]" in caplog.text
    finally:
        v.close()


class _TcpPort:
    """A connected TCP socket that takes only `room` bytes of a send (its buffer nearly
    full: a peer that stopped reading), or raises BlockingIOError when it has none."""

    def __init__(self, room):
        self.room, self.sent = room, []

    def send(self, data, flags=0):
        if self.room == 0:
            raise BlockingIOError(11, "Resource temporarily unavailable")
        self.sent.append(bytes(data[: self.room]))
        return min(self.room, len(data))


@pytest.mark.parametrize(
    "port, error",
    [
        (None, r"tcp:host:5760 not connected \(reconnecting\)"),  # a reconnect that failed
        (_TcpPort(room=3), r"write to tcp:host:5760 failed \(3 of 10 bytes\)"),
        (_TcpPort(room=0), r"Resource temporarily unavailable"),
    ],
    ids=["no-socket", "short", "full"],
)
def test_tcp_writes_that_cannot_send_it_all_raise(port, error):
    """pymavlink's TCP write returns quietly with no socket (its reconnect failed), and
    ignores a short write or a full buffer (EAGAIN)."""
    from pymavlink import mavutil

    conn = object.__new__(mavutil.mavtcp)  # its write method, without a connection
    conn.port, conn.address, conn.autoreconnect = port, "tcp:host:5760", False
    base = object.__new__(MavlinkBase)
    base._conn = conn
    base._install_transport()
    with pytest.raises(OSError, match=error):
        conn.write(b"0123456789")


def test_tcpin_writes_raise_and_a_broken_connection_is_dropped_for_the_next():
    """`tcpin` (the vehicle connects to us): pymavlink's write returns quietly with no
    vehicle connected and drops every error. Before any vehicle was heard there is nobody
    to send to (as on udpin, no error); after, a write with none connected is a failure;
    and a broken pipe must still free the listener for the vehicle's next connection."""
    from pymavlink import mavutil

    class Broken:
        closed = False

        def send(self, data, flags=0):
            raise BrokenPipeError(32, "Broken pipe")

        def close(self):
            self.closed = True

    class Listener:
        def fileno(self):
            return 7

    conn = object.__new__(mavutil.mavtcpin)
    conn.port, conn.address, conn.listen, conn.fd = None, "tcpin:0.0.0.0:5760", Listener(), 9
    base = object.__new__(MavlinkBase)
    base._conn, base._target = conn, None
    base._install_transport()
    conn.write(b"abc")  # no vehicle heard yet: nobody to send to, nothing to report
    base._target = (1, 1)  # the vehicle was heard, and has gone
    with pytest.raises(OSError, match=r"tcpin:0.0.0.0:5760 not connected \(no vehicle"):
        conn.write(b"abc")
    conn.port = broken = Broken()
    with pytest.raises(BrokenPipeError):
        conn.write(b"abc")
    assert broken.closed and conn.port is None and conn.fd == 7


def test_closing_a_tcp_link_left_without_a_socket_does_not_raise():
    """pymavlink's TCP close calls the socket's close, and a reconnect that failed left
    none: close() must still end quietly (its zeros went out, or failed, before)."""
    from pymavlink import mavutil

    conn = object.__new__(mavutil.mavtcp)
    conn.port, conn.address, conn.autoreconnect = None, "tcp:host:5760", False
    base = object.__new__(MavlinkBase)
    base._conn = conn
    base._close_link()  # AttributeError from pymavlink without the guard


def test_serial_write_failures_raise():
    """pymavlink's serial write returns -1 when the port fails (a USB adapter pulled)."""
    from pymavlink import mavutil

    class Unplugged:
        def write(self, data):
            raise OSError(5, "Input/output error")

    conn = object.__new__(mavutil.mavserial)  # its write method, without a device
    conn.port, conn.device = Unplugged(), "/dev/tty0"
    conn.portdead, conn.autoreconnect = True, False
    base = object.__new__(MavlinkBase)
    base._conn = conn
    base._install_transport()
    with pytest.raises(OSError, match=r"write to /dev/tty0 failed \(-1 of 3 bytes\)"):
        conn.write(b"abc")


def test_udpin_sends_to_the_vehicle_only():
    """pymavlink's udpin sends to every address that ever sent to its port, kept for
    ever (a ground station restarted on new ports, a scan): setpoints went to them all."""
    import socket

    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    v = UdpRover()
    v.peer = ("127.0.0.1", port)  # the vehicle sends to our udpin port (SITL's --out)
    stranger = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    stranger.settimeout(0.5)
    gcs = mavlink.MAVLink(None, srcSystem=255, srcComponent=190)
    try:
        with MavlinkBase(MavlinkConfig(connection=f"udpin:127.0.0.1:{port}", **FAST)) as base:
            hb = gcs.heartbeat_encode(mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0)
            stranger.sendto(hb.pack(gcs), ("127.0.0.1", port))
            n0 = len(v.rover.setpoints)
            drive_s = time.monotonic() + 0.5
            while time.monotonic() < drive_s:
                base.send(VelocityCommand(0.5, 0.0, time.monotonic()))
                time.sleep(0.05)
            assert len(v.rover.setpoints) - n0 >= 5 and base.state is LinkState.ACTIVE
            with pytest.raises(TimeoutError):
                stranger.recvfrom(65536)  # nothing for the stranger
    finally:
        stranger.close()
        v.close()
