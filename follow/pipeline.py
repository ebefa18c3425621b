"""The per-frame loop that ties the stages together, and its threads.

    capture thread   -> newest frame only (a slow detector never builds a backlog)
    pose thread      -> pose network on the newest frame (`overlap_stages`: it infers
                        the next frame while the previous one is tracked; two frames in
                        flight at most)
    perception       -> observations -> tracker -> identification -> FrameResult
    output thread    -> drawing, video encoding and logging (`on_result`), in order
    control thread   -> on each new result and at a fixed rate between them: newest
                        target -> controller -> base, with a watchdog that stops the
                        base when perception stalls

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
import math
import sys
import threading
import time
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field

import numpy as np

from follow.capture import LatestSlot, SourceError
from follow.config import ControlConfig
from follow.control.controller import MAX_WATCHDOG_TIMEOUT_S
from follow.control.odometry import OdometryPolicy
from follow.control.target import TargetMotion, ViewCone
from follow.frames import odom_to_base, vector_odom_to_base
from follow.freshness import is_ahead, is_fresh
from follow.handoff import Handoff, OrderedWorker
from follow.latency import LatencyRecorder
from follow.odometry_buffer import OdometryJumps, pose_jumped
from follow.pose.runtime import backend_runs_on_gpu
from follow.shutdown import cleanup_begins, halt_on_signal, stop_within
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

STOP_JOIN_TIMEOUT_S = 5.0  # how long `ControlLoop.stop` waits for a tick, then the last zero
CAPTURE_JOIN_TIMEOUT_S = 2.0  # how long a run's end waits for a read under way


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


@dataclass(frozen=True)
class Detections:
    """The pose stage's output for one frame: what the later stages start from."""

    skeletons: list[Skeleton]
    pose_ms: float


class Perception:
    """pose -> observations -> tracker -> identification, for one frame at a time.

    `detect` maps a frame to skeletons (the pose network, or the simulation's synthetic
    detector); `to_observations` turns skeletons into tracker observations. The two
    halves (`detect_people`, `conclude`) are separate so that a runner can infer one
    frame's pose while the previous frame is tracked. `odometry_jumps` is set by the
    runner to the log of jumps between the odometry samples its poses come from
    (`OdometryJumps`): the tracker moves its tracks by exactly those.
    """

    def __init__(
        self,
        detect: Callable[[Frame], list[Skeleton]],
        to_observations: Callable[[list[Skeleton]], list[Observation]],
        tracker,
        identifier,
        pose_backend: str | None = None,
    ):
        self.detect = detect
        self.to_observations = to_observations
        self.tracker = tracker
        self.identifier = identifier
        self.pose_backend = pose_backend  # where the pose network runs; None: no network
        self.odometry_jumps: OdometryJumps | None = None  # None: the tracker's own test

    def detect_people(self, frame: Frame) -> Detections:
        """The pose stage alone (thread-safe with respect to `conclude`)."""
        t0 = time.perf_counter()
        skeletons = self.detect(frame)
        return Detections(skeletons, 1e3 * (time.perf_counter() - t0))

    def conclude(
        self, frame: Frame, robot: Odometry, frame_index: int, detections: Detections
    ) -> FrameResult:
        """Tracker and identification on one frame's detections (frames in order)."""
        t1 = time.perf_counter()
        observations = self.to_observations(detections.skeletons)
        jumps = {} if self.odometry_jumps is None else {"odometry_jumps": self.odometry_jumps}
        tracks = self.tracker.update(observations, frame.stamp_s, robot, **jumps)
        t2 = time.perf_counter()
        target = self.identifier.update(frame.image, tracks, frame.stamp_s, robot)
        t3 = time.perf_counter()
        timing = {"pose": detections.pose_ms, "tracker": 1e3 * (t2 - t1),
                  "identify": 1e3 * (t3 - t2)}  # fmt: skip
        return FrameResult(frame_index, frame.stamp_s, robot, detections.skeletons, tracks,
                           target, timing)  # fmt: skip

    def process(self, frame: Frame, robot: Odometry, frame_index: int) -> FrameResult:
        return self.conclude(frame, robot, frame_index, self.detect_people(frame))


# The longest capture-to-command latency carried forward: a frame on its way through
# perception (pose network, tracker, identifier) on a laptop CPU or an embedded GPU.
MAX_CARRY_FORWARD_S = 0.25


