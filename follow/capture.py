"""Frame sources (video file, camera index, GStreamer pipeline, image folder) and a
one-slot buffer that keeps only the newest frame, so a slow detector never builds a
backlog of stale images."""

from __future__ import annotations

import functools
import logging
import os
import re
import time
from collections.abc import Callable, Iterable, Iterator
from decimal import Decimal
from pathlib import Path

import cv2
import numpy as np

from follow.cli_args import (
    EARLY_END_TOLERANCE_FRAMES,
    MAX_UNDECODABLE_RUN,
    camera_index_too_large,
    frame_count_fits_file,
    no_camera_at,
    refuse_non_utf8_name,
)
from follow.handoff import Mailbox
from follow.repeated_image import MAX_DRIVER_BUFFERS, RepeatedImages
from follow.types import Frame, InvalidInput

log = logging.getLogger(__name__)

IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png", ".bmp", ".tif", ".tiff")
# An image folder's frame rate unless told (`follow run --folder-fps`): its frames' times.
DEFAULT_FOLDER_FPS = 15.0
# A video's or camera's frame rate where it reports none (0, not finite).
FALLBACK_FPS = 15.0
# A file's frame rate outside this range is a damaged or patched header, not a recording:
# 1,000,000 fps would stamp frames 1 us apart, 0.001 fps 1000 s apart (a --realtime run
# sleeping that long per frame). Such a file is stamped at FALLBACK_FPS instead.
MIN_TRUSTED_FILE_FPS, MAX_TRUSTED_FILE_FPS = 1.0, 240.0
# Frames in a row that cannot be used (a layout no conversion makes BGR) before the source
# is refused: skipped for ever, a camera's would spin the CPU and never reach the stall
# watchdog, which starts after the first frame.
MAX_UNUSABLE_RUN = 10
# A file's presentation time this close to index / fps is a frame on its frame rate's
# grid (containers store times to the millisecond): it keeps index / fps exactly.
FRAME_RATE_GRID_TOLERANCE_S = 1e-3
# A live camera's driver keeps capturing into a queue of buffers while nobody reads
# (OpenCV's V4L2 back-end queues 4): after a pause in reading (the models loading after
# the first frame was read for its size), the queue's frames are as old as the pause.
# A read that returns within this fraction of the frame period did not wait for the
# sensor: it came from the queue. At most MAX_QUEUED_FRAMES are dropped so.
QUEUE_PAUSE_PERIODS = 2.0
QUEUED_READ_MAX_PERIOD_FRACTION = 0.25
MAX_QUEUED_FRAMES = MAX_DRIVER_BUFFERS
# A JPEG marker in entropy-coded data: 0xFF not followed by a stuffed 0x00 or a restart (RSTn).
_JPEG_MARKER_IN_SCAN = re.compile(rb"\xff[^\x00\xd0-\xd7]")
# The markers that may follow a scan: frame and table segments (C0-CF), another scan and
# its tables (DA-DF), APPn (E0-EF), a comment (FE), the end (D9), or a fill byte (FF).
_JPEG_MARKERS_AFTER_SCAN = frozenset([*range(0xC0, 0xD0), *range(0xD9, 0xE0),
                                      *range(0xE0, 0xF0), 0xFE, 0xFF])  # fmt: skip


class SourceError(RuntimeError):
    """A frame source that cannot be opened or read."""


def _refuse_non_utf8_source(spec: str) -> None:
    """SourceError for a file or pipeline whose name is not UTF-8: OpenCV would crash on it."""
    try:
        refuse_non_utf8_name(spec, "source")
    except ValueError as exc:
        raise SourceError(str(exc)) from None


