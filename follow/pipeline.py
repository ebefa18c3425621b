"""The per-frame loop that ties the stages together, and its threads.

    capture thread   -> newest frame only (a slow detector never builds a backlog)
    perception       -> pose -> observations -> tracker -> identification -> FrameResult
    control thread   -> at a fixed rate: newest target -> controller -> base, with a
                        watchdog that stops the base when perception stalls

Without threads (`run_offline`), every frame of a file is processed in order and the
controller is stepped once per frame at the frame's time: reproducible, for evaluation
and replay (never driving a base). `follow run` (the command) lives in `follow/run.py`.

Every runner reads the robot's pose through one `OdometryPolicy`: odometry is sampled
with each frame when it is captured, and no fresh odometry means no target motion and a
zero command.
"""

from __future__ import annotations

import dataclasses
import logging
import threading
import time
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field

from follow.capture import LatestSlot
from follow.config import ControlConfig
from follow.control.odometry import OdometryPolicy
from follow.control.target import TargetMotion, ViewCone
from follow.frames import odom_to_base, vector_odom_to_base
from follow.types import (
    Frame,
    Observation,
    Odometry,
    Skeleton,
    TargetEstimate,
    TargetStatus,
    TrackState,
    VelocityCommand,
)

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class FrameResult:
    """Everything perception concluded about one frame."""

    frame_index: int
    stamp_s: float
    robot: Odometry
    skeletons: list[Skeleton]
    tracks: list[TrackState]
    target: TargetEstimate
    timing_ms: dict[str, float] = field(default_factory=dict)

    @property
    def target_track(self) -> TrackState | None:
        return next((t for t in self.tracks if t.track_id == self.target.target_id), None)


class Perception:
    """pose -> observations -> tracker -> identification, for one frame at a time.

    `detect` maps a frame to skeletons (the pose network, or the simulation's synthetic
    detector); `to_observations` turns skeletons into tracker observations.
    """

    def __init__(
        self,
        detect: Callable[[Frame], list[Skeleton]],
        to_observations: Callable[[list[Skeleton]], list[Observation]],
        tracker,
        identifier,
    ):
        self.detect = detect
        self.to_observations = to_observations
        self.tracker = tracker
        self.identifier = identifier

    def process(self, frame: Frame, robot: Odometry, frame_index: int) -> FrameResult:
        t0 = time.perf_counter()
        skeletons = self.detect(frame)
        t1 = time.perf_counter()
        observations = self.to_observations(skeletons)
        tracks = self.tracker.update(observations, frame.stamp_s, robot)
        t2 = time.perf_counter()
        target = self.identifier.update(frame.image, tracks, frame.stamp_s, robot)
        t3 = time.perf_counter()
        timing = {"pose": 1e3 * (t1 - t0), "tracker": 1e3 * (t2 - t1), "identify": 1e3 * (t3 - t2)}
        return FrameResult(frame_index, frame.stamp_s, robot, skeletons, tracks, target, timing)


def target_motion(result: FrameResult | None, robot_now: Odometry) -> TargetMotion | None:
    """The target's position and velocity in the robot frame as the robot stands now,
    stamped with the time of its track's last observation (a coasting track ages).

    The track lives in `odom`, so the newest odometry (not the pose at the frame's time)
    is used: the robot may have turned since the frame was taken.
    """
    if result is None or result.target.status != TargetStatus.TRACKING:
        return None
    track = result.target_track
    if track is None or track.observation is None and not track.confirmed:
        return None
    return TargetMotion(
        odom_to_base(track.position_m, robot_now),
        vector_odom_to_base(track.velocity_mps, robot_now),
        min(track.last_seen_s, result.stamp_s),
        observed=track.observation is not None,
    )


class ControlLoop:
    """Runs the controller at a fixed rate in its own thread.

    Each tick takes the newest FrameResult; if perception has produced nothing for
    `perception_timeout_s` (the watchdog), or the base has no fresh odometry, the command
    is zero until both are back. On stop, and on any exception inside the loop, the base
    gets a zero command.
    """

    def __init__(
        self,
        controller,
        base,
        results: LatestSlot,
        rate_hz: float,
        perception_timeout_s: float,
        clock: Callable[[], float] = time.monotonic,
        on_command: Callable[[VelocityCommand], None] | None = None,
        odometry: OdometryPolicy | None = None,
    ):
        self.controller = controller
        self.base = base
        self.odometry = odometry if odometry is not None else OdometryPolicy(base)
        self.results = results
        self.period_s = 1.0 / rate_hz
        self.perception_timeout_s = perception_timeout_s
        self.clock = clock
        self.on_command = on_command
        self.last_command: VelocityCommand | None = None
        self.watchdog_trips = 0
        self.error: BaseException | None = None
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="control", daemon=True)

    def start(self) -> ControlLoop:
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(timeout=5.0)
        self._send(VelocityCommand.stop(self.clock()))

    def tick(self) -> VelocityCommand:
        """One control step (public so tests and the offline runner can drive it)."""
        now = self.clock()
        robot = self.odometry.sample()
        if robot is None:  # the robot's pose is unknown: no target motion, stop
            self.controller.update(None, now)
            command = VelocityCommand.stop(now)
            self._send(command)
            return command
        result: FrameResult | None = self.results.peek()
        stalled = result is None or now - result.stamp_s > self.perception_timeout_s
        if stalled and result is not None:
            if self.last_command is None or not self.last_command.is_stop:
                self.watchdog_trips += 1
                log.warning(
                    "perception stalled (%.2f s since the last frame): stopping the base",
                    now - result.stamp_s,
                )
        target = None if stalled else target_motion(result, robot)
        command = self.controller.update(target, now)
        if stalled:
            command = VelocityCommand.stop(now)
        self._send(command)
        return command

    def _send(self, command: VelocityCommand) -> None:
        self.last_command = command
        self.base.send(command)
        if self.on_command is not None:
            self.on_command(command)

    def _run(self) -> None:
        next_tick = self.clock()
        try:
            while not self._stop.is_set():
                self.tick()
                next_tick += self.period_s
                self._stop.wait(max(0.0, next_tick - self.clock()))
        except BaseException as exc:  # the base must stop whatever went wrong
            self.error = exc
            log.exception("control loop failed: stopping the base")
            self._send(VelocityCommand.stop(self.clock()))


