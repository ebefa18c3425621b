"""Recorded robot bags as a frame source: ROS 1 `.bag`, ROS 2 bag directories and
MCAP / SQLite files, read with `rosbags` (pure Python, no ROS installation).

Images come from one topic (Image or CompressedImage), stamped with their header's
time; the robot's pose at each image's stamp comes from an odometry topic
(nav_msgs/Odometry, interpolated between samples). An image with no odometry close
enough is skipped with a warning rather than placed at an assumed pose. Every image
skipped is counted by reason (`skipped_images`); a bag whose images are all skipped is
refused with those counts, and a damaged record that the storage layer cannot read ends
the bag with a SourceError naming it (a damaged message only skips that message).
"""

from __future__ import annotations

import logging
import statistics
from collections.abc import Iterator
from pathlib import Path

from follow.capture import (
    FALLBACK_FPS,
    MAX_TRUSTED_FILE_FPS,
    MIN_TRUSTED_FILE_FPS,
    SourceError,
)
from follow.odometry_buffer import OdometryBuffer
from follow.rosmsg import (
    IMAGE_ENCODINGS,
    frame_id_of,
    image_from_msg,
    odometry_from_msg,
    stamp_s,
)
from follow.types import Frame, InvalidInput, Odometry

log = logging.getLogger(__name__)

# Images whose header stamps give a bag's frame rate (`BagSource._frame_rate`).
RATE_SAMPLE_IMAGES = 300

BAG_SUFFIXES = (".bag", ".mcap", ".db3")
IMAGE_TYPES = ("sensor_msgs/msg/Image", "sensor_msgs/msg/CompressedImage")
ODOMETRY_TYPE = "nav_msgs/msg/Odometry"
CAMERA_INFO_TYPE = "sensor_msgs/msg/CameraInfo"
STRING_TYPE = "std_msgs/msg/String"
SKELETON_STAMP_TOLERANCE_S = 1e-6


def is_bag(spec: str) -> bool:
    """Whether a source names a bag (by suffix, or a directory holding metadata.yaml)."""
    path = Path(spec)
    return path.suffix in BAG_SUFFIXES or (path.is_dir() and (path / "metadata.yaml").is_file())


