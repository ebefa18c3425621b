"""`follow run` refuses outputs that would overwrite its inputs or each other, and files
in folders that do not exist, before it opens or writes anything."""

from __future__ import annotations

import argparse
import dataclasses

import pytest

from follow.run import check_output_paths


def _args(tmp_path, **outputs) -> argparse.Namespace:
    (tmp_path / "in.avi").write_bytes(b"video")
    (tmp_path / "camera.yaml").write_text("camera")
    values = dict(source=str(tmp_path / "in.avi"), camera=str(tmp_path / "camera.yaml"),
                  config=None, replay=None, output_video=None, log=None, frames_dir=None)  # fmt: skip
    values.update(outputs)
    return argparse.Namespace(**values)


@pytest.mark.parametrize(
    "outputs, message",
    [
        ({"output_video": "in.avi"}, "--output-video .* is also the source"),
        ({"log": "camera.yaml"}, "--log .* is also the --camera"),
        ({"log": "run.mp4", "output_video": "run.mp4"}, "is also the --output-video"),
        ({"output_video": "missing/out.mp4"}, "the folder .*missing does not exist"),
        ({"log": "."}, "--log .* is a folder"),
        ({"frames_dir": "in.avi"}, "--frames-dir .* is also the source"),
        ({"output_video": "out.webm"}, "--output-video .*out.webm: name it .mp4 or .avi"),
        ({"output_video": "out"}, "--output-video .*out: name it .mp4 or .avi"),
    ],
)
def test_outputs_that_would_lose_something_are_refused(tmp_path, outputs, message):
    args = _args(tmp_path, **{k: str(tmp_path / v) for k, v in outputs.items()})
    before = {p.name: p.read_bytes() for p in tmp_path.iterdir() if p.is_file()}
    with pytest.raises(ValueError, match=message):
        check_output_paths(args)
    assert {p.name: p.read_bytes() for p in tmp_path.iterdir() if p.is_file()} == before


def test_new_files_in_existing_folders_pass(tmp_path):
    check_output_paths(_args(tmp_path, output_video=str(tmp_path / "out.AVI")))
    check_output_paths(_args(tmp_path, output_video=str(tmp_path / "out.mp4"),
                             log=str(tmp_path / "run.jsonl"), frames_dir=str(tmp_path / "f")))  # fmt: skip


def test_a_frames_dir_holding_another_runs_frames_is_refused(tmp_path):
    """Frames are named by their index: a run into a folder of an earlier run's frames
    would leave that run's frames among its own (past its end, and where a threaded run
    dropped frames), so the folder read back would show two runs mixed."""
    (tmp_path / "f").mkdir()
    (tmp_path / "f" / "notes.txt").write_text("kept")
    check_output_paths(_args(tmp_path, frames_dir=str(tmp_path / "f")))  # no frames in it
    (tmp_path / "f" / "000123.jpg").write_bytes(b"jpeg")
    with pytest.raises(ValueError, match="--frames-dir .* already holds annotated frames"):
        check_output_paths(_args(tmp_path, frames_dir=str(tmp_path / "f")))
    assert (tmp_path / "f" / "000123.jpg").read_bytes() == b"jpeg"


def test_an_annotated_frame_that_cannot_be_written_is_an_error_not_lost(tmp_path):
    import shutil

    import numpy as np

    from follow.pipeline import FrameResult
    from follow.run import Outputs
    from follow.types import Frame, Odometry, TargetEstimate, TargetStatus

    outputs = Outputs({}, 15.0, frames_dir=tmp_path / "frames")
    frame = Frame(np.zeros((48, 64, 3), np.uint8), 0.0)
    result = FrameResult(0, 0.0, Odometry.origin(0.0), [], [],
                         TargetEstimate(TargetStatus.INITIAL, None, {}, 0.0))  # fmt: skip
    outputs.write(frame, result, None)
    assert (tmp_path / "frames" / "000000.jpg").is_file()
    shutil.rmtree(tmp_path / "frames")  # the folder is gone (or the disk is full)
    with pytest.raises(OSError, match="000001.jpg"):
        outputs.write(frame, dataclasses.replace(result, frame_index=1), None)


