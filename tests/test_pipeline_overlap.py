"""The overlapped runner: pose inference one frame ahead, outputs on their own thread."""

import dataclasses
import threading
import time

import numpy as np
import pytest

from follow.capture import LatestSlot
from follow.config import ControlConfig
from follow.control.base import NullBase
from follow.control.controller import FollowingController
from follow.handoff import Handoff, OrderedWorker
from follow.pipeline import (
    ControlLoop,
    Detections,
    FrameResult,
    ThreadedRunner,
    overlaps_stages,
)
from follow.types import (
    Frame,
    Observation,
    Odometry,
    TargetEstimate,
    TargetStatus,
    TrackState,
)


def _result(index: int, stamp_s: float) -> FrameResult:
    track = TrackState(7, np.array([4.0, 0.0, 0.0, 0.0, 1.5]), np.eye(5) * 0.01, True, stamp_s)
    return FrameResult(index, stamp_s, Odometry.origin(stamp_s), [], [track],
                       TargetEstimate(TargetStatus.TRACKING, 7, {7: 0.9}, stamp_s))  # fmt: skip


class _TimedPerception:
    """Each half takes `stage_s`; counts the frames between the start of detection and
    the end of concluding (in flight)."""

    def __init__(self, stage_s: float = 0.02, fail_detect_at: int | None = None):
        self.stage_s = stage_s
        self.fail_detect_at = fail_detect_at
        self.lock = threading.Lock()
        self.in_flight = 0
        self.max_in_flight = 0
        self.detect_threads = set()
        self.concluded: list[int] = []
        self.detected = 0

    def detect_people(self, frame):
        with self.lock:
            self.in_flight += 1
            self.max_in_flight = max(self.max_in_flight, self.in_flight)
            self.detect_threads.add(threading.current_thread().name)
            self.detected += 1
            if self.fail_detect_at is not None and self.detected >= self.fail_detect_at:
                raise ValueError("pose network failed on this frame")
        time.sleep(self.stage_s)
        return Detections([], self.stage_s * 1e3)

    def conclude(self, frame, robot, index, detections):
        time.sleep(self.stage_s)
        with self.lock:
            self.in_flight -= 1
            self.concluded.append(index)
        return _result(index, frame.stamp_s)


def _runner(perception, overlap: bool, base=None) -> ThreadedRunner:
    base = base if base is not None else NullBase()
    control = ControlLoop(FollowingController(ControlConfig()), base, LatestSlot(),
                          rate_hz=15.0, perception_timeout_s=0.5)  # fmt: skip
    return ThreadedRunner(perception, control, base, overlap_stages=overlap)


def _frames(count: int):
    return (Frame(np.zeros((16, 16, 3), np.uint8), k / 100) for k in range(count))


def test_overlapped_stages_keep_two_frames_in_flight_at_most_and_in_order():
    perception = _TimedPerception()
    runner = _runner(perception, overlap=True)
    runner.run(_frames(40), pace_hz=100.0)
    assert perception.max_in_flight == 2  # inference ran while a frame was concluded
    assert perception.detect_threads == {"pose"}
    assert perception.concluded == sorted(perception.concluded)
    assert runner.processed == len(perception.concluded) >= 10
    assert runner.base.commands[-1].is_stop


def test_stages_in_turn_keep_one_frame_in_flight():
    perception = _TimedPerception()
    runner = _runner(perception, overlap=False)
    runner.run(_frames(20), pace_hz=100.0)
    assert perception.max_in_flight == 1
    assert threading.current_thread().name in perception.detect_threads


def test_results_reach_on_result_in_order_on_the_output_thread():
    seen, threads = [], set()

    def on_result(frame, result):
        seen.append(result.frame_index)
        threads.add(threading.current_thread().name)

    runner = _runner(_TimedPerception(stage_s=0.005), overlap=True)
    runner.run(_frames(30), pace_hz=100.0, on_result=on_result)
    assert seen == sorted(seen) and len(seen) == runner.processed
    assert threads == {"outputs"}


def test_an_output_error_ends_the_run_with_the_base_stopped():
    base = NullBase()

    def on_result(frame, result):
        if result.frame_index >= 3:
            raise OSError("disk full")

    runner = _runner(_TimedPerception(stage_s=0.005), overlap=True, base=base)
    with pytest.raises(OSError, match="disk full"):
        runner.run(_frames(500), pace_hz=100.0, on_result=on_result)
    assert base.commands[-1].is_stop


