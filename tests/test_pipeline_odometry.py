"""One odometry policy for every runner: no fresh odometry from a connected base means
no target motion and a zero command (never the origin pose); odometry is sampled with
each frame when it is captured."""

import dataclasses
import logging
import threading
import time

import numpy as np
import pytest

from follow.capture import LatestSlot
from follow.config import ControlConfig
from follow.control.controller import FollowingController
from follow.control.odometry import OdometryPolicy
from follow.frames import base_to_odom
from follow.pipeline import ControlLoop, Detections, FrameResult, ThreadedRunner, run_offline
from follow.types import Frame, Observation, Odometry, TargetEstimate, TargetStatus, TrackState

# The target was seen in the frame (the controller drives blind only briefly).
SEEN = Observation(np.array([320.0, 200.0]), np.array([320.0, 400.0]))


class _Base:
    """A connected base whose odometry can stop and whose pose can be set."""

    def __init__(self):
        self.commands = []
        self.x_m = 0.0
        self.fresh = True

    def send(self, cmd):
        self.commands.append(cmd)

    def odometry(self):
        return Odometry(self.x_m, 0.0, 0.0, time.monotonic()) if self.fresh else None

    def close(self):
        pass


def _tracking(stamp_s: float, robot: Odometry | None = None) -> FrameResult:
    """A frame tracking a target 4 m ahead of the robot's pose at capture, `robot` (the
    origin by default): a real frame carries the odometry of its capture, and one whose
    pose lies far from the robot's now reads as an odometry jump and drives nothing."""
    robot = Odometry.origin(stamp_s) if robot is None else robot
    ahead = base_to_odom(np.array([4.0, 0.0]), robot)
    track = TrackState(1, np.array([*ahead, 0.0, 0.0, 1.45]), np.eye(5) * 0.01, True, stamp_s,
                       observation=SEEN)  # fmt: skip
    return FrameResult(0, stamp_s, robot, [], [track],
                       TargetEstimate(TargetStatus.TRACKING, 1, {1: 0.9}, stamp_s))  # fmt: skip


def _following(base, now: list[float], frame_at=_tracking):
    """A control loop on `base` (clock `now[0]`) after ten 15 Hz frames that see the
    target ahead (`frame_at(stamp)`): (loop, its slot, the last command)."""
    slot = LatestSlot()
    loop = ControlLoop(FollowingController(ControlConfig()), base, slot, rate_hz=15.0,
                       perception_timeout_s=0.5, clock=lambda: now[0])  # fmt: skip
    for _ in range(10):
        now[0] += 1 / 15
        slot.put(frame_at(now[0]))
        moving = loop.tick()
    return loop, slot, moving


def test_no_fresh_odometry_stops_logs_once_and_resumes(caplog):
    now = [0.0]
    base = _Base()
    loop, slot, moving = _following(base, now)
    assert moving.forward_mps > 0.5
    base.fresh = False
    with caplog.at_level(logging.WARNING, logger="follow.control.odometry"):
        for _ in range(10):
            now[0] += 1 / 15
            slot.put(_tracking(now[0]))  # perception still sees the target
            assert loop.tick().is_stop
        base.fresh = True
        for _ in range(5):
            now[0] += 1 / 15
            slot.put(_tracking(now[0]))
            resumed = loop.tick()
    messages = [r.getMessage() for r in caplog.records]
    assert sum("no fresh odometry" in m for m in messages) == 1
    assert sum("back" in m for m in messages) == 1
    assert resumed.forward_mps > 0
    assert loop.odometry.losses == 1


class _SlowPerception:
    def __init__(self):
        self.seen = []

    def detect_people(self, frame):
        time.sleep(0.03)  # the source moves on (and the robot with it) meanwhile
        return Detections([], 0.0)

    def conclude(self, frame, robot, frame_index, detections):
        self.seen.append((frame_index, robot.x_m))
        return _tracking(frame.stamp_s)

    def process(self, frame, robot, frame_index):
        return self.conclude(frame, robot, frame_index, self.detect_people(frame))


def test_threaded_runner_uses_the_odometry_sampled_when_the_frame_was_captured():
    base = _Base()

    def source():
        for index in range(40):
            base.x_m = float(index)  # the robot moves one metre per frame
            base.fresh = index % 10 != 5  # and odometry drops out now and then
            yield Frame(np.zeros((16, 16, 3), np.uint8), 0.0)

    perception = _SlowPerception()
    control = ControlLoop(FollowingController(ControlConfig()), base, LatestSlot(),
                          rate_hz=30.0, perception_timeout_s=0.5)  # fmt: skip
    runner = ThreadedRunner(perception, control, base)
    runner.run(source(), pace_hz=100.0)
    assert len(perception.seen) >= 10
    assert all(x == float(index) for index, x in perception.seen)
    assert all(index % 10 != 5 for index, _ in perception.seen)  # no pose: not processed
    assert base.commands[-1].is_stop