def test_the_log_is_closed_even_when_the_video_fails_to_close(tmp_path):
    from follow.run import Outputs
    from follow.runlog import read_run_log

    class FailingWriter:
        def release(self):
            raise OSError("No space left on device")

    outputs = Outputs({"run": "test"}, 15.0, log_path=tmp_path / "run.jsonl")
    outputs._writer = FailingWriter()
    with pytest.raises(OSError, match="No space"):
        outputs.close()
    assert outputs.log._fh.closed
    header, records = read_run_log(tmp_path / "run.jsonl")
    assert header["run"] == "test" and list(records) == []


def test_the_video_plays_in_the_frames_own_time(tmp_path):
    # A threaded run processes only some of a 10 fps camera's frames: each stands in the
    # video until the next, which played 3.75x fast with every processed frame written
    # once. A frame never goes in fewer than once, nor longer than 2 s.
    import cv2
    import numpy as np

    from follow.pipeline import FrameResult
    from follow.run import Outputs
    from follow.types import Frame, Odometry, TargetEstimate, TargetStatus

    path = tmp_path / "out.avi"
    outputs = Outputs({}, 10.0, video_path=path)
    estimate = TargetEstimate(TargetStatus.INITIAL, None, {}, 0.0)
    for index, stamp in enumerate([0.0, 0.1, 0.4, 0.45, 0.6, 9.0]):
        frame = Frame(np.full((48, 64, 3), 40 * index, np.uint8), stamp)
        result = FrameResult(index, stamp, Odometry.origin(stamp), [], [], estimate)
        outputs.write(frame, result, None)
    outputs.close()
    video = cv2.VideoCapture(str(path))
    shades = []
    while True:
        ok, image = video.read()
        if not ok:
            break
        shades.append(round(float(image[5, 5].mean()) / 40))
    video.release()
    # frames due by each stamp at 10 fps: 1, 2, 5, 5 (+1: never fewer than once), 7, 91
    # (capped at 2 s: 20)
    assert shades == [0, 1, 2, 2, 2, 3, 4] + [5] * 20


@pytest.mark.parametrize("full", [False, True])
def test_a_video_that_stops_growing_is_an_error(tmp_path, monkeypatch, full):
    """OpenCV's writer says nothing when its writes fail (a full disk: here a video file
    that is /dev/full): the run learns of it within VIDEO_GROWTH_CHECK_BYTES of frames,
    while a video that grows is written on."""
    import os

    import numpy as np

    from follow import run as run_module
    from follow.pipeline import FrameResult
    from follow.types import Frame, Odometry, TargetEstimate, TargetStatus

    if full and not os.path.exists("/dev/full"):
        pytest.skip("no /dev/full on this system")
    path = tmp_path / "out.avi"
    if full:
        path.symlink_to("/dev/full")
    monkeypatch.setattr(run_module, "VIDEO_GROWTH_CHECK_BYTES", 2_000_000)
    outputs = run_module.Outputs({}, 10.0, video_path=path)
    estimate = TargetEstimate(TargetStatus.INITIAL, None, {}, 0.0)
    noise = np.random.default_rng(0).integers(0, 256, (48, 64, 3), dtype=np.uint8)

    def write_frames():
        for index in range(300):  # the canvas is 112x48: 16 kB a frame, 4.8 MB in all
            stamp = index / 10.0
            result = FrameResult(index, stamp, Odometry.origin(stamp), [], [], estimate)
            outputs.write(Frame(np.roll(noise, index, axis=1), stamp), result, None)

    if full:
        with pytest.raises(OSError, match="stopped growing at 0 bytes.*disk full"):
            write_frames()
    else:
        write_frames()
        outputs.close()
        assert path.stat().st_size > 1_000_000