def test_a_pose_error_on_the_pose_thread_ends_the_run_with_the_base_stopped():
    base = NullBase()
    runner = _runner(_TimedPerception(stage_s=0.005, fail_detect_at=5), overlap=True, base=base)
    with pytest.raises(ValueError, match="pose network failed"):
        runner.run(_frames(500), pace_hz=100.0)
    assert base.commands[-1].is_stop


def test_latency_is_recorded_once_per_result_from_capture_to_its_first_command():
    now = [10.0]
    slot = LatestSlot()
    loop = ControlLoop(FollowingController(ControlConfig()), NullBase(), slot, rate_hz=15.0,
                       perception_timeout_s=0.5, clock=lambda: now[0])  # fmt: skip
    slot.put(_result(0, 9.95))
    loop.tick()
    now[0] += 0.05
    loop.tick()  # the same result again: not a new latency
    assert loop.latency.count == 1
    assert loop.latency.summary_ms()["median"] == pytest.approx(50.0, abs=1e-6)
    slot.put(_result(1, 10.02))
    loop.tick()
    assert loop.latency.count == 2  # 50 ms and 30 ms
    assert loop.latency.summary_ms()["median"] == pytest.approx(40.0, abs=1e-6)


def test_a_new_result_is_commanded_before_the_next_fixed_tick():
    base = NullBase()
    slot = LatestSlot()
    loop = ControlLoop(FollowingController(ControlConfig()), base, slot, rate_hz=1.0,
                       perception_timeout_s=1.0).start()  # fmt: skip
    time.sleep(0.1)  # the first tick has run; the next fixed one is a second away
    sent = len(base.commands)
    slot.put(_result(0, time.monotonic()))
    loop.notify()
    deadline = time.monotonic() + 0.5
    while len(base.commands) == sent and time.monotonic() < deadline:
        time.sleep(0.005)
    loop.stop()
    assert len(base.commands) > sent
    assert loop.latency.count == 1


def test_handoff_giver_waits_until_taken_and_stops_on_request():
    handoff, stop = Handoff(), threading.Event()
    done = []
    giver = threading.Thread(target=lambda: done.append(handoff.give("x", stop)))
    giver.start()
    time.sleep(0.1)
    assert not done  # not taken yet
    assert handoff.get(1.0) == "x"
    giver.join(1.0)
    assert done == [True]
    giver = threading.Thread(target=lambda: done.append(handoff.give("y", stop)))
    giver.start()
    stop.set()
    giver.join(1.0)
    assert done == [True, False]
    handoff.close()
    handoff.get(0.0)  # "y" is still there
    assert handoff.get(0.01) is None and handoff.closed


def test_ordered_worker_keeps_order_and_raises_the_first_error_on_close():
    seen = []
    worker = OrderedWorker(seen.append, max_pending=2)
    for k in range(50):
        worker.submit(k)
    worker.close()
    assert seen == list(range(50))

    def fail(k):
        if k == 2:
            raise KeyError(k)

    worker = OrderedWorker(fail)
    with pytest.raises(KeyError):
        for k in range(100):
            worker.submit(k)
        worker.close()


def test_a_mailbox_reader_ends_when_it_is_closed_or_told_to_stop():
    slot = LatestSlot()
    slot.put("a")
    slot.close()
    assert list(slot.items(poll_s=0.01)) == ["a"]  # the last item, then the end
    stop = threading.Event()
    stop.set()
    open_slot = LatestSlot()
    open_slot.put("b")
    assert list(open_slot.items(stop, poll_s=0.01)) == []  # stopped before reading


def test_a_last_item_put_as_the_reader_times_out_is_still_read():
    """The capture thread puts the last frame and closes the slot between a reader's
    time-out and its look at `closed`: the frame is read, not dropped."""

    class _Slot(LatestSlot):
        raced = False

        def get(self, timeout_s=None):
            item = super().get(timeout_s)
            if item is None and not self.raced:
                self.raced = True
                self.put("last frame")
                self.close()
            return item

    assert list(_Slot().items(poll_s=0.01)) == ["last frame"]


@pytest.mark.parametrize(
    ("setting", "backend", "overlapped"),
    [
        ("auto", "onnxruntime:CPUExecutionProvider", False),
        ("auto", "openvino:CPU", False),
        ("auto", None, False),  # no network (a synthetic detector)
        ("auto", "onnxruntime:CUDAExecutionProvider", True),
        ("auto", "onnxruntime:TensorrtExecutionProvider", True),
        (True, "onnxruntime:CPUExecutionProvider", True),
        (False, "onnxruntime:CUDAExecutionProvider", False),
    ],
)
def test_auto_overlaps_the_stages_only_where_a_gpu_runs_the_network(setting, backend, overlapped):
    assert overlaps_stages(setting, backend) is overlapped