class FrameSource:
    """Iterates frames from a video file, camera index or device, GStreamer pipeline or folder.

    Frames that cannot be decoded are skipped with a warning; grey (8- or 16-bit), BGRA
    and HxWx1 frames are converted to 8-bit BGR; MAX_UNUSABLE_RUN frames in a row that
    are still unusable, or a live camera whose reads keep failing, raise SourceError (a
    camera does not end: it was lost). Timestamps are taken from a video file's
    presentation times (a variable frame rate kept; where the file has none, from its
    frame rate; a rate outside MIN..MAX_TRUSTED_FILE_FPS is not trusted, nor the times
    derived from it: FALLBACK_FPS), from the frame rate for folders (so replay is
    reproducible) and from the monotonic clock for live cameras, whose frames queued in
    the driver during a pause in reading are dropped (they are as old as the pause).
    """

    def __init__(self, spec: str, folder_fps: float = DEFAULT_FOLDER_FPS):
        self.spec = spec
        self.live = False
        self._folder: list[Path] | None = None
        self.frame_count: int | None = None
        self._cap: cv2.VideoCapture | None = None
        self._rate_trusted = True
        self._count_trusted = False  # the frame count bounds a damaged stretch (a file's)
        self._damage_seen = False  # a damaged stretch was skipped: the file is not whole
        if not str(spec).strip():
            raise SourceError("source is empty: give a video file, camera index, folder or bag")
        path = Path(spec)
        # os.path's checks: a pipeline's long caps make a name too long for Path's (OSError)
        if os.path.isdir(spec):
            images = (p for p in path.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
            self._folder = sorted(images, key=_frame_order)
            if not self._folder:
                raise SourceError(f"source {spec}: folder holds no images ({IMAGE_SUFFIXES})")
            self.fps = folder_fps
            return
        camera_index = spec.isascii() and spec.isdigit()  # not "²", which int() refuses
        pipeline = "!" in spec and not os.path.exists(spec)  # an existing path is a file
        if not camera_index:
            _refuse_non_utf8_source(spec)
        if camera_index:
            if too_large := camera_index_too_large(spec):
                raise SourceError(f"source {spec}: {too_large}; a file named so: ./{spec}")
            self._cap = cv2.VideoCapture(int(spec))
            self.live = True
        elif pipeline:  # GStreamer, e.g. a Jetson CSI camera
            self._cap = cv2.VideoCapture(spec, cv2.CAP_GSTREAMER)
            self.live = True
        else:
            if not path.exists():
                raise SourceError(f"source {spec}: no such file")
            self._cap = cv2.VideoCapture(str(path))
            self.live = path.is_char_device()  # a camera's node: /dev/video0, /dev/v4l/by-id/...
        if not self._cap.isOpened():
            if self.live and camera_index:
                raise SourceError(f"source {spec}: {no_camera_at(spec)}")
            if pipeline:
                raise SourceError(f"source {spec}: the GStreamer pipeline cannot be opened "
                                  f"({_gstreamer_support()})")  # fmt: skip
            raise SourceError(f"source {spec}: cannot be opened by OpenCV")
        self.fps = self._frame_rate()
        count = self._cap.get(cv2.CAP_PROP_FRAME_COUNT) if not self.live else 0
        self.frame_count = int(count) if count and np.isfinite(count) and count > 0 else None
        self._count_trusted = self.frame_count is not None and frame_count_fits_file(
            self.spec, self.frame_count
        )

    def _frame_rate(self) -> float:
        """The capture's frame rate: FALLBACK_FPS where it reports none, or (a file) one
        outside MIN..MAX_TRUSTED_FILE_FPS, whose stamps would be microseconds or hours
        apart; the file's presentation times, derived from that rate, are not used then."""
        fps = self._cap.get(cv2.CAP_PROP_FPS)
        if not (fps and np.isfinite(fps) and fps > 0):
            return FALLBACK_FPS
        if not self.live and not MIN_TRUSTED_FILE_FPS <= fps <= MAX_TRUSTED_FILE_FPS:
            log.warning("source %s: the file's frame rate, %g fps, is outside %g-%g fps (a "
                        "damaged header?): not trusted, nor its frames' times; frames "
                        "stamped at %g fps", self.spec, fps, MIN_TRUSTED_FILE_FPS,
                        MAX_TRUSTED_FILE_FPS, FALLBACK_FPS)  # fmt: skip
            self._rate_trusted = False
            return FALLBACK_FPS
        return fps

    def __iter__(self) -> Iterator[Frame]:
        if self._folder is not None:
            for index, path in enumerate(self._folder):
                try:
                    data = path.read_bytes()
                except OSError as exc:  # a dangling link, a folder named *.jpg, no access
                    log.warning("skipping %s: cannot be read (%s)", path, exc.strerror or exc)
                    continue
                if not data:
                    log.warning("skipping %s: an empty file", path)
                    continue
                if _truncated_jpeg(path, data):  # OpenCV would decode half and only warn
                    log.warning("skipping %s: a JPEG cut short (no end-of-image marker)", path)
                    continue
                image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)
                if image is None:
                    log.warning("skipping %s: not a readable image", path)
                    continue
                try:
                    frame = Frame(image, index / self.fps)
                except InvalidInput as exc:  # decoded, but no usable frame (too small)
                    log.warning("skipping %s: %s", path, exc)
                    continue
                yield frame
            return
        index = 0
        position = 0  # a file's frames read or found undecodable: their time
        start = time.monotonic()
        clock = None if self.live else _FileClock(self.spec, self.fps, self._rate_trusted)
        failures = 0
        unusable = 0  # frames in a row that no conversion made usable
        conversions_said = set()
        repeats = RepeatedImages()
        frozen_said = False
        returned_s = None  # when the last frame was handed over (a live camera's)
        while True:
            paused = (
                self.live
                and returned_s is not None
                and (time.monotonic() - returned_s > QUEUE_PAUSE_PERIODS / self.fps)
            )
            ok, image = self._read_past_queue() if paused else self._cap.read()
            if not ok:
                if self.live and failures < 10:
                    failures += 1
                    continue
                if self.live:  # a camera has no end: it was unplugged or stopped
                    raise SourceError(
                        f"source {self.spec}: the camera delivered no frame after {index} "
                        "frames (every read since failed: disconnected or stalled?)"
                    )
                if self._damaged_not_end(position, failures):
                    failures += 1  # a damaged frame, or the end of a file cut short
                    position += 1
                    continue
                self._warn_if_short(position - failures)
                self._warn_if_uncounted(position - failures, failures)
                return
            if failures and not self.live:  # frames after them: they were damaged
                first = position - failures
                self._damage_seen = True
                log.warning("source %s: frame%s %s cannot be decoded: skipped", self.spec,
                            "s" if failures > 1 else "",
                            first if failures == 1 else f"{first}-{position - 1}")  # fmt: skip
            failures = 0
            if clock is None:
                stamp = time.monotonic() - start
            else:  # the time the container gives the frame just read
                stamp = clock.stamp(position, self._cap.get(cv2.CAP_PROP_POS_MSEC))
            position += 1
            read, (image, conversion) = image, _as_bgr(image)
            if conversion and conversion not in conversions_said:
                log.info("source %s: %s frames, used as 8-bit BGR", self.spec, conversion)
                conversions_said.add(conversion)
            try:
                frame = Frame(image, stamp)
            except InvalidInput as exc:  # the decoder gave something odd
                index += 1
                unusable += 1
                if unusable >= MAX_UNUSABLE_RUN:
                    raise SourceError(
                        f"source {self.spec}: {unusable} frames in a row cannot be used, the "
                        f"last a {_layout(read)} ({exc}); frames must be 8- or 16-bit grey, "
                        "BGR or BGRA"
                    ) from None
                log.warning("skipping frame %d: %s", index, exc)
                continue
            unusable = 0
            # compared as read: a 16-bit sensor's noise may lie in the low byte alone
            if self.live and repeats.is_repeat(read):  # a frozen driver: nothing new
                if not frozen_said:  # (a freeze ends as a stall: camera_stall_timeout_s)
                    log.warning("source %s: the camera delivered the same image again (one "
                                "of its last %d: a frozen driver?): repeated images are "
                                "dropped", self.spec, MAX_DRIVER_BUFFERS)  # fmt: skip
                    frozen_said = True
                continue
            index += 1
            returned_s = time.monotonic()
            yield frame

    def _read_past_queue(self) -> tuple[bool, np.ndarray | None]:
        """The first frame a live camera captures after a pause in reading: the frames
        its driver queued meanwhile (as old as the pause, and stamped as new if read)
        are grabbed and dropped until a grab waits for the sensor."""
        period_s = 1.0 / self.fps
        dropped = -1  # the last frame grabbed is the one handed on
        while dropped < MAX_QUEUED_FRAMES:
            started_s = time.monotonic()
            if not self._cap.grab():
                return False, None
            dropped += 1
            if time.monotonic() - started_s >= QUEUED_READ_MAX_PERIOD_FRACTION * period_s:
                break
        if dropped:
            log.info("source %s: %d frame(s) queued in the camera's driver during a pause in "
                     "reading dropped (older than they would be stamped)", self.spec,
                     dropped)  # fmt: skip
        return self._cap.retrieve()

    def _damaged_not_end(self, position: int, failures: int) -> bool:
        """Whether a file's failed read at `position`, after `failures` in a row, is a
        damaged frame to skip rather than the end. A read fails alike at both, and OpenCV's
        position counts decoded frames only: a trusted frame count is the end, and a damaged
        stretch of any length before it is skipped (a read past a cut file's data fails in
        microseconds). Without a count to trust, MAX_UNDECODABLE_RUN failed reads in a row
        end the file (said by _warn_if_short, _warn_if_uncounted)."""
        if self.frame_count is not None and not self._frames_announced_after(position):
            return False
        return self._count_trusted or failures < MAX_UNDECODABLE_RUN

    def _frames_announced_after(self, position: int) -> bool:
        """Whether a file's header announces frames beyond `position`: a read that fails
        before them is a damaged frame, not the end of the file."""
        if self.frame_count is None:
            return False
        return position < self.frame_count - EARLY_END_TOLERANCE_FRAMES

    def _warn_if_short(self, read: int) -> None:
        """A file that ends before the frame count its header announces is truncated or
        corrupt: say so, since the run would otherwise end early in silence."""
        if self.live or self.frame_count is None:
            return
        if read < self.frame_count - EARLY_END_TOLERANCE_FRAMES:
            log.warning(
                "source %s: the stream ended after %d of the %d frames its header announces "
                "(truncated or corrupt file?)", self.spec, read, self.frame_count,
            )  # fmt: skip

    def _warn_if_uncounted(self, read: int, failures: int) -> None:
        """A file whose header announces no frame count ends after MAX_UNDECODABLE_RUN failed
        reads in a row: its end, or a longer damaged stretch whose later frames are lost;
        nothing tells the two apart, so the frame it ended at is said (a warning where the
        file already had a damaged stretch, else information: a whole raw stream ends so)."""
        if self.live or self.frame_count is not None:
            return
        log.log(logging.WARNING if self._damage_seen else logging.INFO,
                "source %s: the file announces no frame count: it ended at frame %d, where "
                "%d reads in a row failed; if a damaged stretch starts there, the file "
                "ended early and its frames after it were not read", self.spec, read,
                failures)  # fmt: skip

    def close(self) -> None:
        if self._cap is not None:
            self._cap.release()