def target_motion(
    result: FrameResult | None,
    robot_now: Odometry,
    now_s: float | None = None,
    reused: bool = False,
    odometry_jump_s: float | None = None,
) -> TargetMotion | None:
    """The target's position and velocity in the robot frame as the robot stands now,
    stamped with the time of its track's last observation (a coasting track ages).

    The track lives in `odom`, so the newest odometry (not the pose at the frame's time)
    is used: the robot may have turned since the frame was taken. Given `now_s`, the
    position is also carried forward at the track's velocity from the frame's time to
    now: the person kept walking while perception worked on the frame, and a controller
    fed where they were lags them by that latency times their speed. Only within
    `MAX_CARRY_FORWARD_S`: an older result is late, not in flight, and stalled
    perception must not make a target seem to walk on ahead while the robot closes in
    (the watchdog stops the base at its own time-out); such a result that a control step
    already took (`reused`) is `late`: driven on, never faster. None when the odometry
    jumped since the frame's pose (a reset): its tracks are in an odom frame that no
    longer exists until the tracker moves them with the next frame. The jump is seen
    between the frame's pose and the newest, or (`odometry_jump_s`, the odometry stamp of
    the newest jump between two consecutive samples, `OdometryPolicy`) after the frame:
    over a frame's age a base may turn or drive far enough to hide a reset."""
    if result is None or result.target.status != TargetStatus.TRACKING:
        return None
    if odometry_jump_s is not None and result.robot.stamp_s < odometry_jump_s:
        return None
    if pose_jumped(result.robot, robot_now, abs(robot_now.stamp_s - result.robot.stamp_s)):
        return None
    track = result.target_track
    if track is None or track.observation is None and not track.confirmed:
        return None
    position_m = np.asarray(track.position_m, dtype=float)
    late = False
    if now_s is not None:
        ahead_s = max(0.0, now_s - result.stamp_s)
        if ahead_s <= MAX_CARRY_FORWARD_S:
            position_m = position_m + np.asarray(track.velocity_mps) * ahead_s
        late = reused and ahead_s > MAX_CARRY_FORWARD_S
    return TargetMotion(
        odom_to_base(position_m, robot_now),
        vector_odom_to_base(track.velocity_mps, robot_now),
        min(track.last_seen_s, result.stamp_s),
        observed=track.observation is not None,
        late=late,
    )