def test_build_runner_overlaps_by_the_perception_s_pose_runtime():
    from follow.config import ControlConfig
    from follow.pipeline import build_runner

    perception = _TimedPerception()
    for backend, overlapped in (("onnxruntime:CPUExecutionProvider", False),
                                ("onnxruntime:CUDAExecutionProvider", True)):  # fmt: skip
        perception.pose_backend = backend
        runner = build_runner(perception, NullBase(), ControlConfig())
        assert runner.overlap_stages is overlapped


class _SlowingPerception(_TimedPerception):
    """The first `fast` frames are inferred in `stage_s`, every later one takes `slow_s`;
    the target is seen in every frame."""

    def __init__(self, fast: int, slow_s: float):
        super().__init__(stage_s=0.01)
        self.fast, self.slow_s = fast, slow_s

    def detect_people(self, frame):
        detections = super().detect_people(frame)
        if self.detected > self.fast:
            time.sleep(self.slow_s)
        return detections

    def conclude(self, frame, robot, index, detections):
        result = super().conclude(frame, robot, index, detections)
        seen = dataclasses.replace(result.tracks[0], observation=Observation(np.zeros(2)))
        return dataclasses.replace(result, tracks=[seen])


def test_the_base_gets_no_moving_command_once_the_run_is_stopping():
    """A run that ends (here at --max-frames; as well Ctrl-C or an error) while the pose
    thread is still inferring stops the base at once, not after the inference."""
    stopping_moves = []

    class _Base(NullBase):
        def send(self, command):
            if runner._stop.is_set() and not command.is_stop:
                stopping_moves.append(command)
            return super().send(command)

    base = _Base()
    runner = _runner(_SlowingPerception(fast=20, slow_s=1.0), overlap=True, base=base)
    runner.run(_frames(100), pace_hz=50.0, max_frames=20)
    assert any(not c.is_stop for c in base.commands)  # the target was followed
    assert stopping_moves == []
    assert base.commands[-1].is_stop


@pytest.mark.parametrize("overlap", [False, True])
def test_a_camera_that_hangs_ends_the_run_with_an_error_and_the_base_stopped(overlap):
    """A live camera whose read blocks forever used to hold the base at zero and the run
    open for ever, saying nothing; after the stall limit the run ends naming it."""
    from follow.capture import SourceError

    released = threading.Event()

    def hanging_camera():
        yield from _frames(5)
        released.wait(30.0)  # the read that never returns

    runner = _runner(_TimedPerception(0.005), overlap=overlap)
    start = time.monotonic()
    try:
        with pytest.raises(SourceError, match="no frame for 0.6 s"):
            runner.run(hanging_camera(), stall_timeout_s=0.6)
    finally:
        released.set()
    assert time.monotonic() - start < 5.0
    assert runner.processed >= 1
    assert runner.base.commands[-1].is_stop


def test_without_a_stall_limit_a_pause_in_the_source_is_waited_out():
    def pausing_file():
        yield from _frames(3)
        time.sleep(0.8)
        yield from _frames(3)

    runner = _runner(_TimedPerception(0.005), overlap=False)
    runner.run(pausing_file())
    assert runner.captured == 6


@pytest.mark.parametrize("overlap", [False, True])
def test_a_control_loop_failure_after_the_last_frame_is_still_raised(overlap):
    """The control thread fails once the last frame has been concluded (the source then
    ends): the run must end with the error, not report a clean end of input."""
    failing = threading.Event()

    class _Controller(FollowingController):
        def update(self, target, now_s):
            if failing.is_set():
                raise ZeroDivisionError("controller broke")
            return super().update(target, now_s)

    perception = _TimedPerception(0.005)

    def frames_then_failure():
        yield from _frames(3)
        deadline = time.monotonic() + 5.0
        while 2 not in perception.concluded and time.monotonic() < deadline:
            time.sleep(0.005)
        time.sleep(0.1)  # the runner has looked at the control loop after the last frame
        failing.set()
        time.sleep(0.3)  # the control loop ticks (and fails) before the source ends

    base = NullBase()
    control = ControlLoop(_Controller(ControlConfig()), base, LatestSlot(), rate_hz=50.0,
                          perception_timeout_s=0.5)  # fmt: skip
    runner = ThreadedRunner(perception, control, base, overlap_stages=overlap)
    with pytest.raises(RuntimeError, match="control loop failed") as failure:
        runner.run(frames_then_failure())
    assert isinstance(failure.value.__cause__, ZeroDivisionError)
    assert base.commands[-1].is_stop