def test_a_short_video_that_could_not_be_written_is_an_error_at_close(tmp_path):
    """Too short for the growth check: the closed video is read back, and one that cannot
    be (written to a full disk: /dev/full) is an error, not a run reported as recorded."""
    import os

    import numpy as np

    from follow.pipeline import FrameResult
    from follow.run import Outputs
    from follow.types import Frame, Odometry, TargetEstimate, TargetStatus

    if not os.path.exists("/dev/full"):
        pytest.skip("no /dev/full on this system")
    estimate = TargetEstimate(TargetStatus.INITIAL, None, {}, 0.0)
    for name, full in (("good.avi", False), ("full.avi", True)):
        path = tmp_path / name
        if full:
            path.symlink_to("/dev/full")
        outputs = Outputs({}, 10.0, video_path=path)
        for index in range(3):
            result = FrameResult(index, index / 10, Odometry.origin(index / 10), [], [], estimate)
            outputs.write(Frame(np.full((48, 64, 3), 50 * index, np.uint8), index / 10),
                          result, None)  # fmt: skip
        if full:
            with pytest.raises(OSError, match="full.avi was written but cannot be read back"):
                outputs.close()
        else:
            outputs.close()


def test_an_unreadable_video_does_not_hide_the_error_the_run_ends_with(tmp_path, caplog):
    """Closed on the way out of another error (a full disk that stopped the video's
    growth, a camera lost), the read-back failure is logged, not raised in its place."""
    import os

    import numpy as np

    from follow.pipeline import FrameResult
    from follow.run import Outputs
    from follow.types import Frame, Odometry, TargetEstimate, TargetStatus

    if not os.path.exists("/dev/full"):
        pytest.skip("no /dev/full on this system")
    path = tmp_path / "full.avi"
    path.symlink_to("/dev/full")
    outputs = Outputs({}, 10.0, video_path=path)
    result = FrameResult(0, 0.0, Odometry.origin(0.0), [], [],
                         TargetEstimate(TargetStatus.INITIAL, None, {}, 0.0))  # fmt: skip
    outputs.write(Frame(np.zeros((48, 64, 3), np.uint8), 0.0), result, None)
    with pytest.raises(ValueError, match="the camera is gone"):
        try:
            raise ValueError("the camera is gone")
        finally:
            outputs.close()
    assert "full.avi was written but cannot be read back" in caplog.text


def test_a_log_that_cannot_be_written_is_named(tmp_path):
    import os

    from follow.runlog import RunLogWriter

    (tmp_path / "a_file").write_text("x")  # a file where the log's folder should be
    with pytest.raises(OSError, match=r"cannot write the log .*missing\.jsonl"):
        RunLogWriter(tmp_path / "a_file" / "missing.jsonl", {})
    if not os.path.exists("/dev/full"):
        pytest.skip("no /dev/full on this system")
    path = tmp_path / "full.jsonl"
    path.symlink_to("/dev/full")
    with pytest.raises(OSError, match=r"cannot write the log .*full\.jsonl: No space"):
        RunLogWriter(path, {"run": "test"})


def test_output_folders_and_logs_that_cannot_be_used_are_named(tmp_path):
    """A bare `[Errno 2] No such file or directory` or `[Errno 17] File exists` said
    neither which option nor what the file was for."""
    from follow.run import Outputs
    from follow.runlog import read_run_log
    from follow.sim.demo import run_demo

    blocker = tmp_path / "a_file"
    blocker.write_text("x")
    with pytest.raises(OSError, match=r"cannot make the frames folder .*a_file/frames"):
        Outputs({}, 10.0, frames_dir=blocker / "frames")
    with pytest.raises(OSError, match=r"run log .*missing\.jsonl: No such file"):
        read_run_log(tmp_path / "missing.jsonl")
    with pytest.raises(OSError, match=r"--output .*a_file: cannot make the demo's folder"):
        run_demo(seconds=0.2, seed=0, identifier="channels", output=blocker, write_video=False)