class ControlLoop:
    """Runs the controller in its own thread: at once when a new result arrives
    (`notify`), and at a fixed rate between results.

    Each tick takes the newest FrameResult; if perception has produced nothing for
    `perception_timeout_s` (the watchdog), or the base has no fresh odometry, the command
    is zero until both are back; a result stamped ahead of `clock` counts as stale too
    (`follow.freshness`). On stop, and on any exception inside the loop, the base gets a
    zero command, and from the moment `stop` is called nothing else leaves the loop;
    likewise, from the moment `clear_result` drops the newest result, no command computed
    from it leaves the loop.
    Ticks are timed on `time.monotonic`, whatever `clock` is, so a clock that steps back
    (a ROS clock after an NTP step) cannot put the loop to sleep on a moving command.
    `on_failure` is called from the loop's thread when it fails (the runner ends the run:
    without odometry no frame would get as far as looking at `error`).
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
        if not (0.0 < perception_timeout_s <= MAX_WATCHDOG_TIMEOUT_S):
            raise ValueError(
                f"control loop perception_timeout_s must be in (0, {MAX_WATCHDOG_TIMEOUT_S:g}] "
                f"s (a frozen frame is driven on until it trips), got {perception_timeout_s}"
            )
        self.controller = controller
        self.base = base
        self.odometry = odometry if odometry is not None else OdometryPolicy(base)
        self.results = results
        self.period_s = 1.0 / rate_hz
        self.perception_timeout_s = perception_timeout_s
        self.clock = clock
        self.on_command = on_command
        self.on_failure: Callable[[], None] | None = None
        self.last_command: VelocityCommand | None = None
        self.watchdog_trips = 0
        self.error: BaseException | None = None
        self.latency = LatencyRecorder()  # capture of a frame -> first command from it
        self._last_result: FrameResult | None = None
        # frame index -> the first command sent after its result was taken (the newest
        # COMMANDS_KEPT), for the log's record of what the base did about each frame
        self._commands_from: dict[int, VelocityCommand] = {}
        self._commanded_changed = threading.Condition()
        self._stop = threading.Event()
        self._wake = threading.Event()
        self._send_lock = threading.Lock()  # a command and the check before it, as one
        self._clears = 0  # results dropped by `clear_result` (changed under `_send_lock`)
        self._thread = threading.Thread(target=self._run, name="control", daemon=True)

    def start(self) -> ControlLoop:
        self._thread.start()
        return self

    def notify(self) -> None:
        """A new result is in: compute its command now rather than at the next tick."""
        self._wake.set()

    def clear_result(self) -> None:
        """Drop the newest result (the target it tracks is no longer the one to follow):
        zero until a new one is put, and a tick under way that took the dropped one sends
        zero rather than the command it computed from it."""
        with self._send_lock:
            self.results.put(None)
            self._clears += 1  # after the put: a tick that took the dropped one read less

    def stop(self) -> None:
        """Zero from now on: a tick still under way can only send zero after this. A
        base that fails to take the last zero, or whose `send` (the last zero's, or one
        still under way) has not returned `STOP_JOIN_TIMEOUT_S` after the tick's wait,
        is logged and kept in `error` (if nothing failed before), not raised and not
        waited on for ever: the caller's cleanup must go on. Safe from any thread, twice."""
        self._stop.set()
        self._wake.set()
        if self._thread.ident is not None:  # started (a signal may stop it before that)
            self._thread.join(timeout=STOP_JOIN_TIMEOUT_S)
        if self._thread.is_alive():
            log.error("control thread still busy %.0f s after stop: it can only send zero "
                      "commands from now on", STOP_JOIN_TIMEOUT_S)  # fmt: skip
        self._send_last_stop_within(STOP_JOIN_TIMEOUT_S)

    def _send_last_stop_within(self, wait_s: float) -> None:
        """The last zero, sent on a helper thread: a base's `send` that never returns
        (or another stop's, hanging with the lock) holds the caller `wait_s` at most."""

        def send() -> None:
            self._send_last_stop(lock_timeout_s=wait_s)

        if stop_within(send, wait_s, name="control-stop"):
            return
        log.error("the base's send has not returned for %g s: giving up on the last zero",
                  wait_s)  # fmt: skip
        if self.error is None:
            self.error = _send_hangs(wait_s)

    def _stop_stamp_s(self) -> float:
        """The last zero's stamp: the loop's clock, or, where that clock is what failed
        (it raised, or gave no finite time), the last command's stamp: a stop must go out
        whatever its time."""
        try:
            stamp_s = float(self.clock())
        except Exception:
            stamp_s = math.nan
        if math.isfinite(stamp_s):
            return stamp_s
        return self.last_command.stamp_s if self.last_command is not None else 0.0

    def _send_last_stop(self, lock_timeout_s: float = -1.0) -> None:
        try:
            self._send(VelocityCommand.stop(self._stop_stamp_s()), lock_timeout_s=lock_timeout_s)
        except Exception as exc:  # the link is gone: nothing more can be sent
            log.error("the base did not take the stop command: %s", exc)
            if self.error is None:
                self.error = exc

    def tick(self) -> VelocityCommand:
        """One control step (public so tests and the offline runner can drive it)."""
        robot = self.odometry.sample()
        now = self.clock()  # after the sample: a slow read does not age the result early
        if robot is None:  # the robot's pose is unknown: no target motion, stop
            self.controller.update(None, now)
            command = VelocityCommand.stop(now)
            self._send(command, overridden=True)
            self._remember_command(self.results.peek())
            return command
        clears = self._clears  # before the peek: a result dropped after it is noticed
        result: FrameResult | None = self.results.peek()
        stalled = result is None or not is_fresh(now, result.stamp_s, self.perception_timeout_s)
        if stalled and result is not None:
            if self.last_command is None or not self.last_command.is_stop:
                self.watchdog_trips += 1
                if is_ahead(now, result.stamp_s):
                    log.warning("the last frame is stamped %.2f s ahead of the control clock "
                                "(clocks disagree): stopping the base", result.stamp_s - now)  # fmt: skip
                else:
                    log.warning(
                        "perception stalled (%.2f s since the last frame): stopping the base",
                        now - result.stamp_s,
                    )
        reused = result is not None and result is self._last_result
        jump_s = self.odometry.last_jump_s
        target = None if stalled else target_motion(result, robot, now, reused, jump_s)
        command = self.controller.update(target, now)
        if stalled:
            command = VelocityCommand.stop(now)
        self._send(command, overridden=stalled, clears=clears)
        if result is not None and result is not self._last_result:
            self._last_result = result
            self.latency.add(now - result.stamp_s)
        self._remember_command(result)
        return command

    def _remember_command(self, result: FrameResult | None) -> None:
        """Note the command just sent as the one about `result`, the first time a tick
        took it (with or without odometry), for `command_from`."""
        if result is None:
            return
        with self._commanded_changed:
            if result.frame_index in self._commands_from:
                return
            self._commands_from[result.frame_index] = self.last_command
            while len(self._commands_from) > COMMANDS_KEPT:
                del self._commands_from[next(iter(self._commands_from))]
            self._commanded_changed.notify_all()

    def command_from(self, result: FrameResult, timeout_s: float) -> VelocityCommand | None:
        """The first command sent after `result` was taken (what the base did about that
        frame), waiting up to `timeout_s` for the loop to take it or a later result. For
        a result the loop never took (a newer one replaced it first), the command then
        in force: the one from the latest earlier result. The last command sent when the
        loop stopped or did not get there in time."""
        index = result.frame_index

        def reached() -> bool:
            return self._stop.is_set() or any(i >= index for i in self._commands_from)

        with self._commanded_changed:
            if self._commanded_changed.wait_for(reached, timeout=timeout_s):
                if index in self._commands_from:
                    return self._commands_from[index]
                earlier = [i for i in self._commands_from if i < index]
                if earlier:
                    return self._commands_from[max(earlier)]
        return self.last_command

    def _send(
        self,
        command: VelocityCommand,
        overridden: bool = False,
        clears: int | None = None,
        lock_timeout_s: float = -1.0,
    ) -> None:
        """Send `command` (zero once stopping, or when the result it was computed from, taken
        with `clears` results dropped, has been dropped since); the controller is told of
        every zero it did not choose, `overridden` here (a watchdog, no odometry, a dropped
        result) or by the base refusing to move, so that it speeds up from rest afterwards.
        A `send` still under way for `lock_timeout_s` (negative: no limit) raises
        TimeoutError: the base is hanging, and this command could only queue behind it."""
        if not self._send_lock.acquire(timeout=lock_timeout_s):
            raise _send_hangs(lock_timeout_s)
        try:
            if clears is not None and clears != self._clears and not command.is_stop:
                command, overridden = VelocityCommand.stop(command.stamp_s), True
            if self._stop.is_set() and not command.is_stop:
                command = VelocityCommand.stop(command.stamp_s)
            self.last_command = command
            sent = self.base.send(command)
        finally:
            self._send_lock.release()
        if overridden or (sent is not None and sent.is_stop and not command.is_stop):
            self.controller.stopped_elsewhere(command.stamp_s)
        if self.on_command is not None:
            self.on_command(command)

    def _run(self) -> None:
        next_tick = time.monotonic()
        try:
            while not self._stop.is_set():
                self.tick()
                next_tick += self.period_s
                if self._wake.wait(max(0.0, next_tick - time.monotonic())):
                    self._wake.clear()
                    next_tick = time.monotonic()  # a new result: its command now, then the period
        except BaseException as exc:  # the base must stop whatever went wrong
            self.error = exc
            log.exception("control loop failed: stopping the base")
            if self.on_failure is not None:
                self.on_failure()
            self._send_last_stop()


