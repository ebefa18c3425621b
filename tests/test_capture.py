import itertools
import threading
from types import SimpleNamespace

import cv2
import numpy as np
import pytest

from follow.capture import FrameSource, LatestSlot, SourceError, played_at_own_stamps
from follow.types import Frame


def test_latest_slot_keeps_only_the_newest_and_counts_drops():
    slot = LatestSlot()
    for i in range(5):
        slot.put(i)
    assert slot.get(timeout_s=0.1) == 4
    assert slot.dropped == 4
    assert slot.get(timeout_s=0.05) is None  # nothing new
    assert slot.peek() == 4


def test_latest_slot_wakes_a_waiting_reader_and_closes():
    slot = LatestSlot()
    got = []
    reader = threading.Thread(target=lambda: got.append(slot.get(timeout_s=2.0)))
    reader.start()
    slot.put("frame")
    reader.join(1.0)
    assert got == ["frame"]
    slot.close()
    assert slot.get(timeout_s=1.0) is None and slot.closed


def test_folder_source_skips_unreadable_images(tmp_path, caplog):
    for i in range(3):
        cv2.imwrite(str(tmp_path / f"{i:03d}.png"), np.full((20, 30, 3), i * 40, np.uint8))
    (tmp_path / "001b.png").write_bytes(b"not a png")
    frames = list(FrameSource(str(tmp_path), folder_fps=10.0))
    assert [int(f.image[0, 0, 0]) for f in frames] == [0, 40, 80]
    assert [f.stamp_s for f in frames] == pytest.approx([0.0, 0.1, 0.3])
    assert "001b.png" in caplog.text


def test_an_empty_image_file_in_a_folder_is_skipped_as_empty(tmp_path, caplog):
    cv2.imwrite(str(tmp_path / "000.jpg"), np.full((20, 30, 3), 90, np.uint8))
    (tmp_path / "001.jpg").write_bytes(b"")
    frames = list(FrameSource(str(tmp_path), folder_fps=10.0))
    assert len(frames) == 1
    assert "001.jpg: an empty file" in caplog.text and "cut short" not in caplog.text


def test_an_entry_of_a_folder_that_cannot_be_read_is_skipped_not_fatal(tmp_path, caplog):
    """A dangling link or a folder named like an image: the rest of the run goes on."""
    for i in (0, 3):
        cv2.imwrite(str(tmp_path / f"{i:03d}.png"), np.full((20, 30, 3), 40 * i, np.uint8))
    (tmp_path / "001.png").symlink_to(tmp_path / "gone.png")
    (tmp_path / "002.png").mkdir()
    frames = list(FrameSource(str(tmp_path), folder_fps=10.0))
    assert [int(f.image[0, 0, 0]) for f in frames] == [0, 120]
    assert "001.png: cannot be read" in caplog.text and "002.png: cannot be read" in caplog.text


def test_video_source_reads_frames_with_file_timestamps(tmp_path):
    path = tmp_path / "v.avi"
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 5.0, (32, 24))
    for i in range(4):
        writer.write(np.full((24, 32, 3), 60 * i, np.uint8))
    writer.release()
    frames = list(FrameSource(str(path)))
    assert len(frames) == 4
    assert frames[-1].stamp_s == pytest.approx(0.6)


def test_bad_sources_are_named(tmp_path):
    with pytest.raises(SourceError, match="no such file"):
        FrameSource(str(tmp_path / "missing.avi"))
    with pytest.raises(SourceError, match="holds no images"):
        FrameSource(str(tmp_path))
    bad = tmp_path / "bad.avi"
    bad.write_bytes(b"garbage" * 100)
    with pytest.raises(SourceError, match="cannot be opened"):
        FrameSource(str(bad))


def test_a_camera_index_that_cannot_be_opened_is_named_as_one(monkeypatch):
    """Too large for OpenCV's C int, or no such device: the message says it is a camera
    index (not a file OpenCV cannot read) and never a traceback from inside OpenCV."""
    with pytest.raises(SourceError, match="no camera index is that large"):
        FrameSource("99999999999")

    class NoDevice:
        def __init__(self, index):
            self.index = index

        def isOpened(self):
            return False

    monkeypatch.setattr(cv2, "VideoCapture", NoDevice)
    with pytest.raises(SourceError, match="no camera at index 7 can be opened"):
        FrameSource("7")


def test_an_empty_source_is_refused_not_read_as_the_current_folder():
    with pytest.raises(SourceError, match="source is empty"):
        FrameSource("")


