import threading
import time

import numpy as np
import pytest

from follow.capture import LatestSlot
from follow.config import ControlConfig
from follow.control.base import NullBase
from follow.control.controller import FollowingController
from follow.pipeline import (
    MAX_CARRY_FORWARD_S,
    ControlLoop,
    Detections,
    FrameResult,
    Perception,
    ThreadedRunner,
    target_motion,
)
from follow.types import Frame, Observation, Odometry, TargetEstimate, TargetStatus, TrackState

# The target was seen in the frame (the controller drives blind only briefly).
SEEN = Observation(np.array([320.0, 200.0]), np.array([320.0, 400.0]))


def _result(stamp_s: float, target_xy=(5.0, 0.0), status=TargetStatus.TRACKING) -> FrameResult:
    track = TrackState(
        7, np.array([*target_xy, 0.0, 0.0, 1.5]), np.eye(5) * 0.01, True, stamp_s, observation=SEEN
    )
    return FrameResult(0, stamp_s, Odometry.origin(stamp_s), [], [track],
                       TargetEstimate(status, 7, {7: 0.9}, stamp_s))  # fmt: skip


def test_target_motion_uses_the_robot_pose_now():
    result = _result(1.0, target_xy=(0.0, 3.0))
    turned = Odometry(0.0, 0.0, np.pi / 2, 1.5)  # robot now faces +y of odom (0.5 s later)
    motion = target_motion(result, turned)
    np.testing.assert_allclose(motion.position_m, [3.0, 0.0], atol=1e-9)
    assert motion.stamp_s == 1.0
    assert target_motion(_result(1.0, status=TargetStatus.REIDENTIFICATION), turned) is None
    assert target_motion(None, turned) is None


def test_target_motion_carries_the_target_forward_over_the_latency():
    # Seen at 3 m walking away at 1 m/s; the command is computed 0.2 s after the frame.
    walking = TrackState(7, np.array([3.0, 0.0, 1.0, 0.0, 1.5]), np.eye(5) * 0.01, True, 1.0,
                         observation=SEEN)  # fmt: skip
    result = FrameResult(0, 1.0, Odometry.origin(1.0), [], [walking],
                         TargetEstimate(TargetStatus.TRACKING, 7, {7: 0.9}, 1.0))  # fmt: skip
    robot = Odometry(0.5, 0.0, 0.0, 1.2)  # the robot drove 0.5 m meanwhile
    later = target_motion(result, robot, now_s=1.2)
    np.testing.assert_allclose(later.position_m, [2.7, 0.0], atol=1e-9)
    np.testing.assert_allclose(later.velocity_mps, [1.0, 0.0], atol=1e-9)
    assert later.stamp_s == 1.0  # still aged from the observation: staleness unchanged
    np.testing.assert_allclose(target_motion(result, robot).position_m, [2.5, 0.0], atol=1e-9)
    earlier = target_motion(result, robot, now_s=0.9)  # a clock behind the frame: no rewind
    np.testing.assert_allclose(earlier.position_m, [2.5, 0.0], atol=1e-9)
    # A result older than MAX_CARRY_FORWARD_S is stalled perception, not latency: not
    # carried at all (a target must not seem to walk on while nothing new is seen).
    stalled = target_motion(result, robot, now_s=1.0 + MAX_CARRY_FORWARD_S + 0.01)
    np.testing.assert_allclose(stalled.position_m, [2.5, 0.0], atol=1e-9)


def test_watchdog_stops_the_base_when_perception_stalls():
    now = [10.0]
    slot = LatestSlot()
    base = NullBase()
    loop = ControlLoop(FollowingController(ControlConfig()), base, slot, rate_hz=15.0,
                       perception_timeout_s=0.5, clock=lambda: now[0])  # fmt: skip
    assert loop.tick().is_stop  # nothing perceived yet
    slot.put(_result(10.0))
    moving = None
    for _ in range(5):
        now[0] += 1 / 15
        moving = loop.tick()
    assert moving.forward_mps > 0  # target 5 m ahead: drive towards it
    now[0] += 1.0  # perception froze: newest result is over 0.5 s old
    assert loop.tick().is_stop
    assert loop.watchdog_trips == 1
    slot.put(_result(now[0]))
    now[0] += 1 / 15
    assert loop.tick().forward_mps > 0  # fresh data again: it drives again


