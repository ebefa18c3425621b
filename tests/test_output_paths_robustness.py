"""`follow run` and `follow demo` outputs on disks and names that fail: a name that is not
UTF-8 (OpenCV crashes on it), a folder that cannot be written in, a disk that fills
during the run (a video or a log cut short), an earlier demo's video left beside this
run's outputs, and an image folder's frame rate out of range."""

from __future__ import annotations

import argparse
import errno
import io
import os
import subprocess
import sys

import cv2
import numpy as np
import pytest

from follow.camera import CameraModel, CameraPose
from follow.pipeline import FrameResult
from follow.run import Outputs, check_output_paths
from follow.runlog import RunLogWriter, read_run_log
from follow.types import Frame, Odometry, TargetEstimate, TargetStatus

NOT_UTF8 = os.fsdecode(b"clip\xe9")  # a Latin-1 name, as Python holds it (a surrogate)


def _video(path, frames: int = 3) -> None:
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 10.0, (64, 48))
    for index in range(frames):
        writer.write(np.full((48, 64, 3), 40 * index, np.uint8))
    writer.release()


def _run_inputs(tmp_path):
    """A short video and a camera file for it, for `follow run`."""
    _video(tmp_path / "clip.avi")
    pose = CameraPose(height_m=1.0, pitch_rad=0.1)
    CameraModel.from_fov((64, 48), 60.0, pose).save(tmp_path / "cam.yaml")
    return ["run", str(tmp_path / "clip.avi"), "--camera", str(tmp_path / "cam.yaml")]


def _frame_and_result(index: int, stamp_s: float):
    estimate = TargetEstimate(TargetStatus.INITIAL, None, {}, 0.0)
    frame = Frame(np.full((48, 64, 3), (30 * index) % 256, np.uint8), stamp_s)
    return frame, FrameResult(index, stamp_s, Odometry.origin(stamp_s), [], [], estimate)


def _write_frames(outputs: Outputs, count: int) -> None:
    for index in range(count):
        outputs.write(*_frame_and_result(index, index / 10.0), None)


@pytest.mark.parametrize("option", ["source", "--output-video", "--frames-dir", "demo --output"])
def test_a_name_that_is_not_utf8_is_refused_not_a_crash(tmp_path, option):
    """OpenCV's binding crashes the process (a segmentation fault) on such a name: it is
    refused, naming the option, before any model loads or base connects."""
    argv = _run_inputs(tmp_path)
    if option == "source":
        os.rename(tmp_path / "clip.avi", tmp_path / f"{NOT_UTF8}.avi")
        argv[1] = str(tmp_path / f"{NOT_UTF8}.avi")
    elif option == "--output-video":
        argv += [option, str(tmp_path / f"{NOT_UTF8}.avi")]
    elif option == "--frames-dir":
        argv += [option, str(tmp_path / NOT_UTF8)]
    else:
        argv = ["demo", "--seconds", "0.2", "--identifier", "channels",
                "--output", str(tmp_path / NOT_UTF8)]  # fmt: skip
    done = subprocess.run([sys.executable, "-m", "follow.cli", *argv], capture_output=True,
                          text=True, errors="backslashreplace", timeout=300)  # fmt: skip
    assert done.returncode == 1, done.stderr[-2000:]
    name = option.split()[-1]
    assert f"{name} {tmp_path}/clip\\xe9" in done.stderr
    assert "is not a UTF-8 name; rename it" in done.stderr
    assert sorted(p.name for p in tmp_path.iterdir() if p.suffix != ".avi") == ["cam.yaml"]


def test_a_utf8_name_beyond_ascii_is_taken(tmp_path):
    args = argparse.Namespace(source=str(tmp_path / "in.avi"), camera=None, config=None,
                              replay=None, log=None, output_video=str(tmp_path / "vidéo.avi"),
                              frames_dir=str(tmp_path / "images é"))  # fmt: skip
    check_output_paths(args)


class _DiskFillsAfter:
    """OpenCV's video writer on a disk that fills after `kept` frames: the later writes
    are lost with no more than a warning, and the file closes as if whole."""

    def __init__(self, writer, kept: int):
        self._writer, self._left = writer, kept

    def isOpened(self) -> bool:  # noqa: N802 (OpenCV's name)
        return self._writer.isOpened()

    def write(self, image) -> None:
        if self._left > 0:
            self._writer.write(image)
            self._left -= 1

    def release(self) -> None:
        self._writer.release()


@pytest.mark.parametrize("suffix", [".avi", ".mp4"])
def test_a_video_cut_short_by_a_full_disk_is_an_error_not_a_success(tmp_path, monkeypatch,
                                                                   suffix):  # fmt: skip
    opencv_writer = cv2.VideoWriter
    monkeypatch.setattr(cv2, "VideoWriter", lambda *a: _DiskFillsAfter(opencv_writer(*a), 3))
    path = tmp_path / f"out{suffix}"
    outputs = Outputs({}, 10.0, video_path=path)
    _write_frames(outputs, 8)
    with pytest.raises(OSError, match=rf"video .*out\{suffix} holds 3 of the 8 frames written"):
        outputs.close()


