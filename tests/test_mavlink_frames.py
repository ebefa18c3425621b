import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from follow.control import mavlink_frames as mf
from follow.types import VelocityCommand

angles = st.floats(-math.pi + 1e-6, math.pi - 1e-6)
coords = st.floats(-1e4, 1e4)


@given(coords, coords, angles)
def test_ned_odom_round_trip(x, y, yaw):
    back = mf.ned_pose_to_odom(*mf.odom_pose_to_ned(x, y, yaw))
    assert back == pytest.approx((x, y, yaw), abs=1e-9)


def test_ned_to_odom_mirrors_east_and_yaw():
    # Facing east (NED yaw +90 deg) is facing -y in odom, i.e. yaw -90 deg.
    assert mf.ned_pose_to_odom(1.0, 2.0, math.pi / 2) == pytest.approx((1.0, -2.0, -math.pi / 2))


def test_ardupilot_setpoint_is_frd_with_clockwise_yaw_rate():
    assert mf.ardupilot_setpoint(VelocityCommand(0.7, 0.3, 0.0)) == (0.7, 0.0, -0.3)
    assert mf.TYPE_MASK_VELOCITY_YAW_RATE == 0x05C7
    assert mf.TYPE_MASK_VELOCITY_ONLY == 0x0DC7


def test_px4_setpoint_turns_through_the_velocity_direction():
    vx, vy = mf.px4_setpoint(VelocityCommand(1.0, 0.5, 0.0), turn_horizon_s=0.5)
    assert math.hypot(vx, vy) == pytest.approx(1.0)  # speed kept
    assert vy < 0 and math.atan2(-vy, vx) == pytest.approx(0.25)  # left = FRD -y
    assert mf.px4_setpoint(VelocityCommand(1.0, 0.0, 0.0), 0.5) == pytest.approx((1.0, 0.0))
    vx, vy = mf.px4_setpoint(VelocityCommand(1.0, -10.0, 0.0), 0.5)
    assert vx == pytest.approx(0.0, abs=1e-12) and vy == pytest.approx(1.0)  # capped at 90 deg
    # Backing while turning left (counter-clockwise): the velocity, pointing backward,
    # turns counter-clockwise too, so backward and to the right (FRD +y).
    vx, vy = mf.px4_setpoint(VelocityCommand(-0.5, 0.5, 0.0), turn_horizon_s=0.5)
    assert vx < 0 and vy > 0 and math.hypot(vx, vy) == pytest.approx(0.5)


def test_px4_custom_mode_packing():
    mode = mf.px4_custom_mode(mf.PX4_MAIN_MODE_OFFBOARD)
    assert mode == 6 << 16 and mf.px4_main_mode(mode) == 6
