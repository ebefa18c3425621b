"""Shutdown under threads and signals: a stuck output thread cannot hang Ctrl-C; a signal
that arrives while the run cleans up (it ended by itself, or failed) is recorded, not
raised into the cleanup, so every processed frame is logged, the video finalised and a
failure still reported; and a second signal stops a MAVLink rover even when the
interrupted code holds the base's lock."""

import io
import json
import os
import signal
import subprocess
import sys
import textwrap
import threading
import time
from types import SimpleNamespace

import cv2
import numpy as np
import pytest

from follow import run as run_module
from follow.camera import CameraModel, CameraPose
from follow.handoff import OrderedWorker
from follow.pipeline import Detections, FrameResult
from follow.types import Observation, Odometry, TargetEstimate, TargetStatus, TrackState

SEEN = Observation(np.array([32.0, 20.0]), np.array([32.0, 40.0]))  # the target in view

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


# --------------------------------------------------------------------------- 1
def test_ordered_worker_close_is_bounded_when_the_callback_hangs():
    """OrderedWorker.close(timeout_s) must return within about timeout_s even when the
    callback never returns (a stalled disk / NFS / pipe) and the queue is full."""
    release, started = threading.Event(), threading.Event()

    def callback(_):
        started.set()
        release.wait()

    worker = OrderedWorker(callback, max_pending=2)
    worker.submit(0)
    assert started.wait(2.0)
    worker.submit(1)
    worker.submit(2)  # the queue is now full, the worker stuck in the callback
    closer = threading.Thread(target=worker.close, kwargs={"timeout_s": 0.5}, daemon=True)
    t0 = time.monotonic()
    closer.start()
    closer.join(5.0)
    hung = closer.is_alive()
    release.set()  # let the daemon threads end
    assert not hung, f"close(timeout_s=0.5) still running after {time.monotonic() - t0:.1f} s"


HUNG_OUTPUT_SCRIPT = textwrap.dedent("""
    import sys, threading, time
    import numpy as np
    from follow import handoff
    from follow.config import ControlConfig
    from follow.pipeline import Detections, FrameResult, build_runner
    from follow.shutdown import ShutdownSignals
    from follow.types import Frame, Odometry, TargetEstimate, TargetStatus, TrackState

    handoff.OrderedWorker.close.__defaults__ = (2.0,)  # so a bounded close ends fast

    class Base:
        def send(self, c): return c
        def odometry(self): return Odometry(0.0, 0.0, 0.0, time.monotonic())
        def close(self): pass

    class Perception:
        def detect_people(self, frame): return Detections([], 0.0)
        def conclude(self, frame, robot, index, detections):
            track = TrackState(1, np.array([4.0, 0.0, 0.0, 0.0, 1.45]), np.eye(5) * 0.01,
                               True, frame.stamp_s)
            target = TargetEstimate(TargetStatus.TRACKING, 1, {1: 0.9}, frame.stamp_s)
            return FrameResult(index, frame.stamp_s, robot, [], [track], target)

    def frames():
        k = 0
        while True:
            yield Frame(np.zeros((48, 64, 3), np.uint8), k / 15)
            k += 1

    def on_result(frame, result):  # a video/log write that never returns (stalled disk)
        print("OUTPUT-STUCK", flush=True)
        threading.Event().wait()

    runner = build_runner(Perception(), Base(), ControlConfig())
    with ShutdownSignals():
        try:
            runner.run(frames(), pace_hz=15.0, on_result=on_result)
        except KeyboardInterrupt:
            pass
    print("EXITED", flush=True)
""")