@pytest.mark.parametrize("overlap", [False, True])
def test_a_base_that_fails_to_send_still_lets_the_run_deliver_every_result(overlap):
    """The link to the base goes (every send raises from the third on): the control loop
    fails, and so does its last stop; the run ends with the error, but its cleanup still
    delivers every concluded frame's result (the run log) and ends the capture thread."""

    class _LinkGone(NullBase):
        def send(self, cmd):
            if len(self.commands) >= 2:
                raise OSError("serial port gone")
            return super().send(cmd)

    delivered = []
    threads_before = set(threading.enumerate())
    perception = _TimedPerception(0.01)
    runner = _runner(perception, overlap, base=_LinkGone())
    with pytest.raises(RuntimeError, match="control loop failed") as failure:
        runner.run(
            _frames(40),
            pace_hz=50.0,
            on_result=lambda frame, result: delivered.append(result.frame_index),
        )
    assert isinstance(failure.value.__cause__, OSError)
    assert runner.processed >= 1 and len(delivered) == runner.processed
    assert delivered == sorted(set(delivered))  # in order, each once
    left = set(threading.enumerate()) - threads_before
    assert not [t for t in left if t.name in ("capture", "outputs")]


def test_an_interrupted_run_whose_base_hangs_ends_with_that_error_not_a_clean_stop(
    monkeypatch,
):
    """Ctrl-C while the base's send hangs: the stop gives up on it after its waits, and
    the run ends with that failure (the base may still be moving), not with the
    interrupt a run reports as a clean stop."""
    from follow import pipeline

    monkeypatch.setattr(pipeline, "STOP_JOIN_TIMEOUT_S", 0.2)
    hanging, release = threading.Event(), threading.Event()

    class _Hangs(NullBase):
        def send(self, cmd):
            if len(self.commands) >= 3:
                hanging.set()
                release.wait()
            return super().send(cmd)

    class _InterruptedOnceHanging(_TimedPerception):
        def conclude(self, frame, robot, index, detections):  # the main thread: Ctrl-C
            if hanging.is_set():
                raise KeyboardInterrupt
            return super().conclude(frame, robot, index, detections)

    runner = _runner(_InterruptedOnceHanging(0.005), overlap=False, base=_Hangs())
    try:
        with pytest.raises(RuntimeError, match="control loop failed .TimeoutError") as failure:
            runner.run(_frames(400), pace_hz=50.0)
        assert isinstance(failure.value.__context__, KeyboardInterrupt)
    finally:
        release.set()


def test_a_shutdown_signal_stops_driving_while_the_pose_network_runs():
    """SIGTERM arrives while the main thread is inside a long native call (the pose
    network, in turn): the base gets zero at once, not when the call returns."""
    import hashlib
    import os
    import signal

    from follow.shutdown import ShutdownSignals

    probe = 20_000
    started = time.perf_counter()
    hashlib.pbkdf2_hmac("sha256", b"frame", b"salt", probe)
    iterations = int(0.8 * probe / max(time.perf_counter() - started, 1e-6))

    class _SlowNetwork(_TimedPerception):
        def detect_people(self, frame):
            if self.detected == 3:  # the fourth frame's inference is long
                threading.Thread(target=send_signal, daemon=True).start()
                hashlib.pbkdf2_hmac("sha256", b"frame", b"salt", iterations)
            return super().detect_people(frame)

        def conclude(self, frame, robot, index, detections):  # the target seen 4 m ahead
            result = super().conclude(frame, robot, index, detections)
            seen = Observation(np.array([320.0, 200.0]), np.array([320.0, 400.0]))
            track = dataclasses.replace(result.tracks[0], observation=seen)
            return dataclasses.replace(result, tracks=[track],
                                       target=dataclasses.replace(result.target, target_seen=True))  # fmt: skip

    sent = []

    def send_signal():
        time.sleep(0.2)
        sent.append(time.monotonic())
        os.kill(os.getpid(), signal.SIGTERM)

    base = NullBase()
    runner = _runner(_SlowNetwork(0.01), overlap=False, base=base)
    with ShutdownSignals(), pytest.raises(KeyboardInterrupt):
        runner.run(_frames(50), pace_hz=30.0)
    assert sent
    moving = [c for c in base.commands if not c.is_stop]
    assert moving, "the robot never drove"
    assert max(c.stamp_s for c in moving) < sent[0] + 0.1  # nothing moving after the signal
    first_stop_after = min(c.stamp_s for c in base.commands if c.is_stop and c.stamp_s >= sent[0])
    assert first_stop_after - sent[0] < 0.2  # long before the 0.8 s inference ended


