"""MAVLink conventions used by the base driver and the simulated rover, as pure functions.

Frames: MAVLink's local frame is NED (x north, y east, z down, yaw clockwise from north)
and its body frame FRD (x forward, y right, z down). Ours are x forward, y left, z up
(`base`) and a fixed `odom` with the same axes. We define

    odom x = NED x,   odom y = -NED y,   odom yaw = -NED yaw,

so `odom` is NED mirrored about its x axis (x stays north, y points west, z up), and a
body-frame command converts as FRD x = forward, FRD y = -left, NED yaw rate = -yaw rate.
"""

from __future__ import annotations

import math

from follow.frames import wrap_angle
from follow.types import VelocityCommand

# ArduPilot Rover custom modes (heartbeat custom_mode).
ROVER_MODE_MANUAL = 0
ROVER_MODE_ACRO = 1
ROVER_MODE_STEERING = 3
ROVER_MODE_HOLD = 4
ROVER_MODE_LOITER = 5
ROVER_MODE_AUTO = 10
ROVER_MODE_RTL = 11
ROVER_MODE_GUIDED = 15
ROVER_MODES = {
    ROVER_MODE_MANUAL: "MANUAL", ROVER_MODE_ACRO: "ACRO", ROVER_MODE_STEERING: "STEERING",
    ROVER_MODE_HOLD: "HOLD", ROVER_MODE_LOITER: "LOITER", ROVER_MODE_AUTO: "AUTO",
    ROVER_MODE_RTL: "RTL", ROVER_MODE_GUIDED: "GUIDED",
}  # fmt: skip

# PX4: custom_mode carries the main mode in bits 16..23; OFFBOARD is main mode 6.
PX4_MAIN_MODE_OFFBOARD = 6

# SET_POSITION_TARGET_*.type_mask bits (1 = ignore that field).
MASK_POSITION_IGNORE = 0x0007
MASK_VELOCITY_IGNORE = 0x0038
MASK_ACCELERATION_IGNORE = 0x01C0
MASK_FORCE = 0x0200
MASK_YAW_IGNORE = 0x0400
MASK_YAW_RATE_IGNORE = 0x0800
# Velocity + yaw rate only: position, acceleration and yaw ignored.
TYPE_MASK_VELOCITY_YAW_RATE = MASK_POSITION_IGNORE | MASK_ACCELERATION_IGNORE | MASK_YAW_IGNORE
# Velocity only (PX4 rovers, which ignore yaw rate).
TYPE_MASK_VELOCITY_ONLY = TYPE_MASK_VELOCITY_YAW_RATE | MASK_YAW_RATE_IGNORE

assert TYPE_MASK_VELOCITY_YAW_RATE == 0x05C7

# Message ids streamed for odometry.
MSG_ID_ATTITUDE = 30
MSG_ID_LOCAL_POSITION_NED = 32


def px4_custom_mode(main_mode: int, sub_mode: int = 0) -> int:
    return (main_mode << 16) | (sub_mode << 24)


def px4_main_mode(custom_mode: int) -> int:
    return (custom_mode >> 16) & 0xFF


def ned_pose_to_odom(
    north_m: float, east_m: float, yaw_ned_rad: float
) -> tuple[float, float, float]:
    """(x, y, yaw) in `odom` from a NED position and yaw."""
    return north_m, -east_m, float(wrap_angle(-yaw_ned_rad))


def odom_pose_to_ned(x_m: float, y_m: float, yaw_rad: float) -> tuple[float, float, float]:
    """Inverse of `ned_pose_to_odom`."""
    return x_m, -y_m, float(wrap_angle(-yaw_rad))


def ardupilot_setpoint(cmd: VelocityCommand) -> tuple[float, float, float]:
    """(vx, vy, yaw_rate) for SET_POSITION_TARGET_LOCAL_NED in MAV_FRAME_BODY_OFFSET_NED:
    FRD body velocity and a NED (clockwise-positive) yaw rate."""
    return cmd.forward_mps, 0.0, -cmd.yaw_rate_radps


def px4_setpoint(cmd: VelocityCommand, turn_horizon_s: float) -> tuple[float, float]:
    """(vx, vy) FRD body velocity for a rover that ignores yaw rate: the speed is kept and
    the velocity turns with the heading, by the angle the commanded turn reaches within
    the horizon (at most 90 degrees); backing while turning left, the rear swings right.
    A turn on the spot (zero speed) cannot be expressed this way."""
    angle = max(-math.pi / 2, min(math.pi / 2, cmd.yaw_rate_radps * turn_horizon_s))
    speed = cmd.forward_mps
    return speed * math.cos(angle), -speed * math.sin(angle)