def test_offline_runner_stops_on_frames_without_odometry():
    base = _Base()
    policy = OdometryPolicy(base)

    class _Perception:
        def process(self, frame, robot, index):
            return _tracking(frame.stamp_s)

    def frames():
        for index in range(20):
            base.fresh = index < 10
            yield Frame(np.zeros((16, 16, 3), np.uint8), index / 15)

    out = list(run_offline(_Perception(), frames(), FollowingController(), policy))
    assert all(result is not None for _, result, _ in out[:10])
    assert out[9][2].forward_mps > 0
    assert all(result is None and command.is_stop for _, result, command in out[10:])


def test_a_capture_error_ends_the_run_and_is_raised():
    base = _Base()

    def source():
        yield Frame(np.zeros((16, 16, 3), np.uint8), 0.0)
        raise ValueError("frame 1 is 8x8")

    control = ControlLoop(FollowingController(), base, LatestSlot(), rate_hz=30.0,
                          perception_timeout_s=0.5)  # fmt: skip
    runner = ThreadedRunner(_SlowPerception(), control, base)
    done = threading.Event()
    try:
        runner.run(source())
    except ValueError as exc:
        done.set()
        assert "8x8" in str(exc)
    assert done.is_set() and base.commands[-1].is_stop


def test_the_watchdog_has_its_own_timeout():
    from follow.pipeline import build_runner

    now = [0.0]
    base = _Base()
    config = ControlConfig(watchdog_timeout_s=0.3, target_timeout_s=1.0)
    runner = build_runner(None, base, config, clock=lambda: now[0])
    loop = runner.control
    assert loop.perception_timeout_s == 0.3 and runner.odometry is loop.odometry
    loop.results.put(_tracking(0.0))
    now[0] = 0.2
    assert loop.tick().forward_mps > 0  # 0.2 s old: fresh for both timeouts
    now[0] = 0.4
    assert loop.tick().is_stop and loop.watchdog_trips == 1  # past the watchdog only


def test_a_frozen_frame_is_driven_on_never_faster_until_the_watchdog():
    """Perception stops on a frame that saw the target (a frozen camera or driver): each
    tick took that frame as a fresh sighting and sped up toward it (0.3 -> 1.0 m/s) until
    the watchdog. Past a frame in flight (MAX_CARRY_FORWARD_S) it is driven on at most at
    the speed of that moment; a new frame may speed up again."""
    from follow.pipeline import MAX_CARRY_FORWARD_S

    now = [0.0]

    class StampedBase(_Base):
        def odometry(self):
            return Odometry(0.0, 0.0, 0.0, now[0])

    slot = LatestSlot()
    loop = ControlLoop(FollowingController(ControlConfig()), StampedBase(), slot,
                       rate_hz=15.0, perception_timeout_s=0.5, clock=lambda: now[0])  # fmt: skip
    for _ in range(3):  # speeding up from rest toward the target 4 m ahead
        now[0] += 1 / 15
        slot.put(_tracking(now[0]))
        loop.tick()
    frozen_s = now[0]
    in_flight, late = [], []
    while now[0] + 1 / 15 < frozen_s + 0.5:  # up to the watchdog
        now[0] += 1 / 15
        age_s = now[0] - frozen_s
        (in_flight if age_s <= MAX_CARRY_FORWARD_S else late).append(loop.tick().forward_mps)
    assert late and max(late) <= in_flight[-1] + 1e-9
    now[0] += 1 / 15
    slot.put(_tracking(now[0]))  # perception is back: speeding up again
    assert loop.tick().forward_mps > in_flight[-1]


