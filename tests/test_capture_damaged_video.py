"""A video file's damaged stretch (failed reads before the frame count its header announces)
is skipped whatever its length; the end of the file still ends the reading at once."""

import logging

import cv2
import numpy as np
import pytest

from follow.capture import FrameSource
from follow.cli_args import MAX_UNDECODABLE_RUN


def mjpeg_video(path, frames: int = 100, damaged: range = range(0)):
    """A 10 fps MJPEG AVI of `frames` frames whose frames in `damaged` cannot be decoded:
    each one's JPEG data zeroed between its markers, the AVI's chunks left whole (so that
    every damaged frame is one failed read, as OpenCV reports a damaged MJPEG frame)."""
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 10.0, (64, 48))
    for i in range(frames):
        image = np.full((48, 64, 3), 90, np.uint8)
        cv2.rectangle(image, (5 + i % 40, 5), (20 + i % 40, 40), (30, 60, 200), -1)
        writer.write(image)
    writer.release()
    data = bytearray(path.read_bytes())
    starts = [i for i in range(len(data) - 1) if data[i : i + 2] == b"\xff\xd8"]
    assert len(starts) == frames  # one JPEG per frame
    for k in damaged:
        end = data.index(b"\xff\xd9", starts[k])
        data[starts[k] + 2 : end] = bytes(end - starts[k] - 2)
    path.write_bytes(bytes(data))
    return path


def counted_reads(monkeypatch) -> list:
    """The captures FrameSource opens from now on, each counting its read() calls."""
    real, opened = cv2.VideoCapture, []

    class Counting:
        def __init__(self, *args):
            self.cap, self.reads = real(*args), 0
            opened.append(self)

        def read(self):
            self.reads += 1
            return self.cap.read()

        def __getattr__(self, name):
            return getattr(self.cap, name)

    monkeypatch.setattr(cv2, "VideoCapture", Counting)
    return opened


def test_a_damaged_stretch_longer_than_the_run_bound_does_not_end_the_video(tmp_path, caplog):
    damaged = range(30, 70)  # a stretch in the middle of the recording
    assert len(damaged) > MAX_UNDECODABLE_RUN
    path = mjpeg_video(tmp_path / "v.avi", 100, damaged)
    with caplog.at_level(logging.WARNING, logger="follow.capture"):
        frames = list(FrameSource(str(path)))
    assert len(frames) == 60  # the 30 frames after the stretch are not lost
    assert [f.stamp_s for f in frames[29:31]] == pytest.approx([2.9, 7.0])  # its gap kept
    assert "frames 30-69 cannot be decoded: skipped" in caplog.text
    assert "ended after" not in caplog.text  # the file was read to its end


def test_a_whole_video_ends_at_its_first_failed_read_past_its_frames(tmp_path, monkeypatch):
    path = mjpeg_video(tmp_path / "v.avi", 100)
    opened = counted_reads(monkeypatch)
    assert len(list(FrameSource(str(path)))) == 100
    assert opened[0].reads == 101  # no walk at the real end


def test_a_video_cut_short_is_walked_no_further_than_its_announced_frames(
    tmp_path, monkeypatch, caplog
):
    """Its failing reads at the end cannot be told from a damaged stretch's: the header's
    count ends them, and the file is said to be cut short, as before."""
    path = mjpeg_video(tmp_path / "v.avi", 100)
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    opened = counted_reads(monkeypatch)
    with caplog.at_level(logging.WARNING, logger="follow.capture"):
        read = len(list(FrameSource(str(path))))
    assert 0 < read < 100
    assert opened[0].reads <= 100  # one failed read a missing frame, the last announced one
    assert f"ended after {read} of the 100 frames its header announces" in caplog.text


class _ScriptedFile:
    """An OpenCV capture of a file: `script` holds its reads in order, an image or None
    (a failed read: a damaged frame); every read after them fails (its end). `count`:
    the frame count its header announces (0: none)."""

    def __init__(self, script, count: float):
        self.script, self.count, self.reads = list(script), count, 0

    def isOpened(self):
        return True

    def get(self, prop):
        if prop == cv2.CAP_PROP_FPS:
            return 10.0
        return self.count if prop == cv2.CAP_PROP_FRAME_COUNT else 0.0

    def read(self):
        self.reads += 1
        if self.reads > len(self.script) or self.script[self.reads - 1] is None:
            return False, None
        return True, self.script[self.reads - 1]

    def release(self):
        pass


def _script(good_before: int, damaged: int, good_after: int) -> list:
    image = np.full((24, 32, 3), 90, np.uint8)
    return [image] * good_before + [None] * damaged + [image] * good_after


def _uncounted_file(tmp_path, monkeypatch, script: list):
    """A file whose capture reads `script` and announces no frame count (a raw stream)."""
    path = tmp_path / "v.mjpeg"
    path.write_bytes(bytes(1000))
    capture = _ScriptedFile(script, count=0)
    monkeypatch.setattr(cv2, "VideoCapture", lambda *a: capture)
    return path, capture


def test_a_video_without_a_frame_count_skips_a_short_damaged_run_and_says_where_it_ended(
    tmp_path, monkeypatch, caplog
):
    path, capture = _uncounted_file(tmp_path, monkeypatch, _script(5, 10, 5))
    with caplog.at_level(logging.WARNING, logger="follow.capture"):
        frames = list(FrameSource(str(path)))
    assert len(frames) == 10  # the 5 after the damaged run are read
    assert "frames 5-14 cannot be decoded: skipped" in caplog.text
    assert capture.reads == 20 + MAX_UNDECODABLE_RUN + 1  # the end: the run bound, no more
    assert f"source {path}: the file announces no frame count: it ended at frame 20" in (
        caplog.text
    )


def test_a_whole_video_without_a_frame_count_ends_without_a_warning(
    tmp_path, monkeypatch, caplog
):
    """A raw stream that announces no count and has no damaged frame ends as any file:
    where it ended is information, not a warning repeated at the end of every such file."""
    path, capture = _uncounted_file(tmp_path, monkeypatch, _script(12, 0, 0))
    with caplog.at_level(logging.INFO, logger="follow.capture"):
        frames = list(FrameSource(str(path)))
    assert len(frames) == 12
    said = [r for r in caplog.records if "announces no frame count" in r.getMessage()]
    assert [r.levelno for r in said] == [logging.INFO]


def test_an_absurd_frame_count_does_not_make_the_end_of_the_file_a_long_walk(
    tmp_path, monkeypatch, caplog
):
    """A damaged header's count (a billion frames in 1000 bytes) bounds nothing: the run
    bound ends the reading, and the file is said to end before that count."""
    path = tmp_path / "v.avi"
    path.write_bytes(bytes(1000))
    capture = _ScriptedFile(_script(5, 0, 0), count=1e9)
    monkeypatch.setattr(cv2, "VideoCapture", lambda *a: capture)
    with caplog.at_level(logging.WARNING, logger="follow.capture"):
        assert len(list(FrameSource(str(path)))) == 5
    assert capture.reads == 5 + MAX_UNDECODABLE_RUN + 1
    assert "ended after 5 of the 1000000000 frames its header announces" in caplog.text