def played_at_own_stamps(
    frames: Iterable[Frame],
    clock: Callable[[], float] = time.monotonic,
    sleep: Callable[[float], None] = time.sleep,
) -> Iterator[Frame]:
    """Each frame of a file when its own stamp falls due, counted from the first frame:
    the file played as it was recorded. A variable-frame-rate video keeps its gaps, and
    frames skipped as undecodable leave theirs; pacing by index / fps would play both
    on an even grid and the robot would see time run at another speed. A frame already
    late does not wait."""
    start_s = first_stamp_s = None
    for frame in frames:
        if start_s is None:
            start_s, first_stamp_s = clock(), frame.stamp_s
        else:
            delay_s = start_s + (frame.stamp_s - first_stamp_s) - clock()
            if delay_s > 0:
                sleep(delay_s)
        yield frame


class _FileClock:
    """Stamps of a video file's frames: the container's presentation times (read after
    each frame), shifted so that the first frame keeps index / fps; from the frame rate,
    on from the last good stamp, once they are missing (0), go back, stall or are not
    finite. A decoder's constant delay in them (OpenCV reports an H.264 AVI's frames at
    the time of the packet two frames on) is taken out by the shift."""

    def __init__(self, spec: str, fps: float, file_times: bool = True):
        self.spec = spec
        self.fps = fps
        self.from_file = file_times  # False: the file's times are not trusted from the start
        self._stamped = 0  # frames stamped so far
        self._first: tuple[float, float] | None = None  # (file ms, stamp s) of the first
        self._last: tuple[int, float, float] | None = None  # (position, file ms, stamp s)

    def stamp(self, position: int, file_ms: float) -> float:
        grid = position / self.fps
        if self.from_file:
            problem = self._problem(file_ms)
            if problem is None:
                stamp = self._from_file(file_ms, grid)
            else:
                self._give_up(position, problem)
        if not self.from_file:  # on at the frame rate from the last stamp (none: 0 shift)
            stamp = grid
            if self._last is not None:
                stamp += self._last[2] - self._last[0] / self.fps
        self._last = (position, file_ms, stamp)
        self._stamped += 1
        return stamp

    def _problem(self, file_ms: float) -> str | None:
        """Why a frame's presentation time cannot be used; None when it can."""
        if not np.isfinite(file_ms):
            return f"not finite: {file_ms}"
        if self._last is None:
            return None if file_ms >= 0 else f"negative: {file_ms:g} ms"
        if file_ms <= 0:
            return "missing"
        if file_ms <= self._last[1]:
            return f"{file_ms:g} ms after {self._last[1]:g} ms"
        return None

    def _from_file(self, file_ms: float, grid: float) -> float:
        if self._first is None:
            self._first = (file_ms, grid)
            return grid
        if self._stamped == 1:
            log.info("source %s: frames stamped with the file's presentation times", self.spec)
        stamp = self._first[1] + (file_ms - self._first[0]) / 1000.0
        if abs(stamp - grid) <= FRAME_RATE_GRID_TOLERANCE_S and grid > self._last[2]:
            return grid  # on a constant frame rate: the stamps it always gave
        return stamp

    def _give_up(self, position: int, problem: str) -> None:
        self.from_file = False
        if self._stamped <= 1:
            log.info("source %s: the file gives no usable presentation times (frame %d: %s); "
                     "frames stamped from its frame rate, %g fps", self.spec, position,
                     problem, self.fps)  # fmt: skip
            return
        level = logging.INFO if problem == "missing" else logging.WARNING
        log.log(level, "source %s: presentation times unusable from frame %d on (%s): "
                "later frames stamped from the frame rate, %g fps", self.spec, position,
                problem, self.fps)  # fmt: skip


