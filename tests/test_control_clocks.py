"""Stale data cannot pass for fresh data: a stamp ahead of the reading clock (a camera
or base driver on a host whose clock runs ahead, a clock stepped back) stops the base,
a clock that steps back cannot put the control loop to sleep on a moving command, and
nothing but zero leaves the control loop once it is told to stop."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest

from follow import pipeline
from follow.capture import LatestSlot
from follow.config import ControlConfig
from follow.control.base import NullBase
from follow.control.controller import FollowingController
from follow.control.target import TargetMotion
from follow.freshness import MAX_STAMP_AHEAD_S, is_fresh
from follow.pipeline import ControlLoop, FrameResult
from follow.ros2.gate import CmdVelGate
from follow.types import Observation, Odometry, TargetEstimate, TargetStatus, TrackState

SEEN = Observation(np.array([320.0, 200.0]), np.array([320.0, 400.0]))


def _result(stamp_s: float) -> FrameResult:
    track = TrackState(7, np.array([5.0, 0.0, 0.0, 0.0, 1.5]), np.eye(5) * 0.01, True, stamp_s,
                       observation=SEEN)  # fmt: skip
    return FrameResult(0, stamp_s, Odometry.origin(stamp_s), [], [track],
                       TargetEstimate(TargetStatus.TRACKING, 7, {7: 0.9}, stamp_s))  # fmt: skip


def test_a_stamp_ahead_of_the_clock_is_not_fresh():
    assert is_fresh(10.0, 9.8, 0.5) and is_fresh(10.0, 10.0 + 0.5 * MAX_STAMP_AHEAD_S, 0.5)
    assert not is_fresh(10.0, 9.4, 0.5)  # too old
    assert not is_fresh(10.0, 10.0 + 2 * MAX_STAMP_AHEAD_S, 0.5)  # from the future


def test_frames_stamped_ahead_of_the_control_clock_stop_the_base(caplog):
    now = [100.0]
    slot = LatestSlot()
    loop = ControlLoop(FollowingController(ControlConfig()), NullBase(clock=lambda: now[0]),
                       slot, rate_hz=15.0, perception_timeout_s=0.5, clock=lambda: now[0])  # fmt: skip
    slot.put(_result(now[0]))
    assert not loop.tick().is_stop  # in step: following
    for _ in range(10):  # the camera's clock jumps 3 s ahead
        now[0] += 1 / 15
        slot.put(_result(now[0] + 3.0))
        assert loop.tick().is_stop
    assert loop.watchdog_trips == 1
    assert "ahead of the control clock" in caplog.text


def test_the_controller_does_not_follow_an_estimate_from_the_future():
    controller = FollowingController(ControlConfig())
    target = TargetMotion(np.array([3.0, 0.0]), np.zeros(2), 10.0)
    assert not controller.update(target, 10.0).is_stop
    assert controller.update(TargetMotion(np.array([3.0, 0.0]), np.zeros(2), 13.0), 10.1).is_stop


def test_the_ros_gate_takes_odometry_from_the_future_for_stale():
    now = [100.0]
    gate = CmdVelGate(lambda command: None, lambda: now[0], max_odometry_age_s=0.2)
    gate.update_odometry(Odometry.origin(now[0] + 3.0))  # the base driver's clock runs ahead
    assert gate.odometry() is None and not gate.healthy()


def test_a_clock_stepping_back_does_not_silence_the_control_loop():
    """The loop's clock steps back 5 s as the camera stops: ticks go on (timed on the
    monotonic clock) and the base is stopped within the watchdog."""
    offset = [0.0]

    def clock() -> float:
        return time.monotonic() + offset[0]

    slot = LatestSlot()
    base = NullBase(clock=clock)
    loop = ControlLoop(FollowingController(ControlConfig()), base, slot, rate_hz=20.0,
                       perception_timeout_s=0.3, clock=clock).start()  # fmt: skip
    try:
        for _ in range(6):
            slot.put(_result(clock()))
            loop.notify()
            time.sleep(0.05)
        assert not base.commands[-1].is_stop
        offset[0] -= 5.0
        sent_before = len(base.commands)
        time.sleep(0.6)
        after = list(base.commands)[sent_before:]
        assert len(after) >= 5 and after[-1].is_stop
    finally:
        loop.stop()


def test_nothing_but_zero_leaves_the_loop_after_stop(monkeypatch):
    """A tick stalled past stop()'s wait (a blocked odometry read) ends with zero, not
    with the moving command it was computing."""
    monkeypatch.setattr(pipeline, "STOP_JOIN_TIMEOUT_S", 0.2)
    stall, stalled = threading.Event(), threading.Event()

    class SlowOdometry(NullBase):
        def odometry(self):
            if stall.is_set() and not stalled.is_set():
                stalled.set()
                time.sleep(0.6)
            return super().odometry()

    slot = LatestSlot()
    base = SlowOdometry()
    loop = ControlLoop(FollowingController(ControlConfig()), base, slot, rate_hz=20.0,
                       perception_timeout_s=0.5).start()  # fmt: skip
    for _ in range(4):
        slot.put(_result(time.monotonic()))
        loop.notify()
        time.sleep(0.05)
    assert not base.commands[-1].is_stop
    stall.set()
    assert stalled.wait(1.0)
    slot.put(_result(time.monotonic() + 0.3))  # fresh when the stalled read returns
    loop.stop()
    time.sleep(0.7)  # the stalled tick finishes
    assert not loop._thread.is_alive() and base.commands[-1].is_stop


def test_stop_returns_when_the_base_send_hangs(monkeypatch):
    """A third-party base whose send never returns holds the command lock: stop() gives
    up on the last zero after its wait, keeps a TimeoutError in `error`, and returns,
    so that shutdown goes on (the base's own failsafe must then stop it)."""
    monkeypatch.setattr(pipeline, "STOP_JOIN_TIMEOUT_S", 0.2)
    hang, hanging, release = threading.Event(), threading.Event(), threading.Event()

    class HangingBase(NullBase):
        def send(self, cmd):
            if hang.is_set():
                hanging.set()
                release.wait()  # for ever, as far as stop() knows
            return super().send(cmd)

    slot = LatestSlot()
    loop = ControlLoop(FollowingController(ControlConfig()), HangingBase(), slot,
                       rate_hz=20.0, perception_timeout_s=0.5).start()  # fmt: skip
    try:
        slot.put(_result(time.monotonic()))
        loop.notify()
        hang.set()
        assert hanging.wait(1.0)
        stopper = threading.Thread(target=loop.stop, daemon=True)
        started = time.monotonic()
        stopper.start()
        stopper.join(timeout=5.0)
        assert not stopper.is_alive(), "stop() waited on the hanging send"
        assert time.monotonic() - started >= 0.4  # it waited for the tick, then the lock
        assert isinstance(loop.error, TimeoutError)
    finally:
        release.set()


def _result_at(stamp_s: float, position_m: tuple[float, float]) -> FrameResult:
    track = TrackState(7, np.array([*position_m, 0.0, 0.0, 1.5]), np.eye(5) * 0.01, True,
                       stamp_s, observation=SEEN)  # fmt: skip
    return FrameResult(0, stamp_s, Odometry.origin(stamp_s), [], [track],
                       TargetEstimate(TargetStatus.TRACKING, 7, {7: 0.9}, stamp_s))  # fmt: skip


def test_after_a_watchdog_stop_the_controller_speeds_up_from_the_zero_sent():
    """While perception stalls the controller, searching, turns on toward the target's
    last side, but the base is sent zero; when frames come back with the target on the
    other side, the first command turns toward it from rest, not on from the search turn
    the base never got."""
    now = [100.0]
    slot = LatestSlot()
    config = ControlConfig(search_duration_s=5.0)
    loop = ControlLoop(FollowingController(config), NullBase(clock=lambda: now[0]), slot,
                       rate_hz=15.0, perception_timeout_s=0.5, clock=lambda: now[0])  # fmt: skip
    slot.put(_result_at(now[0], (3.0, 2.0)))  # to the left: turning left
    for _ in range(8):
        assert loop.tick().yaw_rate_radps > 0
        now[0] += 1 / 15
    for _ in range(15):  # a second with no frame: the watchdog stops the base
        command = loop.tick()
        now[0] += 1 / 15
    assert command.is_stop and loop.watchdog_trips == 1
    slot.put(_result_at(now[0], (3.0, -2.0)))  # back, to the right
    first = loop.tick()
    assert first.yaw_rate_radps < 0  # toward the target, from rest
    assert abs(first.yaw_rate_radps) <= config.max_yaw_accel_radps2 / 15 + 1e-9


def test_after_an_operator_stop_the_base_speeds_up_from_rest():
    """While following is stopped the node's gate publishes zero in place of the
    controller's commands; when following resumes the first command moving the base is
    within one period's acceleration of rest, not the full speed the controller had
    slewed up to meanwhile."""
    now = [100.0]
    published: list = []
    gate = CmdVelGate(published.append, lambda: now[0], max_odometry_age_s=0.5)
    config = ControlConfig()
    loop = ControlLoop(FollowingController(config), gate, LatestSlot(), rate_hz=15.0,
                       perception_timeout_s=0.5, clock=lambda: now[0])  # fmt: skip
    gate.following = False
    for _ in range(45):  # three seconds stopped, the target 5 m ahead in every frame
        gate.update_odometry(Odometry.origin(now[0]))
        loop.results.put(_result_at(now[0], (5.0, 0.0)))
        loop.tick()
        now[0] += 1 / 15
    assert all(command.is_stop for command in published) and gate.blocked > 0
    gate.following = True
    gate.update_odometry(Odometry.origin(now[0]))
    loop.results.put(_result_at(now[0], (5.0, 0.0)))
    first = loop.tick()
    assert 0 < first.forward_mps <= config.max_forward_accel_mps2 / 15 + 1e-9


@pytest.mark.parametrize("failure", ["nan", "raise"])
def test_the_last_zero_goes_out_when_the_loop_clock_is_what_failed(failure):
    """A clock that raises or gives NaN ends the loop; the stop meant for that failure
    was stamped with the same clock, failed too, and the base kept the moving command."""
    now = [100.0]
    broken = [False]

    def clock():
        if broken[0]:
            if failure == "raise":
                raise RuntimeError("the ROS context is shut down")
            return float("nan")
        return now[0]

    base = NullBase(clock=lambda: now[0])
    slot = LatestSlot()
    loop = ControlLoop(FollowingController(ControlConfig()), base, slot, rate_hz=15.0,
                       perception_timeout_s=0.5, clock=clock)  # fmt: skip
    for _ in range(10):
        now[0] += 1 / 15
        slot.put(_result(now[0]))
        loop.tick()
    assert base.last_command.forward_mps > 0.0
    broken[0] = True
    loop.start()
    loop._thread.join(timeout=5.0)
    assert loop.error is not None and base.last_command.is_stop
    loop.stop()
    assert base.last_command.is_stop