class BagSource:
    """Iterates the frames of one image topic of a bag, in recording order."""

    live = False

    def __init__(
        self,
        spec: str,
        image_topic: str,
        odom_topic: str | None = None,
        camera_info_topic: str | None = None,
        max_odometry_gap_s: float = 0.2,
        skeletons_topic: str | None = None,
    ):
        try:
            from rosbags.highlevel import AnyReader
            from rosbags.typesys import Stores, get_typestore
        except ImportError:
            raise SourceError(
                "reading bags needs the rosbags package: pip install 'follow[bag]'"
            ) from None
        self.spec = spec
        path = Path(spec)
        if not path.exists():
            raise SourceError(f"bag {spec}: no such file or directory")
        try:
            self._reader = AnyReader([path], default_typestore=get_typestore(Stores.LATEST))
            self._reader.open()
        except Exception as exc:  # rosbags raises its own error classes per format
            raise SourceError(f"bag {spec}: cannot be read ({exc})") from None
        try:  # a bag refused here is closed again: the caller gets no source to close
            self._read_topics(image_topic, odom_topic, camera_info_topic, max_odometry_gap_s,
                              skeletons_topic)  # fmt: skip
        except BaseException:
            self._reader.close()
            raise

    def _read_topics(self, image_topic, odom_topic, camera_info_topic, max_odometry_gap_s,
                     skeletons_topic) -> None:  # fmt: skip
        spec = self.spec
        self._images = self._connections(image_topic, IMAGE_TYPES)
        self.odometry: OdometryBuffer | None = None
        if odom_topic:
            connections = self._connections(odom_topic, (ODOMETRY_TYPE,))
            self.odometry = self._read_odometry(connections, max_odometry_gap_s)
        self.camera_info = None
        if camera_info_topic:
            info = self._connections(camera_info_topic, (CAMERA_INFO_TYPE,))
            for connection, log_time_ns, raw in self._messages(info):
                try:
                    self.camera_info = self._decode(raw, connection, log_time_ns)
                except InvalidInput as exc:
                    raise SourceError(f"bag {spec}: camera info {exc}") from None
                break
            if self.camera_info is None:
                raise SourceError(f"bag {spec}: topic {camera_info_topic} holds no message")
        self._skeletons: tuple[list[float], list] | None = None
        if skeletons_topic:
            self._skeletons = self._read_skeletons(
                self._connections(skeletons_topic, (STRING_TYPE,))
            )
        self.fps = self._frame_rate()
        self.frames_without_odometry = 0
        self.repeated_frames = 0  # images not stamped after the one before: skipped
        self.damaged_images = 0  # image messages whose bytes do not decode: skipped
        self.skipped_images: dict[str, int] = {}  # every image skipped, by reason

    def _messages(self, connections: list) -> Iterator:
        """The reader's messages, with an error of the storage layer (a damaged record:
        rosbags' ReaderError, its assertions, struct's errors) as a SourceError naming the
        bag and topic, so that `follow run` ends naming it rather than with a traceback."""
        try:
            yield from self._reader.messages(connections)
        except Exception as exc:  # rosbags raises its own classes, and asserts, per format
            raise SourceError(
                f"bag {self.spec}: {connections[0].topic}: damaged record "
                f"({type(exc).__name__}: {exc})"
            ) from None

    def _decode(self, raw: bytes, connection, log_time_ns: int):
        """The message in `raw`, or InvalidInput naming the topic and time where its bytes
        do not decode as the connection's type (a damaged bag: one message, not the run)."""
        try:
            return self._reader.deserialize(raw, connection.msgtype)
        except Exception as exc:  # rosbags raises its own errors, struct's and others
            raise InvalidInput(
                f"{connection.topic} at {log_time_ns * 1e-9:.3f} s does not decode as "
                f"{connection.msgtype} ({type(exc).__name__}: {exc})"
            ) from None

    def _connections(self, topic: str, types: tuple[str, ...]) -> list:
        found = [c for c in self._reader.connections if c.topic == topic]
        if not found:
            topics = sorted({f"{c.topic} ({c.msgtype})" for c in self._reader.connections})
            raise SourceError(f"bag {self.spec}: no topic {topic}; it holds {topics}")
        wrong = [c.msgtype for c in found if c.msgtype not in types]
        if wrong:
            raise SourceError(f"bag {self.spec}: topic {topic} is {wrong[0]}, expected {types}")
        return found

    def _read_odometry(self, connections: list, max_gap_s: float) -> OdometryBuffer:
        """The topic's poses, in recording order, keeping only those stamped after the
        last kept (as images): after a clock stepped back, the samples before and after
        the step would share stamps and give images the pose from the wrong side. Only
        the frame of the first sample that names one is kept (samples naming none are
        taken to be in it), as the ROS 2 node keeps only `ros.odom_frame`'s: two
        publishers' frames blended swung each image's pose between them."""
        poses, bad, stepped_back = [], [], 0
        odom_frame, other_frames, in_other_frames = "", set(), 0
        for c, log_time_ns, raw in self._messages(connections):
            try:
                msg = self._decode(raw, c, log_time_ns)
                pose = odometry_from_msg(msg)
            except InvalidInput as exc:  # one bad sample: a gap, not an unreadable bag
                bad.append(f"{log_time_ns * 1e-9:.3f} s: {exc}")
                continue
            frame = frame_id_of(msg)
            odom_frame = odom_frame or frame
            if frame and frame != odom_frame:
                other_frames.add(frame)
                in_other_frames += 1
                continue
            if pose.stamp_s == 0.0:  # unstamped, as images can be: the time it was recorded
                pose = Odometry(pose.x_m, pose.y_m, pose.yaw_rad, log_time_ns * 1e-9)
            if poses and pose.stamp_s <= poses[-1].stamp_s:
                stepped_back += 1
                continue
            poses.append(pose)
        topic = connections[0].topic
        if bad:
            log.warning("bag %s: %d odometry message(s) on %s skipped (first at %s)",
                        self.spec, len(bad), topic, bad[0])  # fmt: skip
        if in_other_frames:
            log.warning("bag %s: %d odometry message(s) on %s skipped: in frame %s, not %r, "
                        "the frame of the first sample", self.spec, in_other_frames, topic,
                        " or ".join(map(repr, sorted(other_frames))), odom_frame)  # fmt: skip
        if stepped_back:
            log.warning("bag %s: %d odometry message(s) on %s skipped: stamped at or before "
                        "an earlier sample (a clock stepped back?)",
                        self.spec, stepped_back, topic)  # fmt: skip
        if not poses:
            raise SourceError(f"bag {self.spec}: odometry topic {topic} is empty")
        # every jump kept: the whole topic is read before the first image is tracked
        buffer = OdometryBuffer(max_gap_s, capacity=len(poses), jump_capacity=len(poses))
        for pose in poses:
            buffer.add(pose)
        return buffer

    def _read_skeletons(self, connections: list) -> tuple[list[float], list]:
        """Recorded detections: JSON lists of skeletons (the run log's format), stamped
        with their record time, the time of the image they belong to."""
        import json

        from follow.runlog import skeleton_from_json

        stamps, skeletons, damaged = [], [], []
        for c, log_time_ns, raw in self._messages(connections):
            try:
                text = self._decode(raw, c, log_time_ns).data
            except InvalidInput as exc:  # its frame is run without recorded skeletons
                damaged.append(str(exc))
                continue
            try:
                listed = json.loads(text)
                if not isinstance(listed, list):
                    raise ValueError("its JSON is no list")
                skeletons.append([skeleton_from_json(d, f"skeleton {i}")
                                  for i, d in enumerate(listed)])  # fmt: skip
            except ValueError as exc:  # json.JSONDecodeError is one
                raise SourceError(
                    f"bag {self.spec}: {c.topic} at {log_time_ns} ns is not a JSON list of "
                    "skeletons (objects with keypoints_px and confidences, as the run log "
                    f"writes them: is it the skeletons topic?): {exc}"
                ) from None
            stamps.append(log_time_ns * 1e-9)
        if damaged:
            log.warning("bag %s: %d skeleton message(s) skipped (first: %s)",
                        self.spec, len(damaged), damaged[0])  # fmt: skip
        order = sorted(range(len(stamps)), key=stamps.__getitem__)
        return [stamps[i] for i in order], [skeletons[i] for i in order]

    def recorded_skeletons(self, frame: Frame) -> list:
        """The skeletons recorded for a frame (a `detect` for build_perception)."""
        import bisect

        if self._skeletons is None:
            raise ValueError(f"bag {self.spec}: no skeletons topic was given")
        stamps, skeletons = self._skeletons
        i = bisect.bisect_left(stamps, frame.stamp_s - SKELETON_STAMP_TOLERANCE_S)
        if i < len(stamps) and abs(stamps[i] - frame.stamp_s) <= SKELETON_STAMP_TOLERANCE_S:
            return skeletons[i]
        log.warning("no recorded skeletons at %.6f s: none seen in that frame", frame.stamp_s)
        return []

    def _frame_rate(self) -> float:
        """The images' rate, from the median interval between their header stamps (the
        times frames are played by: the recorder's receive times step with its clock and
        stretched a video to hours); FALLBACK_FPS for fewer than two images or a rate
        outside MIN..MAX_TRUSTED_FILE_FPS, as a video file's."""
        stamps = self._played_image_stamps()
        if len(stamps) < 2:
            return FALLBACK_FPS
        intervals_s = [b - a for a, b in zip(stamps[:-1], stamps[1:], strict=True)]
        fps = 1.0 / statistics.median(intervals_s)
        if not MIN_TRUSTED_FILE_FPS <= fps <= MAX_TRUSTED_FILE_FPS:
            log.warning("bag %s: the images' frame rate, %g fps (by their stamps), is outside "
                        "%g-%g fps: not trusted; %g fps used", self.spec, fps,
                        MIN_TRUSTED_FILE_FPS, MAX_TRUSTED_FILE_FPS, FALLBACK_FPS)  # fmt: skip
            return FALLBACK_FPS
        return fps

    def _played_image_stamps(self) -> list[float]:
        """The stamps of the first RATE_SAMPLE_IMAGES images as they are played: the
        header's (the record time where it is 0), each after the one before; damaged
        images left out. Only the first ones: each is decoded whole to read its header,
        and a long bag's every image would cost seconds before the first frame."""
        stamps: list[float] = []
        for connection, log_time_ns, raw in self._messages(self._images):
            if len(stamps) >= RATE_SAMPLE_IMAGES:
                break
            try:
                stamp = _image_stamp_s(self._decode(raw, connection, log_time_ns), log_time_ns)
            except InvalidInput:  # warned of when the images are played
                continue
            if not stamps or stamp > stamps[-1]:
                stamps.append(stamp)
        return stamps

    def __iter__(self) -> Iterator[Frame]:
        last_stamp, yielded = None, 0
        for connection, log_time_ns, raw in self._messages(self._images):
            try:
                msg = self._decode(raw, connection, log_time_ns)
            except InvalidInput as exc:
                self.damaged_images += 1
                self._skip("damaged", "skipping an image: %s", exc)
                continue
            stamp = _image_stamp_s(msg, log_time_ns)
            if last_stamp is not None and stamp <= last_stamp:
                # A repeated (or older) image: the tracker would fold the same detections
                # in twice at dt = 0 and grow falsely sure of them (as the ROS node, drop).
                self.repeated_frames += 1
                self._skip("stamp not after the previous", "skipping the image at %.6f s: "
                           "not after the previous one (%.6f s)", stamp, last_stamp)  # fmt: skip
                continue
            last_stamp = stamp
            try:
                frame = Frame(image_from_msg(msg), stamp)
            except InvalidInput as exc:
                self._skip(_unusable_reason(msg), "skipping the image at %.3f s: %s", stamp, exc)
                continue
            if self.odometry is not None and self.odometry.at(stamp) is None:
                self.frames_without_odometry += 1
                self._skip("no odometry", "skipping the image at %.3f s: no odometry within "
                           "%.2f s", stamp, self.odometry.max_gap_s)  # fmt: skip
                continue
            yielded += 1
            yield frame
        if not yielded and self.skipped_images:
            raise SourceError(f"bag {self.spec}: {self._all_skipped()}")

    def _skip(self, reason: str, message: str, *args) -> None:
        """Count a skipped image under `reason` (the summary's `skipped_images`), warning."""
        self.skipped_images[reason] = self.skipped_images.get(reason, 0) + 1
        log.warning(message, *args)

    def _all_skipped(self) -> str:
        """'6 images on /camera/image_raw, all skipped: 6 in unsupported encoding ...'."""
        total = sum(self.skipped_images.values())
        counts = ", ".join(f"{n} {_with_reason(r)}" for r, n in self.skipped_images.items())
        images = "image" if total == 1 else "images"
        return f"{total} {images} on {self._images[0].topic}, all skipped: {counts}"

    def odometry_at(self, stamp: float) -> Odometry:
        """The robot's pose at an image's stamp (only for frames this source yielded)."""
        pose = self.odometry.at(stamp) if self.odometry is not None else None
        if pose is None:
            raise ValueError(f"bag {self.spec}: no odometry at {stamp:.3f} s")
        return pose

    def close(self) -> None:
        self._reader.close()


def _unusable_reason(msg) -> str:
    """Why an image message that decodes gives no image: its encoding, or its content."""
    encoding = getattr(msg, "encoding", None)  # CompressedImage has a format instead
    if encoding is not None and encoding not in IMAGE_ENCODINGS:
        return f"unsupported encoding {encoding!r}"
    return "unusable"


def _with_reason(reason: str) -> str:
    """A skip reason after its count: '6 in unsupported encoding ...', '2 with no odometry'."""
    if reason.startswith("unsupported encoding"):
        return f"in {reason}"
    return f"with {reason}" if reason in ("no odometry", "stamp not after the previous") else reason


def _image_stamp_s(msg, log_time_ns: int) -> float:
    """The time an image is played at: its header's stamp, or, for an unstamped image,
    the time it was recorded."""
    stamp = stamp_s(msg.header)
    return stamp if stamp != 0.0 else log_time_ns * 1e-9