def test_a_jpeg_cut_short_in_a_folder_is_skipped_not_used_half_decoded(tmp_path, caplog):
    rng = np.random.default_rng(0)
    for name in ("a", "b", "c"):
        image = rng.integers(0, 255, (48, 64, 3), dtype=np.uint8)
        assert cv2.imwrite(str(tmp_path / f"{name}.jpg"), image)
    whole = (tmp_path / "b.jpg").read_bytes()
    (tmp_path / "b.jpg").write_bytes(whole[: len(whole) // 2])  # cut short
    frames = list(FrameSource(str(tmp_path)))
    assert len(frames) == 2 and "b.jpg: a JPEG cut short" in caplog.text


class _LiveCamera30Fps:
    """What every fake live camera here answers: open, 30 fps."""

    def isOpened(self):
        return True

    def get(self, prop):
        return 30.0


class _UnpluggedCamera(_LiveCamera30Fps):
    """A camera that delivers `frames` images (each its own, as a sensor's noise makes
    them), then fails every read (unplugged)."""

    def __init__(self, frames: int):
        self.frames = frames

    def read(self):
        if self.frames == 0:
            return False, None
        self.frames -= 1
        return True, np.full((24, 32, 3), self.frames, np.uint8)

    def release(self):
        pass


def test_a_camera_that_stops_delivering_frames_is_an_error_not_the_end_of_the_run(
    monkeypatch,
):
    monkeypatch.setattr(cv2, "VideoCapture", lambda *a: _UnpluggedCamera(3))
    source = FrameSource("0")
    frames = iter(source)
    assert len([next(frames) for _ in range(3)]) == 3
    with pytest.raises(SourceError, match="source 0: the camera delivered no frame"):
        next(frames)


class _FrozenCamera(_LiveCamera30Fps):
    """A live camera whose driver hands back its last image again for `frozen` reads
    after the first two images, then delivers new ones."""

    def __init__(self, frozen: int):
        self.reads, self.frozen = 0, frozen

    def read(self):
        self.reads += 1
        fresh = min(self.reads, 2) + max(0, self.reads - 2 - self.frozen)
        return True, np.full((24, 32, 3), fresh, np.uint8)  # the same buffer's contents

    def release(self):
        pass


def test_a_frozen_camera_repeating_its_last_image_delivers_nothing_new(monkeypatch, caplog):
    """The same image again is a frozen driver, not a new view: stamped now it would pass
    old news for fresh. Its repeats are dropped (so a freeze is a camera that delivers
    nothing, which stops the base), and frames come again once it does."""
    monkeypatch.setattr(cv2, "VideoCapture", lambda *a: _FrozenCamera(frozen=5))
    frames = iter(FrameSource("0"))
    images = [int(next(frames).image[0, 0, 0]) for _ in range(4)]
    assert images == [1, 2, 3, 4]  # the five repeats of image 2 never came out
    assert "the same image again" in caplog.text


class _QueueingCamera(_LiveCamera30Fps):
    """A 30 fps camera on a fake clock whose driver queues `queued` frames while nobody
    reads: a grab of a queued frame returns at once, a grab of a new one waits for the
    sensor (a frame period). Each image carries the time it was captured, in ms."""

    def __init__(self, clock, queued: int):
        self.clock, self.queued = clock, queued
        self._grabbed = None

    def grab(self):
        if self.queued:  # captured when the pause began
            self.queued -= 1
            self._grabbed = 0.0
        else:
            self.clock.now_s += 1 / 30
            self._grabbed = self.clock.now_s
        return True

    def retrieve(self):
        return True, np.full((24, 32, 3), int(self._grabbed * 1000) % 256, np.uint8)

    def read(self):
        self.grab()
        return self.retrieve()

    def release(self):
        pass


def test_frames_a_camera_queued_while_nobody_read_are_dropped_not_stamped_as_new(monkeypatch):
    """The first frame is read for its size, then the models load for seconds while the
    driver queues frames; stamped when read, those would pass seconds-old views of the
    scene off as new. After the pause the first frame handed over is one the sensor
    captured after it."""
    import follow.capture as capture

    clock = SimpleNamespace(now_s=0.0)
    monkeypatch.setattr(capture.time, "monotonic", lambda: clock.now_s)
    camera = _QueueingCamera(clock, queued=0)
    monkeypatch.setattr(cv2, "VideoCapture", lambda *a: camera)
    frames = iter(FrameSource("0"))
    next(frames)
    clock.now_s += 3.0  # the models load; the driver fills its four buffers
    camera.queued = 4
    after_pause = next(frames)
    captured_ms = int(clock.now_s * 1000) % 256
    assert int(after_pause.image[0, 0, 0]) == captured_ms != 0  # not a queued frame
    assert camera.queued == 0
    # reading on without a pause drops nothing: each frame is the next one captured
    camera.queued = 1  # (a frame the driver had ready: taken as it is, no pause)
    assert int(next(frames).image[0, 0, 0]) == 0


def test_an_unusable_image_in_a_folder_is_skipped_by_name(tmp_path, caplog):
    for i in range(3):
        cv2.imwrite(str(tmp_path / f"{i:03d}.png"), np.full((20, 30, 3), i * 40, np.uint8))
    cv2.imwrite(str(tmp_path / "001b.png"), np.zeros((4, 4, 3), np.uint8))  # a thumbnail
    frames = list(FrameSource(str(tmp_path)))
    assert [int(f.image[0, 0, 0]) for f in frames] == [0, 40, 80]
    assert "001b.png" in caplog.text and "too small" in caplog.text


def damaged_mjpeg(path, frames: int = 30, damaged: int = 15):
    """A 10 fps MJPEG video of `frames` frames whose frame `damaged` cannot be decoded."""
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 10.0, (64, 48))
    for i in range(frames):
        image = np.full((48, 64, 3), 90, np.uint8)
        cv2.rectangle(image, (5 + i, 5), (20 + i, 40), (30, 60, 200), -1)
        writer.write(image)
    writer.release()
    data = bytearray(path.read_bytes())
    starts = [i for i in range(len(data) - 1) if data[i : i + 2] == b"\xff\xd8"]
    assert len(starts) == frames  # one JPEG per frame
    data[starts[damaged] + 2 : starts[damaged] + 400] = bytes(398)  # its picture destroyed
    path.write_bytes(bytes(data))
    return path


def test_an_undecodable_frame_in_a_video_is_skipped_not_the_end_of_the_file(tmp_path, caplog):
    path = damaged_mjpeg(tmp_path / "v.avi")
    frames = list(FrameSource(str(path)))
    assert len(frames) == 29  # the frames after the damaged one are not lost
    stamps = [f.stamp_s for f in frames]
    assert stamps[14:16] == pytest.approx([1.4, 1.6])  # the gap keeps its time
    assert "frame 15" in caplog.text and "cannot be decoded" in caplog.text


def test_folder_frames_numbered_without_leading_zeros_play_in_number_order(tmp_path):
    # frame_2 before frame_10: sorted as text, frame_10 would come second, and every
    # person would jump back and forth between frames 1-9 and 10-12.
    for i in range(1, 13):
        cv2.imwrite(str(tmp_path / f"frame_{i}.png"), np.full((20, 30, 3), i * 10, np.uint8))
    frames = list(FrameSource(str(tmp_path), folder_fps=10.0))
    assert [int(f.image[0, 0, 0]) // 10 for f in frames] == list(range(1, 13))


def test_folder_frames_named_by_their_time_stamps_play_in_time_order(tmp_path):
    """Names written as `f"{time.time()}.png"`: the fractions' digits compared as whole
    numbers played .5 after .25, frames out of order without a word."""
    stamps = [1700000000 + k / 4 for k in range(12)]  # .0, .25, .5, .75, ...
    for k, stamp in enumerate(stamps):
        cv2.imwrite(str(tmp_path / f"{stamp}.png"), np.full((20, 30, 3), k * 10, np.uint8))
    frames = list(FrameSource(str(tmp_path), folder_fps=10.0))
    assert [int(f.image[0, 0, 0]) // 10 for f in frames] == list(range(12))


def test_a_camera_named_by_its_device_file_is_live_not_a_video_file(monkeypatch):
    # /dev/video0 or a /dev/v4l/by-id/... link: a camera, whose frames are stamped as they
    # come and whose failing reads are a lost camera, not the end of a file.
    device = "/dev/null"  # a character device, as a camera's node is
    monkeypatch.setattr(cv2, "VideoCapture", lambda *a: _UnpluggedCamera(3))
    source = FrameSource(device)
    assert source.live
    frames = iter(source)
    assert len([next(frames) for _ in range(3)]) == 3
    with pytest.raises(SourceError, match="the camera delivered no frame"):
        next(frames)


class _ScriptedCapture:
    """An OpenCV capture that delivers the given images, then ends (a file) or fails (a
    camera); `positions_ms` are what CAP_PROP_POS_MSEC reports after each read."""

    def __init__(self, images, fps: float = 10.0, positions_ms=None):
        self.images = list(images)
        self.fps = fps
        self.positions_ms = list(positions_ms) if positions_ms is not None else None
        self.read_count = 0

    def isOpened(self):
        return True

    def get(self, prop):
        if prop == cv2.CAP_PROP_FPS:
            return self.fps
        if prop == cv2.CAP_PROP_FRAME_COUNT:
            return float(len(self.images))
        if prop == cv2.CAP_PROP_POS_MSEC and self.positions_ms is not None:
            return self.positions_ms[self.read_count - 1]
        return 0.0

    def read(self):
        if self.read_count >= len(self.images):
            return False, None
        self.read_count += 1
        return True, self.images[self.read_count - 1]

    def grab(self):
        self._grabbed = self.read()
        return self._grabbed[0]

    def retrieve(self):
        return self._grabbed

    def release(self):
        pass


def test_single_channel_frames_of_a_pipeline_are_converted_to_bgr_not_skipped(monkeypatch, caplog):
    # e.g. "... ! video/x-raw,format=GRAY8 ! appsink" or a mono USB camera: OpenCV hands
    # over 2-D frames, as a bag's mono8 images are, and they are used as grey BGR frames.
    grey = [np.full((24, 32), 40 * i, np.uint8) for i in range(3)]
    monkeypatch.setattr(cv2, "VideoCapture", lambda *a: _ScriptedCapture(grey))
    frames = iter(FrameSource("v4l2src ! video/x-raw,format=GRAY8 ! appsink"))
    got = [next(frames) for _ in range(3)]
    assert [f.image.shape for f in got] == [(24, 32, 3)] * 3
    assert [int(f.image[5, 5, 2]) for f in got] == [0, 40, 80]
    assert "skipping" not in caplog.text


def test_a_single_channel_video_file_is_read_as_bgr_and_odd_frames_still_skipped(
    tmp_path, monkeypatch, caplog
):
    path = tmp_path / "mono.avi"
    path.write_bytes(b"")
    images = [
        np.full((24, 32), 10, np.uint8),
        np.full((24, 32), 10, np.float32),  # not uint8: still refused
        np.full((24, 32, 2), 10, np.uint8),  # two channels: still refused
        np.full((4, 4), 10, np.uint8),  # too small: still refused, after conversion
        np.zeros((0, 0), np.uint8),  # empty: refused, not handed to cvtColor
        np.full((24, 32), 30, np.uint8),
    ]
    monkeypatch.setattr(cv2, "VideoCapture", lambda *a: _ScriptedCapture(images))
    frames = list(FrameSource(str(path)))
    assert [(f.image.shape, int(f.image[0, 0, 1])) for f in frames] == [
        ((24, 32, 3), 10),
        ((24, 32, 3), 30),
    ]
    assert caplog.text.count("skipping frame") == 4


@pytest.mark.parametrize(
    "layout, image, grey",
    [
        ("GRAY16_LE", np.full((24, 32), 0x5A17, np.uint16), 0x5A),  # a thermal camera
        ("BGR 16-bit", np.full((24, 32, 3), 0x7F00, np.uint16), 0x7F),
        ("BGRA", np.full((24, 32, 4), 90, np.uint8), 90),
        ("HxWx1", np.full((24, 32, 1), 60, np.uint8), 60),
        ("HxWx1 16-bit", np.full((24, 32, 1), 0x3300, np.uint16), 0x33),
    ],
)
def test_16_bit_bgra_and_hxwx1_frames_are_converted_to_8_bit_bgr_not_skipped(
    monkeypatch, caplog, layout, image, grey
):
    # e.g. "... ! video/x-raw,format=GRAY16_LE ! appsink" (a thermal or depth camera): each
    # frame skipped, a live source would read for ever and the run never start.
    images = [image + i for i in range(3)]
    monkeypatch.setattr(cv2, "VideoCapture", lambda *a: _ScriptedCapture(images))
    frames = iter(FrameSource("v4l2src ! appsink"))
    got = [next(frames) for _ in range(3)]
    assert [f.image.shape for f in got] == [(24, 32, 3)] * 3, layout
    assert int(got[0].image[5, 5, 2]) == grey
    assert "skipping" not in caplog.text


def test_a_live_source_whose_frames_are_all_unusable_is_an_error_naming_their_layout(
    monkeypatch, caplog
):
    # Skipped one by one, a camera's would be read for ever before the stall watchdog (it
    # starts at the first frame), the CPU spinning and the log flooded.
    good = np.full((24, 32, 3), 10, np.uint8)
    odd = np.zeros((24, 32, 2), np.uint8)
    images = [odd] * 9 + [good] + [odd] * 9 + [good + 1] + [odd] * 100
    monkeypatch.setattr(cv2, "VideoCapture", lambda *a: _ScriptedCapture(images))
    frames = iter(FrameSource("v4l2src ! video/x-raw,format=GRAY8 ! appsink"))
    assert [int(next(frames).image[0, 0, 0]) for _ in range(2)] == [10, 11]  # 9 in a row: skipped
    with pytest.raises(SourceError, match=r"10 frames in a row cannot be used, the last a "
                       r"24x32x2 uint8 array \(frame image: expected an HxWx3"):  # fmt: skip
        next(frames)
    assert caplog.text.count("skipping frame") == 9 + 9 + 9


def test_a_file_whose_frames_are_all_unusable_is_refused_by_their_dtype(tmp_path, monkeypatch):
    path = tmp_path / "float.avi"
    path.write_bytes(b"")
    images = [np.zeros((24, 32, 3), np.float32)] * 30
    monkeypatch.setattr(cv2, "VideoCapture", lambda *a: _ScriptedCapture(images))
    with pytest.raises(SourceError, match="the last a 24x32x3 float32 array .*dtype uint8"):
        list(FrameSource(str(path)))


def _write_vfr_mp4(path, times_ms):
    """An MP4 whose frames are shown at `times_ms` (variable frame rate, as a phone
    records), written with PyAV; frame i is filled with grey 20 * i."""
    av = pytest.importorskip("av")
    from fractions import Fraction

    with av.open(str(path), "w") as out:
        stream = out.add_stream("mpeg4", rate=10)
        stream.width, stream.height, stream.pix_fmt = 64, 48, "yuv420p"
        stream.time_base = stream.codec_context.time_base = Fraction(1, 1000)
        for i, t in enumerate(times_ms):
            frame = av.VideoFrame.from_ndarray(np.full((48, 64, 3), 20 * i, np.uint8), "bgr24")
            frame.pts, frame.time_base = t, Fraction(1, 1000)
            for packet in stream.encode(frame):
                out.mux(packet)
        for packet in stream.encode():
            out.mux(packet)


def test_a_variable_frame_rate_video_is_stamped_with_its_presentation_times(tmp_path, caplog):
    # A phone's recording: frames 50-450 ms apart. From index / fps (the container's
    # average rate), every stamp after the first would be off, and with them the
    # tracker's velocities and the controller's timing.
    times_ms = [0, 100, 150, 400, 433, 466, 900, 1000, 1050, 1300, 1400, 1500]
    path = tmp_path / "vfr.mp4"
    _write_vfr_mp4(path, times_ms)
    caplog.set_level("INFO", logger="follow.capture")
    frames = list(FrameSource(str(path)))
    assert [f.stamp_s for f in frames] == pytest.approx([t / 1000 for t in times_ms], abs=1e-6)
    assert "presentation times" in caplog.text


def test_a_constant_rate_video_keeps_the_stamps_of_its_frame_rate(tmp_path):
    for suffix, fourcc in ((".avi", "MJPG"), (".mp4", "mp4v"), (".mkv", "XVID")):
        path = tmp_path / f"v{suffix}"
        writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*fourcc), 7.0, (32, 24))
        for i in range(20):
            writer.write(np.full((24, 32, 3), 10 * i, np.uint8))
        writer.release()
        stamps = [f.stamp_s for f in FrameSource(str(path))]
        assert stamps == [i / 7.0 for i in range(20)], suffix  # exactly: no figure moves


def _fake_file(tmp_path, monkeypatch, positions_ms, fps=10.0):
    path = tmp_path / "fake.avi"
    path.write_bytes(b"")
    images = [np.full((24, 32, 3), i, np.uint8) for i in range(len(positions_ms))]
    capture = _ScriptedCapture(images, fps=fps, positions_ms=positions_ms)
    monkeypatch.setattr(cv2, "VideoCapture", lambda *a: capture)
    return str(path)


def test_a_file_without_presentation_times_is_stamped_from_its_frame_rate(
    tmp_path, monkeypatch, caplog
):
    caplog.set_level("INFO", logger="follow.capture")
    source = _fake_file(tmp_path, monkeypatch, [0.0] * 5)
    assert [f.stamp_s for f in FrameSource(source)] == [i / 10.0 for i in range(5)]
    assert caplog.text.count("frame rate") == 1 and "presentation times" in caplog.text


def test_presentation_times_offset_by_the_decoder_and_missing_at_the_end_keep_the_frame_rate(
    tmp_path, monkeypatch, caplog
):
    # What OpenCV reports for an H.264 AVI (PETS 2009 View_001): each frame's time is
    # that of the packet two frames on, and the frames drained at the end have none.
    caplog.set_level("INFO", logger="follow.capture")
    positions = [(i + 2) * 100.00000000000001 for i in range(8)] + [0.0, 0.0]
    source = _fake_file(tmp_path, monkeypatch, positions)
    assert [f.stamp_s for f in FrameSource(source)] == [i / 10.0 for i in range(10)]
    assert "WARNING" not in caplog.text


@pytest.mark.parametrize("bad", [150.0, 300.0, float("nan"), float("inf"), -5.0])
def test_presentation_times_that_go_wrong_midway_give_way_to_the_frame_rate(
    tmp_path, monkeypatch, caplog, bad
):
    caplog.set_level("INFO", logger="follow.capture")
    positions = [0.0, 50.0, 300.0, bad, 400.0, 450.0]  # going back, stalling, not finite
    source = _fake_file(tmp_path, monkeypatch, positions)
    stamps = [f.stamp_s for f in FrameSource(source)]
    # the file's times while they hold, then on from the last one at the frame rate
    assert stamps == pytest.approx([0.0, 0.05, 0.3, 0.4, 0.5, 0.6])
    assert caplog.text.count("frame rate") == 1 and "frame 3" in caplog.text


def test_pets_video_stamps_are_those_of_its_frame_rate(data_path):
    # The PETS evaluations and the bag tests stamp PETS frames through FrameSource.
    path = str(data_path("pets2009_s2l1/View_001.avi"))
    source = FrameSource(path)
    try:
        stamps = [f.stamp_s for f in itertools.islice(source, 60)]
    finally:
        source.close()
    assert source.fps == 10.0
    assert stamps == [i / 10.0 for i in range(60)]


def test_an_image_folder_plays_at_the_rate_given_to_follow_run(tmp_path, monkeypatch):
    from follow import run as run_module
    from follow.camera import CameraModel, CameraPose
    from follow.capture import open_source
    from follow.cli import main

    folder = tmp_path / "frames"
    folder.mkdir()
    for i in range(3):
        cv2.imwrite(str(folder / f"{i:03d}.png"), np.full((48, 64, 3), i * 40, np.uint8))
    CameraModel.from_fov((64, 48), 70.0, CameraPose(height_m=1.0)).save(tmp_path / "cam.yaml")
    stamps = {}

    def opened(*args, **kwargs):  # the run's source, read and then ended
        source = open_source(*args, **kwargs)
        stamps[kwargs.get("folder_fps")] = [f.stamp_s for f in source]
        raise SourceError("read")

    monkeypatch.setattr(run_module, "open_source", opened)
    for given in ([], ["--folder-fps", "5"]):
        assert main(["run", str(folder), "--camera", str(tmp_path / "cam.yaml"), *given]) == 1
    assert stamps == {15.0: [0.0, 1 / 15, 2 / 15], 5.0: [0.0, 0.2, 0.4]}


class _FakeTime:
    """A clock that only sleeps move, and the sleeps asked of it."""

    def __init__(self, start_s: float = 100.0):
        self.now_s, self.sleeps = start_s, []

    def clock(self) -> float:
        return self.now_s

    def sleep(self, seconds: float) -> None:
        self.sleeps.append(seconds)
        self.now_s += seconds


def test_a_file_played_as_recorded_waits_for_each_frames_own_stamp(tmp_path):
    # The phone video of the test above: `--realtime` and `--mavlink` runs play it with
    # its own gaps (250 ms, 434 ms), not on an even grid of the container's rate.
    times_ms = [0, 100, 150, 400, 433, 466, 900, 1000, 1050, 1300, 1400, 1500]
    path = tmp_path / "vfr.mp4"
    _write_vfr_mp4(path, times_ms)
    fake = _FakeTime()
    played = played_at_own_stamps(FrameSource(str(path)), fake.clock, fake.sleep)
    due_s = [fake.clock() - 100.0 for _ in played]
    assert due_s == pytest.approx([t / 1000 for t in times_ms], abs=1e-6)


def test_a_late_frame_is_not_held_back_and_the_next_keeps_its_time():
    fake = _FakeTime()
    image = np.zeros((24, 32, 3), np.uint8)
    played = []
    for frame in played_at_own_stamps(
        [Frame(image, 5.0), Frame(image, 5.1), Frame(image, 5.2), Frame(image, 5.3)],
        fake.clock, fake.sleep,
    ):  # fmt: skip
        played.append(round(fake.clock() - 100.0, 6))
        if frame.stamp_s == 5.1:
            fake.now_s += 0.25  # a slow consumer: frame 5.2 is already late
    assert played == [0.0, 0.1, 0.35, 0.35]
    assert all(s > 0 for s in fake.sleeps)


def test_a_folder_rate_given_for_a_video_is_warned_of_not_ignored_in_silence(
    tmp_path, monkeypatch, caplog
):
    from follow import run as run_module
    from follow.camera import CameraModel, CameraPose
    from follow.cli import main

    video = tmp_path / "v.avi"
    writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"MJPG"), 10.0, (64, 48))
    writer.write(np.zeros((48, 64, 3), np.uint8))
    writer.release()
    CameraModel.from_fov((64, 48), 70.0, CameraPose(height_m=1.0)).save(tmp_path / "cam.yaml")

    def opened(*args, **kwargs):
        raise SourceError("read")

    monkeypatch.setattr(run_module, "open_source", opened)
    argv = ["run", str(video), "--camera", str(tmp_path / "cam.yaml"), "--folder-fps", "5"]
    assert main(argv) == 1
    assert "--folder-fps is an image folder's frame rate" in caplog.text