class _HeldController:
    """A controller whose updates, once `hold` is set, wait for `release` (a tick taken
    between its reading the newest result and its sending the command)."""

    def __init__(self, controller):
        self.controller, self.hold = controller, False
        self.computing, self.release = threading.Event(), threading.Event()

    def update(self, target, stamp_s):
        command = self.controller.update(target, stamp_s)
        if self.hold:
            self.computing.set()
            assert self.release.wait(5.0)
        return command

    def stopped_elsewhere(self, stamp_s):
        self.controller.stopped_elsewhere(stamp_s)


def test_a_command_computed_from_a_cleared_result_is_zero():
    """`clear_result` (the target changed elsewhere) while a tick computes its command
    from the result it drops: that command drives toward the target no longer followed,
    so zero goes to the base instead."""
    now = [10.0]
    slot, base = LatestSlot(), NullBase(clock=lambda: now[0])
    held = _HeldController(FollowingController(ControlConfig()))
    loop = ControlLoop(held, base, slot, rate_hz=15.0, perception_timeout_s=0.5,
                       clock=lambda: now[0])  # fmt: skip
    slot.put(_result(10.0))
    for _ in range(5):
        now[0] += 1 / 15
        loop.tick()
    assert base.commands[-1].forward_mps > 0
    held.hold = True
    now[0] += 1 / 15
    ticking = threading.Thread(target=loop.tick, daemon=True)
    ticking.start()
    assert held.computing.wait(5.0)
    loop.clear_result()
    held.release.set()
    ticking.join(5.0)
    assert not ticking.is_alive()
    assert base.commands[-1].is_stop and loop.last_command.is_stop
    held.hold = False
    now[0] += 1 / 15
    assert loop.tick().is_stop  # nothing concluded for the new target yet
    slot.put(_result(now[0]))
    now[0] += 1 / 15
    assert loop.tick().forward_mps > 0 and base.commands[-1].forward_mps > 0


class _FrozenPerception(Perception):
    """Detects in two frames, then hangs as a stuck detector would."""

    def __init__(self, release: threading.Event):
        self.release, self.calls = release, 0

    def detect_people(self, frame):
        self.calls += 1
        if self.calls > 2:
            self.release.wait(5.0)
        return Detections([], 0.0)

    def conclude(self, frame, robot, frame_index, detections):
        return _result(frame.stamp_s)


def test_threaded_runner_stops_the_base_while_perception_is_frozen():
    release = threading.Event()
    base = NullBase()
    slot = LatestSlot()
    control = ControlLoop(FollowingController(ControlConfig()), base, slot, rate_hz=20.0,
                          perception_timeout_s=0.3)  # fmt: skip
    runner = ThreadedRunner(_FrozenPerception(release), control, base)
    frames = (Frame(np.zeros((16, 16, 3), np.uint8), 0.0) for _ in range(50))
    worker = threading.Thread(target=runner.run, args=(frames,), kwargs={"pace_hz": 20.0})
    worker.start()
    time.sleep(1.2)  # perception has been frozen for about a second
    recent = [c for c in base.commands if c.stamp_s > time.monotonic() - 0.5]
    release.set()
    worker.join(5.0)
    assert any(not c.is_stop for c in base.commands)  # it did move while perceiving
    assert recent and all(c.is_stop for c in recent)
    assert control.watchdog_trips >= 1
    assert base.commands[-1].is_stop  # and it ends stopped


def test_control_loop_failure_stops_the_base():
    class Broken:
        def update(self, target, stamp_s):
            raise ZeroDivisionError("boom")

    base = NullBase()
    loop = ControlLoop(Broken(), base, LatestSlot(), rate_hz=50.0, perception_timeout_s=0.3)
    loop.start()
    time.sleep(0.2)
    assert isinstance(loop.error, ZeroDivisionError)
    assert base.commands and base.commands[-1].is_stop
    loop.stop()
    assert base.commands[-1].is_stop