@pytest.mark.parametrize("age_s", [1 / 30, 0.15, 0.3])
def test_a_reset_hidden_by_a_frames_age_still_drives_nothing(age_s):
    """Over a frame's age a base may turn as far as an estimator's reset moves the pose
    (4 rad/s x 0.15 s), so comparing the frame's pose with the newest one misses a 0.6
    rad reset; consecutive samples of the control loop show it. Until the next frame:
    zero, not a turn and a speed-up after a phantom 34 degrees off."""
    now = [0.0]
    pose = [Odometry.origin()]

    class StampedBase(_Base):
        def odometry(self):
            return dataclasses.replace(pose[0], stamp_s=now[0])

    def tracking(stamp_s: float) -> FrameResult:
        return _tracking(stamp_s, dataclasses.replace(pose[0], stamp_s=stamp_s))

    loop, slot, moving = _following(StampedBase(), now, tracking)
    assert moving.forward_mps > 0.5 and moving.yaw_rate_radps == 0.0
    now[0] += 1 / 15
    slot.put(tracking(now[0]))
    frame_s = now[0]
    while now[0] + 1 / 15 < frame_s + age_s:  # the loop's own ticks, 15 a second
        now[0] += 1 / 15
        loop.tick()
    now[0] = frame_s + age_s
    pose[0] = Odometry(0.0, 0.0, 0.6, 0.0)  # the heading "changed" by 0.6 rad at once
    for _ in range(3):
        assert loop.tick().is_stop
        now[0] += 1 / 30
    slot.put(tracking(now[0]))  # the next frame, its tracks in the new odom frame
    assert loop.tick().forward_mps > 0


def test_odometry_that_jumped_since_the_frame_drives_nothing():
    """An estimator's yaw reset between a frame and the tick: the frame's tracks are in
    the odom frame from before it, so the target cannot be placed (the tracker moves
    them only with the next frame). Until then: zero, not a turn after a phantom."""
    now = [0.0]
    pose = [Odometry.origin()]

    class StampedBase(_Base):
        def odometry(self):
            return dataclasses.replace(pose[0], stamp_s=now[0])

    def tracking(stamp_s: float) -> FrameResult:  # captured at the robot's pose then
        return _tracking(stamp_s, dataclasses.replace(pose[0], stamp_s=stamp_s))

    loop, slot, moving = _following(StampedBase(), now, tracking)
    assert moving.forward_mps > 0.5 and moving.yaw_rate_radps == 0.0
    pose[0] = Odometry(0.0, 0.0, 1.5, 0.0)  # the heading "changed" by 86 degrees at once
    for _ in range(3):
        now[0] += 1 / 30
        assert loop.tick().is_stop
    now[0] += 1 / 30
    slot.put(tracking(now[0]))  # the next frame, its tracks in the new odom frame
    assert loop.tick().forward_mps > 0


class _ScriptedBase(_Base):
    """A base whose odometry samples are given in turn."""

    def __init__(self, samples):
        super().__init__()
        self.samples = list(samples)

    def odometry(self):
        return self.samples.pop(0)


def test_a_reset_stamped_with_the_last_samples_time_is_still_a_jump():
    """A base may stamp a new pose with the last one's time (MAVLink: the older of the
    position and attitude messages, so an attitude arriving first changes the pose, not
    the stamp). The reset is logged all the same, and the moved pose comes stamped after
    the last, so that a frame taken before it can be told from one taken after."""
    before = Odometry(0.0, 0.0, 0.0, 10.0)
    reset = Odometry(0.0, 0.0, 0.6, 10.0)  # a 0.6 rad yaw reset, the same stamp
    older = Odometry(0.5, 0.0, 0.6, 9.9)  # sampled by another thread, handed in late
    policy = OdometryPolicy(_ScriptedBase([before, reset, reset, older]))
    assert policy.sample() is before
    moved = policy.sample()
    assert (moved.yaw_rad, policy.last_jump_s) == (0.6, moved.stamp_s)
    assert moved.stamp_s > before.stamp_s
    assert policy.sample() is moved  # the same pose again: the same sample
    assert policy.sample() is older  # an older sample is handed back as it came


def test_a_reset_at_the_last_samples_stamp_drives_nothing():
    """The control loop's view of the same: a frame taken before such a reset is not
    driven toward (it drove on at 1.45 m/s, turning toward a phantom 0.6 rad off)."""
    now = [0.0]
    pose = [Odometry.origin()]
    tie = []  # the stamp the next sample repeats, once

    class TiedStampBase(_Base):
        def odometry(self):
            return dataclasses.replace(pose[0], stamp_s=tie.pop() if tie else now[0])

    def tracking(stamp_s: float) -> FrameResult:
        return _tracking(stamp_s, dataclasses.replace(pose[0], stamp_s=stamp_s))

    base = TiedStampBase()
    loop, slot, moving = _following(base, now, tracking)
    assert moving.forward_mps > 0.5
    now[0] += 1 / 15
    slot.put(tracking(now[0]))
    loop.tick()
    for _ in range(2):  # 0.2 s: a frame's age, over which a base may turn 0.6 rad
        now[0] += 0.1
        loop.tick()
    tie.append(loop.odometry.sample().stamp_s)
    pose[0] = Odometry(0.0, 0.0, 0.6, 0.0)  # the reset, in the sample with the same stamp
    for _ in range(3):
        assert loop.tick().is_stop
        now[0] += 1 / 30