def _avi_with_header_rate(path, rate: int, scale: int = 1, frames: int = 6):
    """An MJPG AVI whose header says `rate / scale` fps (as a damaged or patched header)."""
    import struct

    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 10.0, (64, 48))
    for i in range(frames):
        writer.write(np.full((48, 64, 3), 20 * i, np.uint8))
    writer.release()
    data = bytearray(path.read_bytes())
    stream_header = data.find(b"strh")  # fcc, size, type, handler, flags, priority, initial
    struct.pack_into("<II", data, stream_header + 28, scale, rate)  # dwScale, dwRate
    main_header = data.find(b"avih")  # its first field: microseconds per frame
    struct.pack_into("<I", data, main_header + 8, max(1, round(1e6 * scale / rate)))
    path.write_bytes(bytes(data))
    return path


@pytest.mark.parametrize("rate, scale", [(1_000_000, 1), (90_000, 1), (1, 1000)])
def test_a_file_frame_rate_outside_the_plausible_range_is_not_trusted(
    tmp_path, caplog, rate, scale
):
    # 10^6 fps stamped frames 1 us apart (with --realtime --output-video, millions of
    # copies of each frame); 0.001 fps, 1000 s apart (a realtime run sleeping that long).
    path = _avi_with_header_rate(tmp_path / "v.avi", rate, scale)
    source = FrameSource(str(path))
    assert source.fps == 15.0
    assert [f.stamp_s for f in source] == [i / 15.0 for i in range(6)]
    assert f"frame rate, {rate / scale:g} fps, is outside 1-240 fps" in caplog.text


