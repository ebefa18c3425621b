"""A minimal fake ArduPilot Rover (and fake GCS / foreign components) written directly on
pymavlink's MAVLink encoder/parser, independent of follow/sim/rover.py.

Transport-agnostic: give it a `write(bytes)` callable and feed it received bytes."""

from __future__ import annotations

import threading
import time

from pymavlink.dialects.v20 import ardupilotmega as mavlink

GUIDED = 15
MANUAL = 0


class _Writer:
    def __init__(self, write):
        self._write = write

    def write(self, data):
        try:
            self._write(bytes(data))
        except OSError:
            pass


class FakeRover:
    def __init__(self, write, sysid=1, compid=1, mode=MANUAL, armed=True,
                 mav_type=mavlink.MAV_TYPE_GROUND_ROVER,
                 autopilot=mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA):
        self.sysid, self.compid = sysid, compid
        self.autopilot = autopilot
        self.mav = mavlink.MAVLink(_Writer(write), srcSystem=sysid, srcComponent=compid)
        self.parser = mavlink.MAVLink(None)
        self.parser.robust_parsing = True
        self.mode, self.armed, self.mav_type = mode, armed, mav_type
        self.boot = time.monotonic()
        self.setpoints: list[tuple[float, int, int, float, float, float]] = []
        self.commands: list[int] = []
        self.north = self.east = self.yaw = 0.0
        self.lock = threading.Lock()
        self.silent = False

    def boot_ms(self):
        return int((time.monotonic() - self.boot) * 1000)

    def feed(self, data: bytes):
        for msg in self.parser.parse_buffer(data) or []:
            self.handle(msg)

    def handle(self, msg):
        kind = msg.get_type()
        with self.lock:
            if kind == "COMMAND_LONG" and msg.target_system in (0, self.sysid):
                self.commands.append(msg.command)
                if msg.command == mavlink.MAV_CMD_DO_SET_MODE:
                    self.mode = int(msg.param2)
                if msg.command == mavlink.MAV_CMD_COMPONENT_ARM_DISARM:
                    self.armed = msg.param1 == 1
                if not self.silent:
                    self.mav.command_ack_send(msg.command, mavlink.MAV_RESULT_ACCEPTED)
                    self.heartbeat()
            elif kind == "SET_POSITION_TARGET_LOCAL_NED":
                self.setpoints.append((time.monotonic(), msg.coordinate_frame, msg.type_mask,
                                       msg.vx, msg.vy, msg.yaw_rate))

    def heartbeat(self):
        base_mode = mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
        if self.armed:
            base_mode |= mavlink.MAV_MODE_FLAG_SAFETY_ARMED
        self.mav.heartbeat_send(self.mav_type, self.autopilot,
                                base_mode, self.mode, mavlink.MAV_STATE_ACTIVE)

    def telemetry(self):
        t = self.boot_ms()
        self.mav.local_position_ned_send(t, self.north, self.east, 0, 0, 0, 0)
        self.mav.attitude_send(t, 0, 0, self.yaw, 0, 0, 0)

    def tick(self):
        with self.lock:
            if self.silent:
                return
            self.heartbeat()
            self.telemetry()


class UdpRover:
    """FakeRover on a UDP socket bound to 127.0.0.1 (connect with udpout:127.0.0.1:PORT)."""

    def __init__(self, rate_hz=20.0, **kw):
        import socket

        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.settimeout(0.01)
        self.port = self.sock.getsockname()[1]
        self.peer = None
        self.rover = FakeRover(self._write, **kw)
        self.rate_hz = rate_hz
        self.extra: list = []  # callables run every tick (fake GCS, other components)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    @property
    def connection(self):
        return f"udpout:127.0.0.1:{self.port}"

    def _write(self, data):
        if self.peer is not None:
            self.sock.sendto(data, self.peer)

    def _run(self):
        next_t = 0.0
        while not self._stop.is_set():
            try:
                data, addr = self.sock.recvfrom(65536)
                self.peer = addr
                self.rover.feed(data)
            except OSError:
                pass
            if time.monotonic() >= next_t:
                next_t = time.monotonic() + 1.0 / self.rate_hz
                self.rover.tick()
                for fn in self.extra:
                    fn()

    def close(self):
        self._stop.set()
        self._thread.join(1)
        self.sock.close()
