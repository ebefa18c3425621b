import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from follow.config import ConfigError, ControlConfig
from follow.control.base import Base, NullBase
from follow.control.controller import FollowingController, slew
from follow.control.target import TargetMotion
from follow.types import InvalidInput, Odometry, VelocityCommand

CFG = ControlConfig()
PERIOD = 1.0 / CFG.control_rate_hz


def target(x, y, vx=0.0, vy=0.0, stamp=0.0):
    return TargetMotion(np.array([x, y]), np.array([vx, vy]), stamp)


def run(controller, make_target, seconds, t0=0.0):
    cmd = None
    steps = int(seconds / PERIOD)
    for i in range(steps):
        t = t0 + i * PERIOD
        cmd = controller.update(make_target(t), t)
    return cmd


def test_drives_toward_a_far_target_and_stops_at_the_set_distance():
    c = FollowingController()
    far = run(c, lambda t: target(4.0, 0.0, stamp=t), 3.0)
    assert far.forward_mps == pytest.approx(CFG.max_forward_speed_mps)
    assert abs(far.yaw_rate_radps) < 1e-9
    c = FollowingController()
    at_set = run(c, lambda t: target(CFG.following_distance_m, 0.0, stamp=t), 1.0)
    assert at_set.forward_mps == pytest.approx(0.0, abs=1e-9)


def test_never_backs_off_unless_enabled():
    too_close = lambda t: target(0.8, 0.0, stamp=t)  # noqa: E731
    assert run(FollowingController(), too_close, 2.0).forward_mps == 0.0
    backing = FollowingController(ControlConfig(allow_backing_off=True))
    cmd = run(backing, too_close, 2.0)
    assert cmd.forward_mps == pytest.approx(-CFG.max_backward_speed_mps)


def test_turns_toward_the_target_and_in_place_when_bearing_is_large():
    left = run(FollowingController(), lambda t: target(3.0, 1.0, stamp=t), 2.0)
    assert left.yaw_rate_radps > 0 and left.forward_mps > 0
    right = run(FollowingController(), lambda t: target(3.0, -1.0, stamp=t), 2.0)
    assert right.yaw_rate_radps < 0
    beside = run(FollowingController(), lambda t: target(0.5, -3.0, stamp=t), 2.0)
    assert beside.forward_mps == 0.0
    assert beside.yaw_rate_radps == pytest.approx(-CFG.max_yaw_rate_radps)


def test_feed_forward_matches_a_walking_target_without_distance_error():
    walking = run(FollowingController(), lambda t: target(1.8, 0.0, 1.0, 0.0, stamp=t), 3.0)
    assert walking.forward_mps == pytest.approx(1.0, abs=1e-6)
    no_ff = FollowingController(ControlConfig(velocity_feedforward_gain=0.0))
    assert run(no_ff, lambda t: target(1.8, 0.0, 1.0, 0.0, stamp=t), 3.0).forward_mps == 0.0


def test_acceleration_is_limited_when_starting():
    c = FollowingController()
    first = c.update(target(5.0, 0.0, stamp=0.0), 0.0)
    assert first.forward_mps == pytest.approx(CFG.max_forward_accel_mps2 * PERIOD)
    second = c.update(target(5.0, 0.0, stamp=PERIOD), PERIOD)
    assert second.forward_mps == pytest.approx(2 * CFG.max_forward_accel_mps2 * PERIOD)


@pytest.mark.parametrize(
    "previous, wanted, expected",
    [
        (0.0, 1.0, 0.1),  # speeding up: rise limit
        (0.5, 1.0, 0.6),
        (1.0, 0.0, 0.8),  # braking: fall limit
        (1.0, 0.95, 0.95),
        (-0.05, 1.0, 0.075),  # 0.025 s to stop, then 0.075 s at the rise limit
        (0.3, -1.0, 0.1),  # still braking
    ],
)
def test_slew_brakes_before_reversing(previous, wanted, expected):
    assert slew(previous, wanted, 1.0, 2.0, 0.1) == pytest.approx(expected)