@pytest.mark.parametrize("fps", [1.0, 240.0])
def test_a_file_frame_rate_at_the_ends_of_the_plausible_range_is_kept(
    tmp_path, monkeypatch, caplog, fps
):
    positions_ms = [i * 1000.0 / fps for i in range(4)]
    source = FrameSource(_fake_file(tmp_path, monkeypatch, positions_ms, fps=fps))
    assert source.fps == fps
    assert [f.stamp_s for f in source] == [i / fps for i in range(4)]
    assert "not trusted" not in caplog.text


class _RingFrozenCamera(_LiveCamera30Fps):
    """A live camera whose driver, after `fresh` images, hands back its ring of stale
    buffers in turn (fresh - 1, fresh, fresh - 1, ...) for `frozen` reads, then new
    images again."""

    def __init__(self, fresh: int, frozen: int):
        self.fresh, self.frozen, self.reads = fresh, frozen, 0

    def read(self):
        self.reads += 1
        if self.reads <= self.fresh:
            value = self.reads
        elif self.reads <= self.fresh + self.frozen:
            value = self.fresh - 1 + self.reads % 2
        else:
            value = self.reads - self.frozen
        return True, np.full((24, 32, 3), value, np.uint8)

    def grab(self):
        self._grabbed = self.read()
        return True

    def retrieve(self):
        return self._grabbed

    def release(self):
        pass