def test_ctrl_c_ends_a_run_whose_output_thread_is_stuck():
    """`follow run`'s first Ctrl-C must end the process (base zeroed, outputs given up
    after their time-out); a stuck output callback makes it hang for ever."""
    env = dict(os.environ, PYTHONPATH=REPO)
    proc = subprocess.Popen(
        [sys.executable, "-c", HUNG_OUTPUT_SCRIPT],
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
        text=True,
        env=env,
        cwd=REPO,
    )
    try:
        first = []
        reader = threading.Thread(target=lambda: first.append(proc.stdout.readline()), daemon=True)
        reader.start()
        reader.join(30.0)
        assert first and first[0].strip() == "OUTPUT-STUCK"
        time.sleep(1.0)  # the queue fills, the feeding loop waits in submit()
        proc.send_signal(signal.SIGINT)
        try:
            out, _ = proc.communicate(timeout=15.0)
        except subprocess.TimeoutExpired:
            pytest.fail("the process still runs 15 s after SIGINT (OrderedWorker.close loops)")
        assert "EXITED" in out
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()


# --------------------------------------------------------------------------- 2
def _write_video(path, frames=30, size=(64, 48), fps=15.0):
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), fps, size)
    for i in range(frames):
        image = np.full((size[1], size[0], 3), 90, np.uint8)
        cv2.rectangle(image, (5 + i, 5), (20 + i, 40), (30, 60, 200), -1)
        writer.write(image)
    writer.release()


class _Perception:
    identifier = None

    def detect_people(self, frame):
        return Detections([], 0.0)

    def conclude(self, frame, robot, index, detections):
        track = TrackState(1, np.array([4.0, 0.0, 0.0, 0.0, 1.45]), np.eye(5) * 0.01, True,
                           frame.stamp_s, observation=SEEN)  # fmt: skip
        target = TargetEstimate(TargetStatus.TRACKING, 1, {1: 0.9}, frame.stamp_s)
        return FrameResult(index, frame.stamp_s, robot, [], [track], target)

    def process(self, frame, robot, index):
        return self.conclude(frame, robot, index, self.detect_people(frame))


class _Base:
    """A connected base (so `follow run` takes the threaded runner); `close_hook` runs
    inside close(), like the ~0.1 s MavlinkBase.close spends sending zeros and joining."""

    def __init__(self, close_hook=None):
        self.commands = []
        self.close_hook = close_hook
        self.closed = False

    def send(self, cmd):
        self.commands.append(cmd)
        return cmd

    def odometry(self):
        return Odometry(0.0, 0.0, 0.0, time.monotonic())

    def close(self):
        self.closed = True
        if self.close_hook:
            self.close_hook()


def _args(tmp_path, **kw):
    _write_video(tmp_path / "in.mp4")
    CameraModel.from_fov((64, 48), 70.0, CameraPose(height_m=1.0)).save(tmp_path / "cam.yaml")
    args = SimpleNamespace(
        source=str(tmp_path / "in.mp4"), image_topic=None, odom_topic=None,
        camera_info_topic=None, skeletons_topic=None, camera=str(tmp_path / "cam.yaml"),
        config=None, mavlink=None, target_id=None, output_video=str(tmp_path / "out.mp4"),
        frames_dir=None, log=str(tmp_path / "run.jsonl"), realtime=True, max_frames=None,
        replay=None, json=True, folder_fps=15.0, no_base=False,
    )  # fmt: skip
    for k, v in kw.items():
        setattr(args, k, v)
    return args


def _video_frames(path):
    cap = cv2.VideoCapture(str(path))
    n = 0
    while cap.read()[0]:
        n += 1
    return n


def test_sigterm_while_the_base_closes_does_not_escape_the_cleanup(tmp_path, monkeypatch):
    """The run ended by itself (end of the file); SIGTERM (systemd stop) arrives while
    base.close() runs. The video must still be finalised and main() return."""
    monkeypatch.setattr(run_module, "build_perception", lambda *a, **k: _Perception())
    base = _Base(close_hook=lambda: signal.raise_signal(signal.SIGTERM))
    monkeypatch.setattr(run_module, "open_base", lambda config: base)
    args = _args(tmp_path)
    try:
        summary = run_module.main(args)
    except KeyboardInterrupt:
        summary = None
    frames = _video_frames(tmp_path / "out.mp4")
    assert summary is not None, (
        f"KeyboardInterrupt escaped follow run's cleanup; {frames} video frames readable"
    )
    assert frames >= 25, f"video not finalised: {frames} frames readable"


