"""`follow run`'s loop choice and its bounded memory: a connected base is always driven
by the threaded runner (watchdog, capture-time odometry), even from a file; only a run
without a base goes frame by frame; the run keeps counters, not results."""

import json
import subprocess
import sys
import time
from types import SimpleNamespace

import numpy as np
import pytest
from recording_base import RecordingBase

from follow import run as run_module
from follow.camera import CameraModel, CameraPose
from follow.config import Config
from follow.control.base import NullBase
from follow.pipeline import Detections, FrameResult
from follow.types import Frame, TargetEstimate, TargetStatus, TrackState

CAMERA = CameraModel.from_fov((64, 48), 70.0, CameraPose(height_m=1.0))


class _Perception:
    def detect_people(self, frame):
        return Detections([], 0.0)

    def conclude(self, frame, robot, index, detections):
        track = TrackState(1, np.array([4.0, 0.0, 0.0, 0.0, 1.45]), np.eye(5) * 0.01, True,
                           frame.stamp_s)  # fmt: skip
        target = TargetEstimate(TargetStatus.TRACKING, 1, {1: 0.9}, frame.stamp_s)
        return FrameResult(index, frame.stamp_s, robot, [], [track], target)

    def process(self, frame, robot, index):
        return self.conclude(frame, robot, index, self.detect_people(frame))


def _run_args(camera_path, source: str = "in.avi", json: bool = True) -> SimpleNamespace:
    """`follow run`'s arguments for `source` with a camera file and no outputs."""
    return SimpleNamespace(
        max_frames=None, config=None, mavlink=None, replay=None, source=source,
        image_topic=None, odom_topic=None, camera_info_topic=None, skeletons_topic=None,
        realtime=False, camera=str(camera_path), output_video=None, log=None,
        frames_dir=None, target_id=None, json=json, folder_fps=15.0, no_base=False,
    )  # fmt: skip


class _StillFile:
    """A 10 fps file of `frames` black frames."""

    fps, live = 10.0, False

    def __init__(self, frames: int):
        self.frames = frames

    def __iter__(self):
        return iter([Frame(np.zeros((48, 64, 3), np.uint8), k / 10) for k in range(self.frames)])

    def close(self):
        pass


def _run(base, monkeypatch, offline_allowed):
    if not offline_allowed:
        monkeypatch.setattr(run_module, "run_offline", lambda *a, **k: pytest.fail("offline"))
    frames = [Frame(np.zeros((48, 64, 3), np.uint8), k / 10) for k in range(10)]
    summary = run_module.RunSummary()
    run_module.run_frames(
        SimpleNamespace(realtime=False, max_frames=None), Config(),
        SimpleNamespace(live=False, fps=10.0), iter(frames), _Perception(), CAMERA, base,
        run_module.Outputs({}, 10.0), summary,
    )  # fmt: skip
    return summary


def test_a_file_with_a_base_plays_at_its_frame_rate_through_the_threaded_runner(monkeypatch):
    base = RecordingBase()
    started = time.monotonic()
    summary = _run(base, monkeypatch, offline_allowed=False)
    assert time.monotonic() - started >= 0.85  # 10 frames at 10 fps, not as fast as possible
    assert summary.frames == 10
    assert summary.commands >= 12  # the control loop ticks at 15 Hz, not once per frame
    assert base.commands[-1].is_stop


def test_a_file_without_a_base_is_processed_frame_by_frame(monkeypatch):
    base = NullBase()
    summary = _run(base, monkeypatch, offline_allowed=True)
    assert summary.frames == 10 and summary.commands == 10
    assert summary.states == {"tracking": 10}


def test_memory_stays_flat_over_a_synthetic_run():
    """Measured in a process of its own: in the test process, what earlier tests left
    (threads, allocator arenas; 870 MiB resident by then) moved the reading by 5 MiB."""
    entry = "import sys; from follow.cli import main; sys.exit(main(sys.argv[1:]))"
    command = [sys.executable, "-c", entry,
               "bench", "memory", "--frames", "1100", "--warmup-frames", "300", "--json"]  # fmt: skip
    finished = subprocess.run(command, capture_output=True, text=True, timeout=600)
    assert finished.returncode == 0, finished.stderr[-2000:]
    result = json.loads(finished.stdout.strip().splitlines()[-1])
    assert result["frames"] == 1100
    # Keeping every result grows 4.6 MiB per 400 frames on this path (~9 MiB here).
    assert result["growth_mib"] < 4.0, result


@pytest.mark.parametrize("warmup, message", [
    ("0", "argument --warmup-frames: expected an integer >= 1"),
    ("10", "--warmup-frames 10 must be below --frames 10"),
])
def test_bench_memory_names_a_warm_up_it_cannot_measure_after(warmup, message, capsys):
    """It said `warm-up (0) must be between 0 and frames (10)`, naming no option."""
    from follow import cli

    try:
        code = cli.main(["bench", "memory", "--frames", "10", "--warmup-frames", warmup])
    except SystemExit as exit_:  # argparse's own refusal
        code = exit_.code
    assert code != 0 and message in capsys.readouterr().err