def test_a_frozen_driver_cycling_its_stale_buffers_delivers_nothing_new(monkeypatch, caplog):
    """Buffers 3, 4, 3, 4, ... each differ from the one before: compared with the last
    image only, all would pass as fresh and the stall watchdog never fire."""
    monkeypatch.setattr(cv2, "VideoCapture", lambda *a: _RingFrozenCamera(4, frozen=20))
    frames = iter(FrameSource("0"))
    assert [int(next(frames).image[0, 0, 0]) for _ in range(6)] == [1, 2, 3, 4, 5, 6]
    assert "the same image again" in caplog.text


def test_a_real_cameras_noisy_frames_are_never_taken_for_repeats():
    """A still scene: consecutive frames differ by sensor noise alone, a 16-bit sensor's
    perhaps in the low byte only (which the 8-bit conversion drops)."""
    from follow.repeated_image import RepeatedImages

    rng = np.random.default_rng(0)
    scene = rng.integers(0, 200, (48, 64, 3), dtype=np.uint8)
    repeats = RepeatedImages()
    for _ in range(300):
        noisy = np.clip(scene + rng.normal(0.0, 1.0, scene.shape), 0, 255).astype(np.uint8)
        assert not repeats.is_repeat(noisy)
    thermal = np.full((24, 32), 0x4000, np.uint16)
    for low_byte in range(1, 20):
        assert not repeats.is_repeat(thermal + low_byte)