def _send_hangs(wait_s: float) -> TimeoutError:
    return TimeoutError(f"the base's send has not returned for {wait_s:g} s")


def control_failure(error: BaseException) -> RuntimeError:
    """The run's error for a control loop that failed, naming why (a base whose send
    hung, a link that refused the last zero, a bug)."""
    return RuntimeError(f"control loop failed ({type(error).__name__}: {error})")


# Commands remembered by the frame they answer: more than the outputs' queue can lag.
COMMANDS_KEPT = 64


def run_offline(
    perception: Perception,
    frames: Iterable[Frame],
    controller=None,
    odometry: OdometryPolicy | Callable[[float], Odometry | None] | None = None,
    odometry_jumps: OdometryJumps | None = None,
) -> Iterator[tuple[Frame, FrameResult | None, VelocityCommand | None]]:
    """Every frame in order; the controller (if any) is stepped once per frame at the
    frame's time. The robot pose comes from `odometry`: a base's policy, or a recorded
    pose at the frame's stamp (a bag, with `odometry_jumps` its buffer's log of jumps);
    default still at the origin. A frame without fresh odometry is not processed
    (result None) and gets a stop."""
    if isinstance(odometry, OdometryPolicy):
        odometry_jumps = odometry.jumps
    perception.odometry_jumps = odometry_jumps
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