def test_loss_gives_zero_within_one_period_even_at_full_speed():
    c = FollowingController()
    moving = run(c, lambda t: target(5.0, 0.5, stamp=t), 3.0)
    assert moving.forward_mps > 1.0 and moving.yaw_rate_radps != 0
    lost = c.update(None, 3.0 + PERIOD)
    assert lost.is_stop


def test_stale_estimate_gives_zero_but_a_fresh_one_does_not():
    c = FollowingController()
    run(c, lambda t: target(5.0, 0.0, stamp=t), 2.0)
    t = 2.0
    fresh = c.update(target(5.0, 0.0, stamp=t - 0.9 * CFG.target_timeout_s), t)
    assert fresh.forward_mps > 0
    stale = c.update(target(5.0, 0.0, stamp=t - 1.1 * CFG.target_timeout_s), t + PERIOD)
    assert stale.is_stop


def test_search_turns_toward_last_bearing_for_a_bounded_time_then_stops():
    cfg = ControlConfig(search_duration_s=1.0)
    c = FollowingController(cfg)
    run(c, lambda t: target(3.0, -0.5, stamp=t), 1.0)
    t = 1.0
    first = c.update(None, t)
    assert first.forward_mps == 0.0  # forward stops at once even while searching
    yaws = [c.update(None, t + k * PERIOD).yaw_rate_radps for k in range(1, 10)]
    assert yaws[-1] == pytest.approx(-cfg.search_yaw_rate_radps)
    after = c.update(None, t + cfg.search_duration_s + PERIOD)
    assert after.is_stop


def test_bad_inputs_are_named():
    with pytest.raises(InvalidInput, match="position_m"):
        target(float("nan"), 0.0)
    with pytest.raises(InvalidInput, match="velocity_mps"):
        TargetMotion(np.zeros(2), np.zeros(3), 0.0)
    with pytest.raises(ConfigError, match="max_forward_speed_mps"):
        FollowingController(ControlConfig(max_forward_speed_mps=-1.0))
    with pytest.raises(InvalidInput, match="stamp_s"):
        FollowingController().update(None, float("inf"))


finite = st.floats(-20, 20, allow_nan=False)
step = st.tuples(
    st.one_of(st.none(), st.tuples(finite, finite, finite, finite, st.floats(0, 1.5))),
    st.floats(0.0, 0.3),
)


@settings(max_examples=100, deadline=None)
@given(
    steps=st.lists(step, min_size=1, max_size=40),
    backing=st.booleans(),  # with backing off, commands change sign
    search=st.floats(0, 2),
)
def test_no_command_ever_exceeds_its_limits(steps, backing, search):
    cfg = ControlConfig(allow_backing_off=backing, search_duration_s=search)
    c = FollowingController(cfg)
    t = 0.0
    prev = None
    for spec, dt in steps:
        t += dt
        tgt = None
        if spec is not None:
            x, y, vx, vy, age = spec
            if math.hypot(x, y) > 1e-6:
                tgt = target(x, y, vx, vy, stamp=t - age)
        cmd = c.update(tgt, t)
        lo = -cfg.max_backward_speed_mps if backing else 0.0
        assert lo - 1e-9 <= cmd.forward_mps <= cfg.max_forward_speed_mps + 1e-9
        assert abs(cmd.yaw_rate_radps) <= cfg.max_yaw_rate_radps + 1e-9
        fresh = tgt is not None and t - tgt.stamp_s <= cfg.target_timeout_s
        if not fresh:
            assert cmd.forward_mps == 0.0
            if search == 0:
                assert cmd.is_stop
        else:
            # Speeding up is never faster than the acceleration limit; the first command
            # starts from standstill one control period earlier.
            dt = c.period_s if prev is None else t - prev.stamp_s
            prev = prev or VelocityCommand.stop(t - dt)
            for now_v, before_v, rise, fall in (
                (cmd.forward_mps, prev.forward_mps, cfg.max_forward_accel_mps2,
                 cfg.max_forward_decel_mps2),
                (cmd.yaw_rate_radps, prev.yaw_rate_radps, cfg.max_yaw_accel_radps2,
                 cfg.max_yaw_accel_radps2),
            ):  # fmt: skip
                if now_v * before_v > 0 or before_v == 0:
                    if abs(now_v) >= abs(before_v):
                        assert abs(now_v) - abs(before_v) <= rise * dt + 1e-9
                    else:
                        assert abs(before_v) - abs(now_v) <= fall * dt + 1e-9
                else:  # reached or crossed zero: braked all the way, then sped up
                    assert abs(before_v) <= fall * dt + 1e-9
                    assert abs(now_v) <= rise * dt + 1e-9
        prev = cmd