def test_a_base_whose_close_hangs_does_not_hang_follow_run(tmp_path, monkeypatch, caplog):
    """A third-party base whose close() never returns (a driver stuck on its link): the
    run gives up on it after BASE_CLOSE_WAIT_S, with a warning naming it, and still
    finalises the video and the log. It used to wait on the close for ever."""
    release, closing = threading.Event(), []

    class _StuckBase(_Base):
        pass

    def hang():
        closing.append(time.monotonic())
        release.wait(5.0)

    monkeypatch.setattr(run_module, "build_perception", lambda *a, **k: _Perception())
    monkeypatch.setattr(run_module, "open_base", lambda config: _StuckBase(close_hook=hang))
    monkeypatch.setattr(run_module, "BASE_CLOSE_WAIT_S", 0.5)
    try:
        summary = run_module.main(_args(tmp_path))
        returned_s = time.monotonic()
    finally:
        release.set()
    assert closing and returned_s - closing[0] < 2.0, "follow run waited on the base's close"
    assert "base _StuckBase has not closed after 0.5 s" in caplog.text
    lines = (tmp_path / "run.jsonl").read_text().splitlines()
    assert len(lines) - 1 == summary["frames"] > 0  # the log closed, every frame in it
    assert _video_frames(tmp_path / "out.mp4") >= 25  # the video finalised


def test_an_error_the_base_close_raises_is_still_the_run_error(tmp_path, monkeypatch):
    """The close bounded in time still reports its failure (a serial port gone), after
    the outputs were closed."""

    def unplugged():
        raise OSError(5, "Input/output error")

    monkeypatch.setattr(run_module, "build_perception", lambda *a, **k: _Perception())
    monkeypatch.setattr(run_module, "open_base", lambda config: _Base(close_hook=unplugged))
    with pytest.raises(OSError, match="Input/output error"):
        run_module.main(_args(tmp_path))
    assert _video_frames(tmp_path / "out.mp4") >= 25


def test_sigterm_while_outputs_drain_loses_no_logged_frame(tmp_path, monkeypatch):
    """The run ended by itself; SIGTERM arrives while the runner waits for the output
    thread to finish the frames still queued. Every processed frame must be logged,
    and the video/log must not be closed under the output thread."""
    monkeypatch.setattr(run_module, "build_perception", lambda *a, **k: _Perception())
    monkeypatch.setattr(run_module, "open_base", lambda config: _Base())
    real_write = run_module.Outputs.write

    def slow_write(self, frame, result, command):  # a slow encoder: the queue fills
        time.sleep(0.1)
        real_write(self, frame, result, command)

    monkeypatch.setattr(run_module.Outputs, "write", slow_write)
    real_close = OrderedWorker.close

    def close_then_signalled(self, timeout_s=30.0):
        signal.raise_signal(signal.SIGTERM)  # arrives while the queue drains
        return real_close(self, timeout_s)

    monkeypatch.setattr(OrderedWorker, "close", close_then_signalled)
    workers = []
    real_init = OrderedWorker.__init__

    def init(self, *a, **k):
        real_init(self, *a, **k)
        workers.append(self)

    monkeypatch.setattr(OrderedWorker, "__init__", init)
    args = _args(tmp_path)
    try:
        summary = run_module.main(args)
    except KeyboardInterrupt:
        summary = None
    worker = workers[0]
    worker._thread.join(5.0)
    lines = (tmp_path / "run.jsonl").read_text().splitlines()
    logged = len(lines) - 1  # the header
    assert worker.error is None, f"the output thread wrote after close: {worker.error!r}"
    assert summary is not None and summary["stopped_by"] == "SIGTERM"
    assert logged == summary["frames"] > 0  # every processed frame