def _as_bgr(image) -> tuple[np.ndarray, str | None]:
    """`image` as 8-bit BGR where OpenCV handed over another layout that cameras and
    pipelines give (GRAY8 or a mono camera, as a bag's mono8; GRAY16_LE of a thermal or
    depth camera, its high byte kept; BGRA; HxWx1), and what it was (None: left as it is,
    for Frame to accept or refuse by name)."""
    if not isinstance(image, np.ndarray) or image.size == 0:
        return image, None
    if image.dtype not in (np.uint8, np.uint16):
        return image, None
    was = []
    if image.ndim == 3 and image.shape[2] == 1:
        image = image[:, :, 0]
    if image.dtype == np.uint16:
        image = (image >> 8).astype(np.uint8)
        was.append("16-bit")
    if image.ndim == 2:
        image = cv2.cvtColor(image, cv2.COLOR_GRAY2BGR)
        was.append("single-channel")
    elif image.ndim == 3 and image.shape[2] == 4:
        image = cv2.cvtColor(image, cv2.COLOR_BGRA2BGR)
        was.append("BGRA")
    return image, " ".join(was) or None


def _layout(image) -> str:
    """What a frame source handed over, for an error: `48x64x4 uint16 array`."""
    if not isinstance(image, np.ndarray):
        return type(image).__name__
    return f"{'x'.join(map(str, image.shape))} {image.dtype} array"