def test_an_avi_whose_end_the_disk_took_is_an_error(tmp_path, monkeypatch):
    """A full disk takes the avi's last frames and its index: the file still opens, and
    its first frame reads back."""
    opencv_writer = cv2.VideoWriter

    class CutAtClose(_DiskFillsAfter):
        def release(self) -> None:
            super().release()
            data = path.read_bytes()
            path.write_bytes(data[: len(data) // 2])

    monkeypatch.setattr(cv2, "VideoWriter", lambda *a: CutAtClose(opencv_writer(*a), 8))
    path = tmp_path / "out.avi"
    outputs = Outputs({}, 10.0, video_path=path)
    _write_frames(outputs, 8)
    with pytest.raises(OSError, match=r"video .*out\.avi holds [1-7] of the 8 frames written"):
        outputs.close()


@pytest.mark.parametrize("suffix", [".avi", ".mp4"])
def test_a_whole_video_passes_with_its_repeated_frames(tmp_path, suffix):
    outputs = Outputs({}, 10.0, video_path=tmp_path / f"out{suffix}")
    for index, stamp_s in enumerate([0.0, 0.1, 0.5, 0.6]):  # 0.5: stands in 4 times
        outputs.write(*_frame_and_result(index, stamp_s), None)
    outputs.close()
    assert cv2.VideoCapture(str(tmp_path / f"out{suffix}")).get(cv2.CAP_PROP_FRAME_COUNT) == 7


class _FullDisk(io.RawIOBase):
    """A file on a full disk: every write fails."""

    def writable(self) -> bool:
        return True

    def write(self, data) -> int:
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))


def _on_full_disk(writer: RunLogWriter) -> None:
    writer._fh.close()
    writer._fh = io.TextIOWrapper(io.BufferedWriter(_FullDisk()), encoding="utf-8")


def test_a_log_that_cannot_be_flushed_at_close_is_named(tmp_path):
    writer = RunLogWriter(tmp_path / "run.jsonl", {"run": "test"})
    _on_full_disk(writer)
    writer._fh.write("a line the disk has no room for\n")
    with pytest.raises(OSError, match=r"cannot write the end of the log .*run\.jsonl: No space"):
        writer.close()
    assert writer._fh.closed


def test_a_full_disk_under_the_log_ends_the_run_with_the_named_error(tmp_path, caplog):
    """The frame's line fails, and so does the flush at close on the way out: the run
    ends with the first error, naming the log, not with a bare `[Errno 28]`."""
    outputs = Outputs({"run": "test"}, 10.0, log_path=tmp_path / "run.jsonl")
    _on_full_disk(outputs.log)
    with pytest.raises(OSError, match=r"cannot write the log .*run\.jsonl") as err:
        try:
            _write_frames(outputs, 1)
        finally:
            outputs.close()
    assert err.value.__cause__.errno == errno.ENOSPC
    assert outputs.log._fh.closed
    assert "cannot write the end of the log" in caplog.text  # the second failure, logged
    header, records = read_run_log(tmp_path / "run.jsonl")
    assert header["run"] == "test"


@pytest.mark.parametrize("option", ["output_video", "log", "frames_dir"])
def test_an_output_in_a_folder_that_cannot_be_written_in_is_refused_first(tmp_path, monkeypatch,
                                                                          option):  # fmt: skip
    read_only = tmp_path / "read_only"
    read_only.mkdir()
    real_access = os.access
    monkeypatch.setattr(os, "access", lambda path, mode, **kw: (
        str(path) != str(read_only) and real_access(path, mode, **kw)))  # fmt: skip
    names = {"output_video": "out.mp4", "log": "run.jsonl", "frames_dir": "frames"}
    values = dict(source=str(tmp_path / "in.avi"), camera=None, config=None, replay=None,
                  output_video=None, log=None, frames_dir=None)  # fmt: skip
    values[option] = str(read_only / names[option])
    flag = "--" + option.replace("_", "-")
    with pytest.raises(OSError, match=rf"\({flag}\): .*read_only is not a folder that can be"):
        check_output_paths(argparse.Namespace(**values))


def test_a_video_writer_that_does_not_open_is_named_with_its_size_and_rate(tmp_path, caplog):
    outputs = Outputs({}, 10.0, video_path=tmp_path / "gone" / "out.avi")
    with pytest.raises(OSError, match=r"cannot write video .*out\.avi \(112x48 at 10 fps\)"):
        _write_frames(outputs, 1)
    outputs.close()  # nothing was written: nothing to report as unreadable
    assert "cannot be read back" not in caplog.text


def test_a_demo_without_video_lists_and_leaves_only_its_own_outputs(tmp_path, caplog):
    import logging

    from follow.sim.demo import run_demo

    caplog.set_level(logging.INFO, logger="follow.sim.demo")
    (tmp_path / "demo.mp4").write_bytes(b"an earlier run's video")
    summary = run_demo(seconds=0.2, seed=0, identifier="channels", output=tmp_path,
                       write_video=False)  # fmt: skip
    assert [os.path.basename(p) for p in summary["outputs"]] == ["demo_top_down.png",
                                                                 "demo.jsonl"]  # fmt: skip
    assert sorted(p.name for p in tmp_path.iterdir()) == ["demo.jsonl", "demo_top_down.png"]
    assert f"removed {tmp_path / 'demo.mp4'}, an earlier run's video" in caplog.text


@pytest.mark.parametrize("fps", ["1e-300", "0.5", "241", "1e300"])
def test_a_folder_rate_outside_the_trusted_range_is_refused_by_name(tmp_path, capsys, fps):
    from follow.cli import main

    with pytest.raises(SystemExit) as exit_:
        main(["run", str(tmp_path), "--camera", "cam.yaml", "--folder-fps", fps])
    assert exit_.value.code == 2
    assert f"argument --folder-fps: expected a number from 1 to 240, got '{fps}'" in (
        capsys.readouterr().err)  # fmt: skip