def run_offline(
    perception: Perception,
    frames: Iterable[Frame],
    controller=None,
    odometry: OdometryPolicy | Callable[[float], Odometry | None] | None = None,
) -> Iterator[tuple[Frame, FrameResult | None, VelocityCommand | None]]:
    """Every frame in order; the controller (if any) is stepped once per frame at the
    frame's time. The robot pose comes from `odometry`: a base's policy, or a recorded
    pose at the frame's stamp (a bag); default still at the origin. A frame without
    fresh odometry is not processed (result None) and gets a stop."""
    for index, frame in enumerate(frames):
        if odometry is None:
            robot = Odometry.origin(frame.stamp_s)
        elif isinstance(odometry, OdometryPolicy):
            robot = odometry.sample()
        else:
            robot = odometry(frame.stamp_s)
        if robot is None:
            if controller is not None:
                controller.update(None, frame.stamp_s)
            yield frame, None, VelocityCommand.stop(frame.stamp_s)
            continue
        result = perception.process(frame, robot, index)
        command = None
        if controller is not None:
            command = controller.update(target_motion(result, robot), frame.stamp_s)
        yield frame, result, command


class ThreadedRunner:
    """Capture, perception and control in their own threads, on one clock.

    Frames are re-stamped with `clock()` as they are captured, and the robot's pose is
    sampled with them (so the tracker places each frame where the robot was when it was
    taken), so the control loop's staleness checks compare like with like. A frame
    captured without fresh odometry is not processed. `pace_hz` plays a file at its
    frame rate. An error in the capture thread (a bad frame) ends the run and is raised.
    """

    def __init__(
        self,
        perception: Perception,
        control: ControlLoop,
        base,
        clock: Callable[[], float] = time.monotonic,
    ):
        self.perception = perception
        self.control = control
        self.base = base
        self.clock = clock
        self.frames = LatestSlot()
        self.results = control.results
        self._stop = threading.Event()
        self.odometry = control.odometry
        self.captured = 0
        self.processed = 0
        self.skipped_without_odometry = 0
        self.capture_error: BaseException | None = None

    def _capture(self, source: Iterable[Frame], pace_hz: float | None) -> None:
        start = self.clock()
        try:
            for index, frame in enumerate(source):
                if self._stop.is_set():
                    break
                if pace_hz:
                    delay = start + index / pace_hz - self.clock()
                    if delay > 0:
                        time.sleep(delay)
                stamped = dataclasses.replace(frame, stamp_s=self.clock())
                self.frames.put((index, stamped, self.odometry.sample()))
                self.captured += 1
        except Exception as exc:  # raised again by run(), after the base has stopped
            self.capture_error = exc
        finally:
            self.frames.close()

    def run(
        self,
        source: Iterable[Frame],
        pace_hz: float | None = None,
        on_result: Callable[[Frame, FrameResult], None] | None = None,
        max_frames: int | None = None,
    ) -> None:
        capture = threading.Thread(
            target=self._capture, args=(source, pace_hz), name="capture", daemon=True
        )
        capture.start()
        self.control.start()
        try:
            while max_frames is None or self.processed < max_frames:
                item = self.frames.get(timeout_s=1.0)
                if item is None:
                    if self.frames.closed:
                        break
                    continue
                index, frame, robot = item
                if robot is None:  # pose unknown when taken: the control loop stops
                    self.skipped_without_odometry += 1
                    continue
                result = self.perception.process(frame, robot, index)
                self.results.put(result)
                self.processed += 1
                if on_result is not None:
                    on_result(frame, result)
                if self.control.error is not None:
                    raise RuntimeError("control loop failed") from self.control.error
        finally:
            self._stop.set()
            self.control.stop()
            capture.join(timeout=2.0)
        if self.capture_error is not None:
            raise self.capture_error

    @property
    def dropped_frames(self) -> int:
        return self.frames.dropped


def build_runner(
    perception: Perception,
    base,
    config: ControlConfig,
    view: ViewCone | None = None,
    clock: Callable[[], float] = time.monotonic,
    on_command: Callable[[VelocityCommand], None] | None = None,
) -> ThreadedRunner:
    """The runner that drives a base: `follow run`, the demo and the evaluations all
    build it here, so they test the code that drives the robot. `view` is the camera's
    field of view (`ViewCone.from_camera`); `clock` is injectable for tests."""
    from follow.control.controller import FollowingController

    control = ControlLoop(
        FollowingController(config, view=view), base, LatestSlot(), config.control_rate_hz,
        config.watchdog_timeout_s, clock=clock, on_command=on_command,
        odometry=OdometryPolicy(base),
    )  # fmt: skip
    return ThreadedRunner(perception, control, base, clock=clock)