@functools.cache
def _gstreamer_support() -> str:
    """Whether this OpenCV build reads GStreamer pipelines (pip's opencv-python does not),
    for the error of a pipeline that cannot be opened."""
    listed = "not listed"
    for line in cv2.getBuildInformation().splitlines():
        name, _, value = line.strip().partition(":")
        if name == "GStreamer":
            listed = value.strip()
    if listed.upper().startswith("YES"):
        return f"this OpenCV has GStreamer, {listed}: check the pipeline with gst-launch-1.0"
    return (
        f"this OpenCV is built without GStreamer (cv2.getBuildInformation(): GStreamer "
        f"{listed}; pip's opencv-python has none): use an OpenCV built with it"
    )


def _frame_order(path: Path) -> tuple:
    """Sort key of an image file in a folder: the numbers in its name compared as numbers,
    so that frame_2 comes before frame_10 (as text it would come after frame_19), and a
    number with a fraction (a time stamp, 1700000000.25.png) by its value: its fraction's
    digits compared as a whole number put .5 after .25."""
    parts = re.split(r"(\d+(?:\.\d+)?)", path.name)
    return [Decimal(p) if i % 2 else p for i, p in enumerate(parts)], path.name


def _truncated_jpeg(path: Path, data: bytes) -> bool:
    """Whether a .jpg/.jpeg file lacks its image's end-of-image marker (FFD9): a file cut
    short in copying or writing. Found by walking the JPEG's segments, since phones append
    data after it (Samsung's trailer, Apple's further images); where they cannot be walked,
    the file must end with it (padding after it allowed)."""
    if path.suffix.lower() not in (".jpg", ".jpeg"):
        return False
    ends = _jpeg_reaches_end(data)
    if ends is None:
        return not data.rstrip(b"\x00\r\n ").endswith(b"\xff\xd9")
    return not ends