def test_a_run_error_is_not_turned_into_a_clean_exit_by_a_signal_in_cleanup(tmp_path, monkeypatch):
    """An output error (disk full) ends the run; SIGTERM lands during the cleanup. The
    error must still be raised, not reported as a clean 'stopped_by: SIGTERM'."""
    monkeypatch.setattr(run_module, "build_perception", lambda *a, **k: _Perception())
    base = _Base(close_hook=lambda: None)
    monkeypatch.setattr(run_module, "open_base", lambda config: base)

    def failing_write(self, frame, result, command):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(run_module.Outputs, "write", failing_write)
    real_stop = run_module.build_runner

    def build_runner(*a, **k):
        runner = real_stop(*a, **k)
        stop = runner.control.stop

        def stop_signalled():
            signal.raise_signal(signal.SIGTERM)  # lands in the runner's finally
            stop()

        runner.control.stop = stop_signalled
        return runner

    monkeypatch.setattr(run_module, "build_runner", build_runner)
    with pytest.raises(OSError, match="No space left"):
        summary = run_module.main(_args(tmp_path))
        pytest.fail(f"the disk-full error was swallowed; summary {json.dumps(summary)}")


# --------------------------------------------------------------------------- 3
def test_second_signal_stops_the_rover_even_inside_a_base_lock(monkeypatch):
    """shutdown.py: a second signal 'stops the base first (from a helper thread, so a lock
    held by the interrupted code cannot block it)'. If it lands while the main thread is
    inside MavlinkBase.send (ControlLoop.stop's zero), the helper blocks on the base's
    lock and the process exits after 1 s with the moving command still streaming."""
    from follow import shutdown
    from follow.config import MavlinkConfig
    from follow.control.mavlink_base import LinkState, MavlinkBase
    from follow.sim.rover import RoverLimits, SimRover
    from follow.types import VelocityCommand

    with SimRover(heartbeat_rate_hz=5, limits=RoverLimits(guided_timeout_s=3.0)) as rover:
        base = MavlinkBase(MavlinkConfig(connection=rover.connection, arm=True,
                                         heartbeat_timeout_s=0.6, connect_timeout_s=2.0,
                                         odometry_timeout_s=0.3))  # fmt: skip
        try:
            assert base.state is LinkState.ACTIVE
            end = time.monotonic() + 1.0
            while time.monotonic() < end:  # the control loop drives forward
                base.send(VelocityCommand(0.8, 0.0, time.monotonic()))
                time.sleep(0.05)
            at_exit = {}

            def fake_exit(code):  # what has reached the vehicle when the process dies
                time.sleep(0.1)
                at_exit["streamed"] = base._command[0]
                at_exit["rover"] = rover.last_setpoint
                at_exit["state"] = base._state

            monkeypatch.setattr(shutdown.os, "_exit", fake_exit)
            real_check = base._check_link_locked
            fired = []

            def check_then_signalled():  # runs with base._lock held
                real_check()
                # in the main thread's send: the sender thread checks the link too, and
                # a signal it raised before the block below would find no handler there
                if not fired and threading.current_thread() is threading.main_thread():
                    fired.append(1)
                    signal.raise_signal(signal.SIGTERM)  # the second signal lands here

            monkeypatch.setattr(base, "_check_link_locked", check_then_signalled)
            with shutdown.ShutdownSignals() as signals:
                signals.base = base
                signals.reason = "SIGINT"  # the first signal is being handled
                base.send(VelocityCommand.stop(time.monotonic()))  # ControlLoop.stop's zero
            assert fired and at_exit
            streamed, rover_last = at_exit["streamed"], at_exit["rover"]
            assert streamed.is_stop and rover_last[1] == 0.0
        finally:
            monkeypatch.undo()
            base.close()


# --------------------------------------------------------------------------- 4
class _StallingDisk(io.RawIOBase):
    """A file whose disk stalls from its `stall_at`-th write: the write blocks, inside the
    buffered file's lock, until `release` (or 10 s)."""

    def __init__(self, stall_at: int):
        self.stall_at, self.writes = stall_at, 0
        self.stuck, self.release = threading.Event(), threading.Event()

    def writable(self):
        return True

    def write(self, data):
        self.writes += 1
        if self.writes >= self.stall_at:
            self.stuck.set()
            self.release.wait(10.0)
        return len(data)