def test_null_base_records_and_stops_on_close():
    base = NullBase(clock=lambda: 7.0)
    assert isinstance(base, Base)
    assert base.odometry() == Odometry(0.0, 0.0, 0.0, 7.0)
    base.send(VelocityCommand(0.5, 0.1, 1.0))
    assert base.healthy() and base.last_command.forward_mps == 0.5
    base.close()
    assert base.last_command.is_stop and not base.healthy()
    with pytest.raises(RuntimeError, match="after close"):
        base.send(VelocityCommand(0.5, 0.1, 2.0))


def test_a_starved_control_step_speeds_up_by_two_periods_at_most_but_brakes_in_full():
    """A control thread that runs again 1 s late (a loaded CPU) jumped a second's
    acceleration in one command (0.3 -> 1.5 m/s); the base spent that second at the old
    speed. Speeding up now counts two periods at most; braking keeps the whole step."""
    c = FollowingController()
    c.update(target(4.0, 0.0, stamp=0.0), 0.0)
    start = c.update(target(4.0, 0.0, stamp=PERIOD), PERIOD).forward_mps
    late = c.update(target(4.0, 0.0, stamp=1.0 + PERIOD), 1.0 + PERIOD).forward_mps
    assert late - start == pytest.approx(2 * PERIOD * CFG.max_forward_accel_mps2)
    # braking from full speed toward a target at the set distance, after a late step
    assert slew(1.5, 0.0, 1.5, 2.0, 1.0, rise_dt_s=2 * PERIOD) == 0.0
    # a sign change: braking takes its time from the whole step, the rise after it is capped
    assert slew(0.2, -1.0, 1.5, 2.0, 1.0, rise_dt_s=2 * PERIOD) == pytest.approx(
        -1.5 * 2 * PERIOD
    )


@pytest.mark.parametrize("xy", [(-1.0, 0.25), (-3.0, 0.5), (-0.2, 1.2)])
def test_a_target_behind_is_never_driven_toward_or_reversed_into(xy):
    """With `turn_in_place_bearing_rad` past 90 degrees (allowed up to pi) a target
    behind the robot was inside the forward rule: close, it was backed into at full
    backing speed; far, driven away from. Only the part along the heading counts."""
    cfg = ControlConfig(allow_backing_off=True, turn_in_place_bearing_rad=3.0)
    command = run(FollowingController(cfg), lambda t: target(*xy, stamp=t), 1.0)
    assert command.forward_mps == 0.0 and command.yaw_rate_radps != 0.0


def test_backing_off_from_a_close_target_ahead_still_works():
    cfg = ControlConfig(allow_backing_off=True)
    command = run(FollowingController(cfg), lambda t: target(0.8, 0.1, stamp=t), 2.0)
    assert command.forward_mps < 0.0


def test_a_search_ends_when_the_clock_steps_back_instead_of_lasting_the_step():
    """The search turn is timed from the loss; a clock stepped back a minute (NTP, a
    simulator restarted) made it last that minute more."""
    cfg = ControlConfig(search_duration_s=2.0, search_yaw_rate_radps=0.4)
    c = FollowingController(cfg)
    run(c, lambda t: target(3.0, 1.0, stamp=t), 0.5, t0=100.0)
    assert c.update(None, 100.6).yaw_rate_radps > 0.0  # searching
    turning = [not c.update(None, 40.6 + i * PERIOD).is_stop for i in range(60)]
    assert not any(turning)


def test_a_target_far_past_any_person_is_refused_by_name_not_overflowed():
    with pytest.raises(InvalidInput, match=r"target position_m \[1e\+155, 0.0\] is beyond"):
        target(1e155, 0.0)
    with pytest.raises(InvalidInput, match="target velocity_mps .* is beyond"):
        target(2.0, 0.0, vx=1e308)