def wait_until_due(start_s: float, index: int, rate_hz: float, clock: Callable[[], float]) -> None:
    """Sleep until frame `index` of a source played at `rate_hz` from `start_s` (on
    `clock`) is due; a frame already late does not wait."""
    delay = start_s + index / rate_hz - clock()
    if delay > 0:
        time.sleep(delay)


class ThreadedRunner:
    """Capture, pose, perception, outputs and control in their own threads, on one clock.

    Frames are re-stamped with `clock()` as they are captured, and the robot's pose is
    sampled with them (so the tracker places each frame where the robot was when it was
    taken), so the control loop's staleness checks compare like with like. A frame
    captured without fresh odometry is not processed. `pace_hz` plays a file at its
    frame rate. With `overlap_stages` the pose network infers the next frame while the
    previous one is tracked and identified (two frames in flight at most). `on_result`
    (drawing, video, log) runs on its own thread, in frame order. An error in any of
    these threads (a bad frame, a full disk, a failed control loop) ends the run and is
    raised here. After the run, `capture_running` and `outputs_stuck` say whether the
    source and `on_result`'s files are still in use by a thread that did not end: not to
    be closed under it.
    """

    def __init__(
        self,
        perception: Perception,
        control: ControlLoop,
        base,
        clock: Callable[[], float] = time.monotonic,
        overlap_stages: bool = False,
    ):
        self.perception = perception
        self.control = control
        self.base = base
        self.clock = clock
        self.overlap_stages = overlap_stages
        self.frames = LatestSlot()
        self.results = control.results
        self._stop = threading.Event()
        control.on_failure = self._stop.set  # a dead control loop ends the run
        self.odometry = control.odometry
        self.captured = 0
        self.processed = 0
        self.skipped_without_odometry = 0
        self.capture_error: BaseException | None = None
        self.pose_error: BaseException | None = None
        self.outputs_stuck = False
        self._capture_thread: threading.Thread | None = None

    @property
    def capture_running(self) -> bool:
        """The capture thread is still reading the source (a camera's read that hangs):
        the source must not be released under it (OpenCV's capture is not thread-safe)."""
        return self._capture_thread is not None and self._capture_thread.is_alive()

    def _capture(self, source: Iterable[Frame], pace_hz: float | None) -> None:
        start = self.clock()
        try:
            for index, frame in enumerate(source):
                if self._stop.is_set():
                    break
                if pace_hz:
                    wait_until_due(start, index, pace_hz, self.clock)
                stamped = dataclasses.replace(frame, stamp_s=self.clock())
                self.frames.put((index, stamped, self.odometry.sample()))
                self.captured += 1
        except Exception as exc:  # raised again by run(), after the base has stopped
            self.capture_error = exc
        finally:
            self.frames.close()

    def _newest_frames(
        self, stall_timeout_s: float | None
    ) -> Iterator[tuple[int, Frame, Odometry]]:
        """Each newest captured frame with a known robot pose, until the source ends.
        With `stall_timeout_s`, a source that delivers nothing that long (a camera whose
        read hangs) raises SourceError: the base is already held at zero by the watchdog,
        and the run ends saying why instead of waiting forever."""
        poll_s = min(1.0, stall_timeout_s / 4.0) if stall_timeout_s else 1.0
        try:
            for item in self.frames.items(self._stop, poll_s, max_wait_s=stall_timeout_s):
                if item[2] is None:  # pose unknown when taken: the control loop stops
                    self.skipped_without_odometry += 1
                    continue
                yield item
        except TimeoutError:
            raise SourceError(
                f"the camera delivered no frame for {stall_timeout_s:g} s (hung or "
                "unplugged?); [control] camera_stall_timeout_s sets the limit"
            ) from None

    def _detected_in_turn(self, stall_timeout_s: float | None
                          ) -> Iterator[tuple[int, Frame, Odometry, Detections]]:  # fmt: skip
        for index, frame, robot in self._newest_frames(stall_timeout_s):
            yield index, frame, robot, self.perception.detect_people(frame)

    def _detected_ahead(self, stall_timeout_s: float | None
                        ) -> Iterator[tuple[int, Frame, Odometry, Detections]]:  # fmt: skip
        """Pose inference on its own thread, one frame ahead of the caller."""
        handoff = Handoff()

        def infer() -> None:
            try:
                for index, frame, robot in self._newest_frames(stall_timeout_s):
                    item = (index, frame, robot, self.perception.detect_people(frame))
                    if not handoff.give(item, self._stop):
                        return
            except Exception as exc:  # raised again by run(), after the base has stopped
                self.pose_error = exc
            finally:
                handoff.close()

        worker = threading.Thread(target=infer, name="pose", daemon=True)
        worker.start()
        try:
            yield from handoff.items(poll_s=1.0)
        finally:
            self._stop.set()
            worker.join(timeout=5.0)

    def run(
        self,
        source: Iterable[Frame],
        pace_hz: float | None = None,
        on_result: Callable[[Frame, FrameResult], None] | None = None,
        max_frames: int | None = None,
        stall_timeout_s: float | None = None,
    ) -> None:
        """Drive the base from `source` until it ends, `max_frames` are processed or an
        error; a live source that delivers nothing for `stall_timeout_s` is an error."""
        capture = self._capture_thread = threading.Thread(
            target=self._capture, args=(source, pace_hz), name="capture", daemon=True
        )
        unregister_halt = outputs = detected = None
        self.perception.odometry_jumps = self.odometry.jumps  # those between frames' samples
        try:  # threads started in here: a signal landing between two starts is cleaned up
            capture.start()
            self.control.start()
            # a shutdown signal stops driving at once, not when the pose network returns
            unregister_halt = halt_on_signal(self.control.stop)
            outputs = OrderedWorker(on_result) if on_result is not None else None
            if self.overlap_stages:
                detected = self._detected_ahead(stall_timeout_s)
            else:
                detected = self._detected_in_turn(stall_timeout_s)
            for index, frame, robot, detections in detected:
                result = self.perception.conclude(frame, robot, index, detections)
                self.results.put(result)
                self.control.notify()
                self.processed += 1
                if outputs is not None:
                    outputs.submit(frame, result)
                if self.control.error is not None:
                    raise control_failure(self.control.error) from self.control.error
                if max_frames is not None and self.processed >= max_frames:
                    break
        finally:
            late_interrupt = None
            try:  # a signal now is recorded, not raised into this cleanup
                cleanup_begins()
            except KeyboardInterrupt as interrupt:  # landed before the flag was set
                late_interrupt = interrupt  # raised once the cleanup is done
            if unregister_halt is not None:
                unregister_halt()
            self._stop.set()
            self.control.stop()  # first: waiting for the pose thread must not drive on
            if detected is not None:
                detected.close()
            if capture.ident is not None:  # started
                capture.join(timeout=CAPTURE_JOIN_TIMEOUT_S)
            if outputs is not None:
                self.outputs_stuck = not outputs.close()
            interrupted = isinstance(sys.exc_info()[1], KeyboardInterrupt)
            if interrupted and self.control.error is not None:
                # a base that hung or refused the last zero may still be moving: that
                # outranks a clean stop by signal
                raise control_failure(self.control.error) from self.control.error
        for error in (self.capture_error, self.pose_error):
            if error is not None:
                raise error
        if self.control.error is not None:  # failed after the last frame was looked at
            raise control_failure(self.control.error) from self.control.error
        if late_interrupt is not None:  # the run had ended by itself when the signal came
            raise late_interrupt

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
    # a scripted or synthetic perception has no pose network, hence no pose_backend
    backend = getattr(perception, "pose_backend", None)
    overlap = overlaps_stages(config.overlap_stages, backend)
    if backend is not None:
        log.info("stages %s (overlap_stages = %r, pose network on %s)",
                 "overlapped" if overlap else "in turn", config.overlap_stages, backend)  # fmt: skip
    return ThreadedRunner(perception, control, base, clock=clock, overlap_stages=overlap)


def overlaps_stages(setting: bool | str, pose_backend: str | None) -> bool:
    """`[control] overlap_stages` for a pose runtime: "auto" overlaps the stages where
    the network runs on a GPU, which infers the next frame while the CPU tracks and
    identifies this one; on a CPU the network already keeps every core busy, and
    overlapping there gained 1-5 % of frame rate for 18-30 % more 95th-percentile
    capture-to-command latency (measured on 2 cores, docs/system.md)."""
    if setting == "auto":
        return pose_backend is not None and backend_runs_on_gpu(pose_backend)
    return bool(setting)