def test_a_sigterm_while_the_base_hangs_ends_the_run_with_that_error(monkeypatch):
    """SIGTERM, and the base's send hangs from then on: the signal watcher's stop hangs
    in the send with its lock; the runner's own stop must still give up after its wait
    and the run end with the hung base as its error, not wait on that lock for ever."""
    import os
    import signal

    from follow import pipeline
    from follow.shutdown import ShutdownSignals

    monkeypatch.setattr(pipeline, "STOP_JOIN_TIMEOUT_S", 0.1)
    hang, release = threading.Event(), threading.Event()

    class _Hangs(NullBase):
        def send(self, cmd):
            if hang.is_set():
                release.wait(10.0)
            return super().send(cmd)

    def hang_then_signal():
        time.sleep(0.2)
        hang.set()
        os.kill(os.getpid(), signal.SIGTERM)

    runner = _runner(_TimedPerception(0.005), overlap=False, base=_Hangs())
    threading.Thread(target=hang_then_signal, daemon=True).start()
    start = time.monotonic()
    try:
        with ShutdownSignals():
            runner.run(_frames(1000), pace_hz=50.0)
    except BaseException as exc:  # a KeyboardInterrupt here would end pytest's session
        ended = exc
    finally:
        release.set()
    assert "control loop failed (TimeoutError" in str(ended), repr(ended)
    assert time.monotonic() - start < 5.0


@pytest.mark.parametrize("overlap", [False, True])
def test_a_control_loop_that_dies_with_the_odometry_ends_the_run(overlap):
    """A serial base is unplugged: its send raises (the control loop dies) and its
    odometry stops (every frame is then skipped, none gets as far as the runner's look at
    the control loop). The run must end at once with that failure, not go on without a
    control loop until the camera ends."""
    unplugged = threading.Event()

    class _Serial(NullBase):
        def send(self, cmd):
            if unplugged.is_set():
                raise OSError(5, "Input/output error")
            return super().send(cmd)

        def odometry(self):
            return None if unplugged.is_set() else super().odometry()

    def camera():  # 4 s of frames
        for k, frame in enumerate(_frames(200)):
            if k == 10:
                unplugged.set()
            yield frame

    runner = _runner(_TimedPerception(0.005), overlap=overlap, base=_Serial())
    with pytest.raises(RuntimeError, match="control loop failed .OSError") as failure:
        runner.run(camera(), pace_hz=50.0)
    assert isinstance(failure.value.__cause__, OSError)
    assert runner.captured < 100, "the run went on without its control loop"


def test_a_signal_as_the_runners_threads_start_still_stops_them(monkeypatch):
    """SIGINT between the capture thread's start and the control loop's: the
    KeyboardInterrupt came before the runner's `try`, its cleanup never ran, and the
    control loop and the capture thread were left running."""
    from follow.pipeline import ControlLoop

    real_start = ControlLoop.start

    def started_then_interrupted(loop):
        real_start(loop)
        raise KeyboardInterrupt("SIGINT")

    monkeypatch.setattr(ControlLoop, "start", started_then_interrupted)
    threads_before = set(threading.enumerate())
    runner = _runner(_TimedPerception(0.002), overlap=False)
    with pytest.raises(KeyboardInterrupt):
        runner.run(_frames(2000), pace_hz=100.0)
    time.sleep(0.1)
    left = set(threading.enumerate()) - threads_before
    assert not [t for t in left if t.is_alive() and t.name in ("capture", "control")], left
    assert runner.control.last_command is not None and runner.control.last_command.is_stop


def test_a_signal_just_before_the_cleanup_flag_still_lets_the_cleanup_run(monkeypatch):
    """The source ends and SIGINT lands as the runner's cleanup begins, before its flag
    is set: the KeyboardInterrupt must not skip the rest of the cleanup (the output
    thread drains every frame, the threads end); it is raised once that is done."""
    import signal

    from follow import pipeline
    from follow.shutdown import ShutdownSignals

    real = pipeline.cleanup_begins

    def signalled_then_flagged():
        signal.raise_signal(signal.SIGINT)  # the handler runs here, before the flag
        real()

    monkeypatch.setattr(pipeline, "cleanup_begins", signalled_then_flagged)
    written = []

    def on_result(frame, result):  # a slow encoder: frames queue up
        time.sleep(0.02)
        written.append(result.frame_index)

    threads_before = set(threading.enumerate())
    runner = _runner(_TimedPerception(0.002), overlap=False)
    with ShutdownSignals(), pytest.raises(KeyboardInterrupt):
        runner.run(_frames(20), pace_hz=100.0, on_result=on_result)
    assert runner.processed > 0 and len(written) == runner.processed
    left = set(threading.enumerate()) - threads_before
    assert not [t for t in left if t.name in ("capture", "outputs")]