@pytest.mark.parametrize("fails", ["no frames", "camera file"])
def test_the_source_is_released_when_the_run_fails_before_it_starts(tmp_path, monkeypatch, fails):
    """A camera opened for a run that then fails (an empty source, an unreadable camera
    file) is released, not left busy for the next attempt in the same process."""

    class Source:
        fps = 15.0
        closed = False

        def __iter__(self):
            if fails == "no frames":
                return iter([])
            return iter([Frame(np.zeros((48, 64, 3), np.uint8), 0.0)])

        def close(self):
            self.closed = True

    source = Source()
    monkeypatch.setattr(run_module, "open_source", lambda *a, **k: source)
    args = _run_args(tmp_path / "missing.yaml", source="0", json=False)
    with pytest.raises((ValueError, OSError)):
        run_module.main(args)
    assert source.closed


def test_a_live_camera_that_hangs_ends_follow_run_after_the_stall_limit():
    """`[control] camera_stall_timeout_s` reaches the runner for a live source."""
    import threading

    from follow.capture import SourceError

    released = threading.Event()

    def camera():
        yield from (Frame(np.zeros((48, 64, 3), np.uint8), k / 10) for k in range(3))
        released.wait(30.0)

    config = Config().replace("control", camera_stall_timeout_s=0.5)
    base = RecordingBase()
    started = time.monotonic()
    try:
        with pytest.raises(SourceError, match="no frame for 0.5 s"):
            run_module.run_frames(
                SimpleNamespace(realtime=False, max_frames=None), config,
                SimpleNamespace(live=True, fps=30.0), camera(), _Perception(), CAMERA, base,
                run_module.Outputs({}, 30.0), run_module.RunSummary(),
            )  # fmt: skip
    finally:
        released.set()
    assert time.monotonic() - started < 5.0
    assert base.commands[-1].is_stop


def test_a_live_cameras_size_probe_frame_is_not_run(tmp_path, monkeypatch):
    """The first frame of a live camera is read to learn its size before the models load
    (seconds): it is not fed to the run, where it would be stamped as just captured."""
    seen = []

    class Recording(_Perception):
        def detect_people(self, frame):
            seen.append(int(frame.image[0, 0, 0]))
            return super().detect_people(frame)

    class LiveSource:
        fps, live = 30.0, True

        def __iter__(self):
            for k in range(4):
                if k:
                    time.sleep(0.1)  # a camera's pace: each frame is taken by the run
                yield Frame(np.full((48, 64, 3), k, np.uint8), float(k))

        def close(self):
            pass

    CAMERA.save(tmp_path / "camera.yaml")
    monkeypatch.setattr(run_module, "open_source", lambda *a, **k: LiveSource())
    monkeypatch.setattr(run_module, "build_perception", lambda *a, **k: Recording())
    args = _run_args(tmp_path / "camera.yaml", source="0")
    run_module.main(args)
    assert seen == [1, 2, 3]


def test_the_frame_rate_is_the_runs_own_not_the_bases_connection_or_closing(
    tmp_path, monkeypatch
):
    """The summary's fps counts the time the frames took, not the seconds spent waiting
    for the vehicle's heartbeat when the base is opened, nor closing it."""
    now = [0.0]

    class Clocked(_Perception):
        def process(self, frame, robot, index):
            now[0] += 0.1  # each frame takes 0.1 s
            return super().process(frame, robot, index)

    class Base(NullBase):
        def close(self):
            now[0] += 5.0  # the link closed slowly

    def open_base(config):
        now[0] += 10.0  # the vehicle's heartbeat came late
        return Base()

    CAMERA.save(tmp_path / "camera.yaml")
    monkeypatch.setattr(run_module, "time", SimpleNamespace(perf_counter=lambda: now[0]))
    monkeypatch.setattr(run_module, "open_source", lambda *a, **k: _StillFile(20))
    monkeypatch.setattr(run_module, "build_perception", lambda *a, **k: Clocked())
    monkeypatch.setattr(run_module, "open_base", open_base)
    args = _run_args(tmp_path / "camera.yaml", source="in.avi")
    result = run_module.main(args)
    assert result["frames"] == 20
    assert result["fps"] == pytest.approx(10.0)


def test_frames_captured_without_the_bases_odometry_are_reported(tmp_path, monkeypatch):
    """A threaded run skips a frame captured while the base has no fresh odometry; the
    summary says how many, as a bag's run does, rather than leaving them uncounted."""
    import threading

    class Base(RecordingBase):
        captured = 0

        def odometry(self):
            if threading.current_thread().name == "capture":
                self.captured += 1
                if self.captured <= 3:  # the vehicle's clock not yet trusted
                    return None
            return super().odometry()

    CAMERA.save(tmp_path / "camera.yaml")
    monkeypatch.setattr(run_module, "open_source", lambda *a, **k: _StillFile(10))
    monkeypatch.setattr(run_module, "build_perception", lambda *a, **k: _Perception())
    monkeypatch.setattr(run_module, "open_base", lambda config: Base())
    args = _run_args(tmp_path / "camera.yaml", source="in.avi")
    result = run_module.main(args)
    assert result["frames_without_odometry"] >= 1
    assert result["frames"] + result["dropped_frames"] + result["frames_without_odometry"] == 10