def test_ctrl_c_ends_follow_run_whose_log_is_on_a_stalled_disk(tmp_path, monkeypatch, caplog):
    """The output thread is stuck writing the log (its file's lock held); after Ctrl-C
    the runner gives up on it, and `follow run` must then not close the log under it
    (a flush that waits on that lock for ever), but return, naming the log left open."""
    disk = _StallingDisk(stall_at=3)

    class _LogOnStalledDisk(run_module.RunLogWriter):
        def __init__(self, path, header):
            super().__init__(path, header)
            self._fh.close()
            self._fh = io.TextIOWrapper(io.BufferedWriter(disk))

    monkeypatch.setattr(run_module, "RunLogWriter", _LogOnStalledDisk)
    monkeypatch.setattr(OrderedWorker.close, "__defaults__", (0.3,))
    monkeypatch.setattr(run_module, "build_perception", lambda *a, **k: _Perception())
    monkeypatch.setattr(run_module, "open_base", lambda config: _Base())
    released_by_test = []

    def ctrl_c_then_release():
        if disk.stuck.wait(5.0):
            os.kill(os.getpid(), signal.SIGINT)
        if not disk.release.wait(5.0):  # main() has not returned: let it
            released_by_test.append(1)
            disk.release.set()

    threading.Thread(target=ctrl_c_then_release, daemon=True).start()
    try:
        summary = run_module.main(_args(tmp_path, output_video=None))
    finally:
        returned = not disk.release.is_set()
        disk.release.set()
    assert returned and not released_by_test, "follow run waited on the stuck log's lock"
    assert summary["stopped_by"] == "SIGINT"
    assert "not closing" in caplog.text and "run.jsonl" in caplog.text


class _HangingCamera:
    """A camera (cv2.VideoCapture) whose read hangs from the 8th frame until `unhang`;
    it notes a `release` called while a read is under way."""

    def __init__(self, *args, **kwargs):
        self.frames, self.reading = 0, 0
        self.unhang = threading.Event()
        self.released_while_reading: list[bool] = []

    def isOpened(self):
        return True

    def get(self, prop):
        return 30.0 if prop == cv2.CAP_PROP_FPS else 0.0

    def grab(self):
        self.reading += 1
        try:
            if self.frames >= 8:
                self.unhang.wait(10.0)
            time.sleep(1 / 30)
            self.frames += 1
            return True
        finally:
            self.reading -= 1

    def retrieve(self):
        return True, np.random.default_rng(self.frames).integers(0, 255, (48, 64, 3), np.uint8)

    def read(self):
        return self.grab() and self.retrieve()

    def release(self):
        self.released_while_reading.append(self.reading > 0)


def test_a_camera_whose_read_hangs_is_not_released_under_the_read(tmp_path, monkeypatch):
    """A live camera's read hangs: the run ends on the stall limit while the capture
    thread is still inside the read; the camera must not be released from the main
    thread meanwhile (OpenCV's capture is not thread-safe), but left to the exit."""
    from follow import pipeline
    from follow.capture import SourceError

    cameras = []

    def open_camera(*args):
        cameras.append(_HangingCamera())
        return cameras[-1]

    monkeypatch.setattr(cv2, "VideoCapture", open_camera)
    monkeypatch.setattr(pipeline, "CAPTURE_JOIN_TIMEOUT_S", 0.1)
    monkeypatch.setattr(run_module, "build_perception", lambda *a, **k: _Perception())
    monkeypatch.setattr(run_module, "open_base", lambda config: _Base())
    (tmp_path / "stall.toml").write_text("[control]\ncamera_stall_timeout_s = 0.3\n")
    args = _args(tmp_path, source="0", realtime=False, output_video=None, log=None,
                 config=str(tmp_path / "stall.toml"))  # fmt: skip
    try:
        with pytest.raises(SourceError, match="no frame for 0.3 s"):
            run_module.main(args)
    finally:
        for camera in cameras:
            camera.unhang.set()
    assert cameras and True not in cameras[0].released_while_reading
