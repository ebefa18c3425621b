"""The driver's contract with an ArduPilot Rover, run against the simulated rover and,
where $ARDUROVER_BIN names an ArduPilot SITL `ardurover` binary, against SITL too.

SITL: started as `$ARDUROVER_BIN --model rover --speedup 1 -I N --defaults
$ARDUROVER_DEFAULTS --serial0 udpclient:127.0.0.1:P0 --serial1 udpclient:127.0.0.1:P1`
(serial1 plays the pilot's ground station). It has no RC pilot to arm it, so the driver
is configured to arm, and GUIDED is retried until the EKF has an origin.
"""

from __future__ import annotations

import math
import os
import random
import socket
import subprocess
import tempfile
import time

import pytest
from pymavlink import mavutil
from waiting import wait_for

from follow.config import MavlinkConfig
from follow.control import mavlink_frames as mf
from follow.control.mavlink_base import LinkState, MavlinkBase, MavlinkError
from follow.sim.rover import SimRover
from follow.types import VelocityCommand

mavlink = mavutil.mavlink


def drive(base, forward, yaw_rate, seconds):
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        base.send(VelocityCommand(forward, yaw_rate, time.monotonic()))
        time.sleep(0.05)


class SimVehicle:
    name = "sim"

    def __init__(self):
        self.rover = SimRover(heartbeat_rate_hz=5).start()
        self.config = MavlinkConfig(
            connection=self.rover.connection, heartbeat_timeout_s=0.6, connect_timeout_s=2.0
        )
        self.settle_s = 1.0

    def connect(self) -> MavlinkBase:
        return MavlinkBase(self.config)

    def pilot_set_mode(self, mode: int) -> None:
        self.rover.pilot_set_mode(mode)

    def ground_speed_mps(self) -> float:
        return abs(self.rover.true_velocity()[0])

    def close(self):
        self.rover.stop()


def _free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class SitlVehicle:
    name = "sitl"

    def __init__(self, binary: str):
        port, self._pilot_port = _free_udp_port(), _free_udp_port()
        self._workdir = tempfile.TemporaryDirectory()
        cmd = [
            binary, "--model", "rover", "--speedup", "1", "-I", str(random.randint(10, 60)),
            "--serial0", f"udpclient:127.0.0.1:{port}",
            "--serial1", f"udpclient:127.0.0.1:{self._pilot_port}",
        ]  # fmt: skip
        if os.environ.get("ARDUROVER_DEFAULTS"):
            cmd += ["--defaults", os.environ["ARDUROVER_DEFAULTS"]]
        self._proc = subprocess.Popen(
            cmd, cwd=self._workdir.name, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL
        )
        self.config = MavlinkConfig(connection=f"udpin:127.0.0.1:{port}", arm=True)
        self.settle_s = 3.0
        self._pilot_conn = None

    def connect(self) -> MavlinkBase:
        deadline = time.monotonic() + 120.0
        while True:  # GUIDED and arming are refused until the EKF and pre-arm checks pass
            try:
                return MavlinkBase(self.config)
            except MavlinkError:
                if time.monotonic() > deadline:
                    raise
                time.sleep(2.0)

    def _pilot(self):
        if self._pilot_conn is None:
            self._pilot_conn = mavutil.mavlink_connection(
                f"udpin:127.0.0.1:{self._pilot_port}", source_system=255, source_component=190
            )
            self._pilot_conn.wait_heartbeat(timeout=5)
            self._pilot_conn.mav.command_long_send(
                1, 1, mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, 0, 74, 1e5, 0, 0, 0, 0, 0
            )  # VFR_HUD at 10 Hz
        return self._pilot_conn

    def pilot_set_mode(self, mode: int) -> None:
        self._pilot().mav.command_long_send(
            1, 1, mavlink.MAV_CMD_DO_SET_MODE, 0,
            mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, mode, 0, 0, 0, 0, 0,
        )  # fmt: skip

    def ground_speed_mps(self) -> float:
        newest = None
        while msg := self._pilot().recv_match(type="VFR_HUD", blocking=newest is None, timeout=1):
            newest = msg
        return math.inf if newest is None else newest.groundspeed

    def close(self):
        if self._pilot_conn is not None:
            self._pilot_conn.close()
        self._proc.terminate()
        self._proc.wait(timeout=10)
        self._workdir.cleanup()


@pytest.fixture(params=["sim", "sitl"])
def vehicle(request):
    if request.param == "sitl":
        binary = os.environ.get("ARDUROVER_BIN")
        if not binary:
            pytest.skip("ARDUROVER_BIN is not set (path to an ArduPilot SITL ardurover binary)")
        if not os.access(binary, os.X_OK):
            pytest.fail(f"ARDUROVER_BIN={binary} is not an executable file")
        v = SitlVehicle(binary)
    else:
        v = SimVehicle()
    yield v
    v.close()


def test_guided_odometry_and_command_directions(vehicle):
    with vehicle.connect() as base:
        assert base.vehicle_mode == mf.ROVER_MODE_GUIDED and base.state is LinkState.ACTIVE
        assert wait_for(lambda: base.odometry() is not None, 2.0)
        start = base.odometry()
        drive(base, 0.6, 0.0, vehicle.settle_s)
        moved = base.odometry()
        ahead = (moved.x_m - start.x_m) * math.cos(start.yaw_rad) + (
            moved.y_m - start.y_m
        ) * math.sin(start.yaw_rad)
        assert ahead > 0.3  # forward is forward
        drive(base, 0.0, 0.5, vehicle.settle_s)
        turned = base.odometry()
        dyaw = math.atan2(
            math.sin(turned.yaw_rad - moved.yaw_rad), math.cos(turned.yaw_rad - moved.yaw_rad)
        )
        assert dyaw > 0.2  # positive yaw rate turns left (counter-clockwise) in odom


def test_pilot_mode_switch_stops_commanding(vehicle):
    with vehicle.connect() as base:
        drive(base, 0.5, 0.0, 0.5)
        vehicle.pilot_set_mode(mf.ROVER_MODE_HOLD)
        assert wait_for(lambda: base.state is LinkState.MODE_OVERRIDDEN, 3.0)
        sent = base.setpoints_sent
        drive(base, 0.5, 0.0, 0.5)
        assert base.setpoints_sent == sent and base.vehicle_mode == mf.ROVER_MODE_HOLD


def test_close_brings_the_vehicle_to_rest(vehicle):
    base = vehicle.connect()
    drive(base, 0.8, 0.0, vehicle.settle_s)
    assert vehicle.ground_speed_mps() > 0.5
    base.close()
    # At rest well before the vehicle's own 3 s setpoint timeout would stop it.
    assert wait_for(lambda: vehicle.ground_speed_mps() < 0.05, 1.5)