def test_repeated_images_remember_a_driver_ring_and_no_more():
    from follow.repeated_image import MAX_DRIVER_BUFFERS, RepeatedImages

    repeats = RepeatedImages()
    images = [np.full((8, 8, 3), i, np.uint8) for i in range(MAX_DRIVER_BUFFERS + 1)]
    assert not any(repeats.is_repeat(image) for image in images)
    assert repeats.is_repeat(images[1].copy())  # within the ring: a stale buffer
    assert not repeats.is_repeat(images[0])  # older than any ring: a scene come back
    assert not repeats.is_repeat(images[0].reshape(8, 24))  # same bytes, another shape


def test_an_existing_file_whose_name_has_a_bang_is_read_as_a_file(tmp_path):
    path = _video_with_frames(tmp_path / "take1!.avi", 3)
    source = FrameSource(str(path))
    assert not source.live and len(list(source)) == 3


def _video_with_frames(path, frames: int):
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 10.0, (32, 24))
    for i in range(frames):
        writer.write(np.full((24, 32, 3), 40 * i, np.uint8))
    writer.release()
    return path


@pytest.mark.parametrize("listed, says", [
    ("NO", "built without GStreamer .*GStreamer NO; pip's opencv-python has none"),
    ("YES (1.20.3)", "this OpenCV has GStreamer, YES \\(1.20.3\\): check the pipeline"),
])  # fmt: skip
def test_a_pipeline_that_cannot_be_opened_says_whether_opencv_has_gstreamer(
    monkeypatch, listed, says
):
    import follow.capture as capture

    class Closed:
        def __init__(self, *args):
            pass

        def isOpened(self):
            return False

    build = f"General configuration\n  Video I/O:\n    GStreamer:                   {listed}\n"
    monkeypatch.setattr(cv2, "VideoCapture", Closed)
    monkeypatch.setattr(cv2, "getBuildInformation", lambda: build)
    capture._gstreamer_support.cache_clear()
    try:
        with pytest.raises(SourceError, match=f"the GStreamer pipeline cannot be opened .*{says}"):
            FrameSource("videotestsrc ! videoconvert ! appsink")
    finally:
        capture._gstreamer_support.cache_clear()


def test_a_pipeline_too_long_for_a_file_name_is_still_a_pipeline(monkeypatch):
    opened = []
    monkeypatch.setattr(cv2, "VideoCapture", lambda *a: opened.append(a) or _UnpluggedCamera(1))
    properties = " ".join(f"property-{i}={i}" for i in range(30))  # before any "/"
    FrameSource(f"v4l2src {properties} ! appsink")  # a name over 255 characters: no OSError
    assert opened[0][1] == cv2.CAP_GSTREAMER


def test_a_non_ascii_digit_is_no_camera_index(tmp_path):
    # "²".isdigit() is True, but int("²") raises: named as a missing file, not a traceback
    with pytest.raises(SourceError, match="source ²: no such file"):
        FrameSource("²")