def test_the_command_logged_for_a_frame_is_the_one_sent_about_it():
    """`command_from` gives the first command sent after a frame's result was taken, not
    whatever the loop sent last; a frame the loop never took (a newer result replaced
    it) gets the command then in force, and one not yet taken waits for it."""
    import dataclasses

    now = [10.0]
    slot = LatestSlot()
    loop = ControlLoop(FollowingController(ControlConfig()), NullBase(), slot, rate_hz=15.0,
                       perception_timeout_s=0.5, clock=lambda: now[0])  # fmt: skip
    near, skipped, far, later = (dataclasses.replace(_result(10.0, (x, 0.0)), frame_index=i)
                                 for i, x in enumerate((1.0, 3.0, 8.0, 8.0)))  # fmt: skip
    slot.put(near)
    from_near = loop.tick()
    assert from_near.is_stop  # 1 m away: nearer than the following distance
    slot.put(skipped)
    slot.put(far)  # before a tick: `skipped` is never taken
    for _ in range(4):
        now[0] += 1 / 15
        last = loop.tick()
    assert last.forward_mps > 0
    assert loop.command_from(near, 0.0) is from_near  # not the loop's last command
    assert loop.command_from(skipped, 0.0) is from_near
    from_far = loop.command_from(far, 0.0)
    assert from_far is not last and abs(from_far.stamp_s - (10.0 + 1 / 15)) < 1e-9
    got = []
    waiter = threading.Thread(target=lambda: got.append(loop.command_from(later, 5.0)))
    waiter.start()
    time.sleep(0.05)
    assert not got  # waits for the loop to take `later`
    slot.put(later)
    now[0] += 1 / 15
    from_later = loop.tick()
    waiter.join(timeout=5.0)
    assert got == [from_later]


def test_a_frame_taken_without_odometry_has_its_stop_logged_at_once():
    """Without fresh odometry the loop sends zero and looks at no target, but the frame
    it took still has its command: the log's thread must not wait out its time-out on
    every frame (it would hold up perception behind it)."""
    import dataclasses

    from follow.control.odometry import OdometryPolicy

    class NoOdometry(NullBase):
        def odometry(self):
            return None

    base = NoOdometry()
    slot = LatestSlot()
    loop = ControlLoop(FollowingController(ControlConfig()), base, slot, rate_hz=15.0,
                       perception_timeout_s=0.5, clock=lambda: 10.0,
                       odometry=OdometryPolicy(base))  # fmt: skip
    result = dataclasses.replace(_result(10.0), frame_index=3)
    slot.put(result)
    sent = loop.tick()
    assert sent.is_stop
    started = time.monotonic()
    assert loop.command_from(result, 5.0) is loop.last_command
    assert time.monotonic() - started < 1.0


class _HangsOnceTold(NullBase):
    """A base whose `send` stops returning once `hang` is set (a link that no longer
    drains), until `release` is."""

    def __init__(self):
        super().__init__()
        self.hang, self.release = threading.Event(), threading.Event()

    def send(self, cmd):
        if self.hang.is_set():
            self.release.wait(10.0)
        return super().send(cmd)


def _idle_loop_on_hanging_base() -> tuple[_HangsOnceTold, ControlLoop]:
    """A loop between two ticks (1 s apart): `stop` finds it idle, not busy."""
    base = _HangsOnceTold()
    loop = ControlLoop(FollowingController(ControlConfig()), base, LatestSlot(), rate_hz=1.0,
                       perception_timeout_s=0.5).start()  # fmt: skip
    deadline = time.monotonic() + 2.0
    while not base.commands and time.monotonic() < deadline:
        time.sleep(0.005)
    base.hang.set()
    return base, loop


def _returns_within(call, timeout_s: float) -> bool:
    caller = threading.Thread(target=call, daemon=True)
    caller.start()
    caller.join(timeout_s)
    return not caller.is_alive()


def test_stop_gives_up_on_a_last_zero_whose_send_hangs(monkeypatch):
    """The loop was idle between ticks and the base's send hangs on the last zero: `stop`
    returns after its wait with a TimeoutError in `error`, and so does a second `stop`
    (the main thread's, after the signal watcher's hung in that send with the lock)."""
    from follow import pipeline

    monkeypatch.setattr(pipeline, "STOP_JOIN_TIMEOUT_S", 0.1)
    base, loop = _idle_loop_on_hanging_base()
    try:
        assert _returns_within(loop.stop, 1.0), "stop() hangs in the base's send"
        assert isinstance(loop.error, TimeoutError)
        assert _returns_within(loop.stop, 1.0), "a second stop() waits on the send lock"
    finally:
        base.release.set()


@pytest.mark.parametrize("timeout_s", [0.0, 1.5, float("nan")])
def test_a_control_loop_refuses_a_watchdog_longer_than_a_blind_drive(timeout_s):
    """A frozen frame that saw the target is driven on until the watchdog trips: the
    ROS node's `max_image_age_s` allowed 2 s of it, twice `follow run`'s bound."""
    with pytest.raises(ValueError, match="perception_timeout_s must be in"):
        ControlLoop(FollowingController(ControlConfig()), NullBase(), LatestSlot(),
                    rate_hz=15.0, perception_timeout_s=timeout_s)  # fmt: skip