def _jpeg_reaches_end(data: bytes) -> bool | None:
    """Whether a JPEG's segments, walked from its start-of-image marker, reach the image's
    end-of-image marker (False: the data ends first; None: no JPEG segments to walk). An
    FFD9 searched for would be found in an EXIF thumbnail too, ahead of the image."""
    if not data.startswith(b"\xff\xd8"):
        return None
    at = 2
    while at + 1 < len(data):
        if data[at] != 0xFF:
            return None
        marker = data[at + 1]
        if marker == 0xD9:
            return True
        if marker == 0xFF or 0xD0 <= marker <= 0xD7 or marker == 0x01:
            at += 1 if marker == 0xFF else 2  # a fill byte, or a marker without a segment
            continue
        at += 2 + int.from_bytes(data[at + 2 : at + 4], "big")
        if marker == 0xDA:  # a scan: its entropy-coded data runs to the next marker
            found = _JPEG_MARKER_IN_SCAN.search(data, at)
            if found is None:
                return False
            at = found.start()
            if data[at + 1] not in _JPEG_MARKERS_AFTER_SCAN:
                return None  # a damaged byte pair in the scan, not a marker: walk no further
    return False


def open_source(
    spec: str,
    image_topic: str | None = None,
    odom_topic: str | None = None,
    camera_info_topic: str | None = None,
    max_odometry_gap_s: float = 0.2,
    skeletons_topic: str | None = None,
    folder_fps: float = DEFAULT_FOLDER_FPS,
):
    """A FrameSource, or a BagSource when `spec` names a recorded bag (or topics are given).
    `folder_fps`: the frame rate an image folder's frames are stamped at."""
    from follow.bag import BagSource, is_bag

    if not (is_bag(spec) or image_topic or odom_topic or camera_info_topic or skeletons_topic):
        return FrameSource(spec, folder_fps)
    if not image_topic:
        raise SourceError(f"bag {spec}: give the image topic to read (--image-topic)")
    return BagSource(spec, image_topic, odom_topic, camera_info_topic, max_odometry_gap_s,
                     skeletons_topic)  # fmt: skip


class LatestSlot(Mailbox):
    """A one-item mailbox: `put` replaces whatever is there, `get` waits for a new item.

    Counts the items that were replaced before anyone read them (dropped frames).
    """

    def __init__(self):
        super().__init__()
        self._fresh = False
        self.dropped = 0

    def put(self, item) -> None:
        with self._cond:
            if self._fresh:
                self.dropped += 1
            self._item, self._fresh = item, True
            self._cond.notify_all()

    def get(self, timeout_s: float | None = None):
        """The newest item not yet taken; None when closed (and empty) or on time-out."""
        with self._cond:
            self._cond.wait_for(lambda: self._fresh or self._closed, timeout=timeout_s)
            if not self._fresh:
                return None
            self._fresh = False
            return self._item

    def peek(self):
        """The newest item, taken or not (None before the first)."""
        with self._cond:
            return self._item
