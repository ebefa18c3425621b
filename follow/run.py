"""`follow run`: follow a person from a camera or a video, optionally driving a base.

Live sources (a camera index or a GStreamer pipeline), `--realtime` and any run that
drives a base (`--mavlink`, a file then plays at its own frames' stamps) run capture,
perception and control in their own threads on the wall clock, with the perception
watchdog. A file without a base and without `--realtime` is processed frame by frame,
every frame, reproducibly. Ctrl-C, SIGTERM, SIGHUP or an error send the base a zero
command, flush the log and finalise the video (see `follow/shutdown.py`). A camera file
whose pose is still the placeholder of `follow-calib intrinsics` (not yet measured by
`follow-calib ground`) drives no base: such a run is refused, and one without a base
warned.
"""

from __future__ import annotations

import logging
import sys
import time
from pathlib import Path

import cv2
import numpy as np

from follow.bag import is_bag
from follow.camera import CameraModel, check_pose_measured
from follow.capture import (
    DEFAULT_FOLDER_FPS,
    MAX_TRUSTED_FILE_FPS,
    MIN_TRUSTED_FILE_FPS,
    open_source,
    played_at_own_stamps,
)
from follow.cli_args import (
    float_within,
    non_negative_int,
    refuse_non_utf8_name,
    refuse_overwriting,
    refuse_unwritable,
)
from follow.config import Config
from follow.person_in_view import log_person_in_view
from follow.pipeline import FrameResult, Perception, build_runner, run_offline
from follow.render import annotate, top_down
from follow.runlog import RunLogWriter, read_run_log
from follow.shutdown import ShutdownSignals, stop_within
from follow.types import Frame, Odometry, VelocityCommand

log = logging.getLogger(__name__)


def add_arguments(p) -> None:
    p.add_argument(
        "source",
        help="video file, camera index (e.g. 0), GStreamer pipeline (a string with '!'), "
        "a folder of images, or a recorded bag (ROS 1 .bag, ROS 2 bag directory, .mcap)",
    )
    p.add_argument("--image-topic", help="bag: the image topic (Image or CompressedImage)")
    p.add_argument("--odom-topic", help="bag: nav_msgs/Odometry, the robot pose at each image")
    p.add_argument("--camera-info-topic", help="bag: CameraInfo, intrinsics over the camera file")
    p.add_argument("--skeletons-topic", help="bag: recorded skeletons (follow demo --bag) "
                   "used instead of the pose network")  # fmt: skip
    # the range a video file's own rate is trusted in (1e-300 Hz overflowed the stamps)
    p.add_argument("--folder-fps", default=None, metavar="HZ",
                   type=float_within(MIN_TRUSTED_FILE_FPS, MAX_TRUSTED_FILE_FPS),
                   help="an image folder's frame rate, which its frames are stamped at "
                   f"(default {DEFAULT_FOLDER_FPS:g}; {MIN_TRUSTED_FILE_FPS:g} to "
                   f"{MAX_TRUSTED_FILE_FPS:g})")  # fmt: skip
    p.add_argument("--camera", required=True, help="camera file (YAML/JSON, from follow-calib)")
    p.add_argument("--config", help="TOML configuration over the robot defaults (docs/config.md)")
    p.add_argument("--mavlink", help="MAVLink connection string, e.g. udpin:0.0.0.0:14550")
    p.add_argument("--no-base", action="store_true",
                   help="drive no base, even where the configuration names a MAVLink "
                        "connection (to check the view first)")  # fmt: skip
    p.add_argument("--target-id", type=non_negative_int,
                   help="follow this track id instead of the nearest")  # fmt: skip
    p.add_argument("--output-video", help="write the annotated video here (.mp4 or .avi)")
    p.add_argument("--frames-dir", help="write annotated frames (with a top-down view) here")
    p.add_argument("--log", help="write a JSON-lines log of every frame here")
    p.add_argument(
        "--realtime",
        action="store_true",
        help="play a file as recorded (its frames' own times) with threads",
    )
    p.add_argument("--max-frames", type=int, help="stop after this many frames")
    p.add_argument(
        "--replay",
        metavar="LOG",
        help="re-run tracking and identification on the skeletons of a log and the same "
        "source, and report whether the targets agree",
    )


def build_perception(
    config: Config, camera: CameraModel, detect=None, pose_backend: str | None = None
) -> Perception:
    """The standard stack: pose network (unless `detect` is given, running on
    `pose_backend`), UKF, identifier."""
    from follow.identify.factory import build_identifier
    from follow.pose.observations import skeletons_to_observations
    from follow.ukf.tracker import PeopleTracker

    if detect is None:
        from follow.pose.detector import PoseDetector
        from follow.pose.input_size import pose_config_for_camera

        # warmed up at the frames' size: a runtime that compiles per input shape does
        # it before the first real frame, not on it
        pose = pose_config_for_camera(config.pose, camera)
        detector = PoseDetector(pose, frame_size=camera.image_size)
        pose_backend = detector.backend_name

        def detect(frame: Frame):
            return detector.detect(frame.image)

    def to_observations(skeletons):
        return skeletons_to_observations(skeletons, camera.image_size, config.pose)

    return Perception(
        detect,
        to_observations,
        PeopleTracker(camera, config.tracker),
        build_identifier(config.identify),
        pose_backend,
    )


def open_base(config: Config):
    from follow.control.base import NullBase

    if not config.mavlink.connection:
        return NullBase()
    from follow.control.mavlink_base import MavlinkBase

    return MavlinkBase(config.mavlink)


def camera_for_frames(camera: CameraModel, width: int, height: int) -> CameraModel:
    """The camera scaled to the frames' size; a different aspect ratio is an error."""
    scaled = camera.for_image_size(width, height)
    if scaled is not camera:
        log.info("scaling the camera model from %dx%d to %dx%d", *camera.image_size, width, height)
    return scaled


# How long the log waits for the control loop's command from a frame (it comes within a
# millisecond of the frame's result; longer only when the loop is starved).
COMMAND_WAIT_S = 0.25
# How long `follow run` waits for the base to close. MavlinkBase's own waits add up to
# 3.5 s at most (0.5 s on a write under way before each of its three zeros, 1 s on each
# of its threads), but a write of its own may hang on a port that stopped draining.
BASE_CLOSE_WAIT_S = 5.0
MAX_VIDEO_REPEAT_S = 2.0  # the longest one processed frame stands in the video
# ... and at most this many copies of it, whatever the rate (a bag's, a camera's: 10^6 fps
# would write millions of copies of one frame)
MAX_VIDEO_COPIES = round(MAX_VIDEO_REPEAT_S * MAX_TRUSTED_FILE_FPS)
VIDEO_FOURCCS = {".mp4": "mp4v", ".avi": "MJPG"}  # what --output-video writes, by its name
# OpenCV's video writer reports no failed write: the file is checked to have grown once
# this many bytes of raw frames went in since it last grew. The writers hold 256 kB
# before the file grows; a still 1120x480 scene took 336 frames (540 MB raw) to fill
# that with mp4v, 71 with MJPG: 2 GiB leaves a margin of four.
VIDEO_GROWTH_CHECK_BYTES = 2 * 2**30


class Outputs:
    """Annotated video, annotated frame files and the JSON-lines log."""

    def __init__(
        self,
        header: dict,
        fps: float,
        video_path: str | Path | None = None,
        frames_dir: str | Path | None = None,
        log_path: str | Path | None = None,
    ):
        self.video_path = str(video_path) if video_path else None
        self.frames_dir = Path(frames_dir) if frames_dir else None
        if self.frames_dir:
            try:
                self.frames_dir.mkdir(parents=True, exist_ok=True)
            except OSError as exc:
                raise OSError(f"cannot make the frames folder {self.frames_dir}: "
                              f"{exc.strerror or exc}") from exc  # fmt: skip
        self.fps = fps
        self._writer = None
        self._video_first_stamp_s: float | None = None
        self._video_frames = 0  # written so far, repeats included
        self._video_raw_bytes = 0  # of raw frames written since the file last grew
        self._video_size_bytes = 0  # the file's size then
        self._abandoned = False
        self.log = RunLogWriter(log_path, header) if log_path else None

    def write(self, frame: Frame, result: FrameResult, command: VelocityCommand | None) -> None:
        if self.log is not None:
            self.log.write_frame(
                result.frame_index, result.stamp_s, result.robot, result.skeletons,
                result.tracks, result.target, command, result.timing_ms,
            )  # fmt: skip
        if not (self.video_path or self.frames_dir):
            return
        picture = annotate(frame.image, result.skeletons, result.tracks, result.target, command)
        side = top_down(result.tracks, result.target.target_id, result.robot,
                        size_px=picture.shape[0])  # fmt: skip
        canvas = np.hstack([picture, side])
        if self.video_path:
            if self._writer is None:
                self._writer = self._open_video(canvas.shape[1], canvas.shape[0])
            copies = self._video_copies(result.stamp_s)
            for _ in range(copies):
                self._writer.write(canvas)
            self._check_video_grows(copies * canvas.nbytes)
        if self.frames_dir:
            path = self.frames_dir / f"{result.frame_index:06d}.jpg"
            if not cv2.imwrite(str(path), canvas):  # OpenCV reports a failed write so only
                raise OSError(f"cannot write frame {path}")

    def _open_video(self, width_px: int, height_px: int):
        """The video writer, once it is open: one that failed to open is not kept, so
        `close` does not report a file that was never written as unreadable."""
        suffix = Path(self.video_path).suffix.lower()
        fourcc = cv2.VideoWriter_fourcc(*VIDEO_FOURCCS.get(suffix, "MJPG"))
        writer = cv2.VideoWriter(self.video_path, fourcc, self.fps, (width_px, height_px))
        if not writer.isOpened():
            raise OSError(f"cannot write video {self.video_path} ({width_px}x{height_px} at "
                          f"{self.fps:g} fps): OpenCV's writer does not open (a folder that cannot "
                          "be written in, or a size or rate its codec refuses)")  # fmt: skip
        return writer

    def _check_video_grows(self, raw_bytes: int) -> None:
        """Raise OSError when the video file has not grown over
        VIDEO_GROWTH_CHECK_BYTES of raw frames: the writer failed silently (a full
        disk), and the run must not go on as if it were recorded."""
        self._video_raw_bytes += raw_bytes
        if self._video_raw_bytes < VIDEO_GROWTH_CHECK_BYTES:
            return
        size = Path(self.video_path).stat().st_size
        if size <= self._video_size_bytes:
            raise OSError(
                f"video {self.video_path} stopped growing at {size} bytes although "
                f"{self._video_raw_bytes / 2**20:.0f} MiB of frames went in since: is the "
                "disk full?"
            )
        self._video_raw_bytes, self._video_size_bytes = 0, size

    def _video_copies(self, stamp_s: float) -> int:
        """How many times a frame stamped `stamp_s` goes into the video, at `fps`, so that
        the video plays in the frames' own time: a threaded run processes only some of
        the camera's frames (each processed frame stands until the next), a
        variable-frame-rate file has gaps. At least once; at most `MAX_VIDEO_REPEAT_S`
        of repeats for one frame, never over `MAX_VIDEO_COPIES`: a stall is shown short,
        the time left out dropped from the video's clock (not spilled onto the frames
        after it, each of which would stand that long again until it was made up)."""
        if self._video_first_stamp_s is None:
            self._video_first_stamp_s = stamp_s
        due = round((stamp_s - self._video_first_stamp_s) * self.fps) + 1
        most = min(max(1, round(MAX_VIDEO_REPEAT_S * self.fps)), MAX_VIDEO_COPIES)
        behind = due - self._video_frames
        copies = min(max(behind, 1), most)
        if behind > most:
            self._video_first_stamp_s += (behind - most) / self.fps
        self._video_frames += copies
        return copies

    def abandon(self) -> None:
        """The output thread is still stuck in `write` (a stalled disk), holding the
        log's or the video's lock: `close` then leaves them to the process's exit rather
        than wait on that lock for ever."""
        self._abandoned = True

    def close(self) -> None:
        """Close the video and the log; a video that fails to close still lets the log
        close (flushed: the run's record is what tells what happened)."""
        if self._abandoned:
            self._warn_left_open()
            return
        failing = sys.exc_info()[1] is not None  # closed on the way out of an error
        try:
            if self._writer is not None:
                self._writer.release()
                self._check_video_readable(raise_error=not failing)
        except BaseException:
            self._close_log(raise_error=False)
            raise
        self._close_log(raise_error=not failing)

    def _close_log(self, raise_error: bool) -> None:
        """Close the log. A failure (a full disk) is only logged while another error is
        on its way out: that one says what went wrong first."""
        if self.log is None:
            return
        try:
            self.log.close()
        except OSError as exc:
            if raise_error:
                raise
            log.error("%s", exc)

    def _warn_left_open(self) -> None:
        left_open = [self.video_path] if self._writer is not None else []
        if self.log is not None:
            left_open.append(str(self.log.path))
        if left_open:
            log.warning("not closing %s: the output thread is still stuck writing (a "
                        "stalled disk?); the end of the file may be lost",
                        " and ".join(left_open))  # fmt: skip

    def _check_video_readable(self, raise_error: bool) -> None:
        """OSError when the closed video holds fewer frames than were written: OpenCV's
        writer reports no failed write, and a short run ends before `_check_video_grows`
        looks (an mp4 cut short by a full disk lacks the index it is opened by, an avi
        the frames after the disk filled). Only logged while another error is on its way
        out: that one says what went wrong first."""
        read_back = frames_read_back(self.video_path, self._video_frames)
        if read_back >= self._video_frames:
            return
        message = (
            f"video {self.video_path} holds {read_back} of the {self._video_frames} frames "
            "written: is the disk full?"
            if read_back
            else f"video {self.video_path} was written but cannot be read back: is the disk full?"
        )
        if raise_error:
            raise OSError(message)
        log.error("%s", message)


def frames_read_back(path: str, written: int) -> int:
    """How many frames of the video at `path` can be read, counted up to `written`: all
    of them when its header counts them and the last one reads (cheap however long the
    video), else counted by grabbing them one by one (a file the disk cut short has no
    count in its header, or one its tail no longer holds); 0 when the first cannot be."""
    capture = cv2.VideoCapture(path)
    try:
        if not (capture.isOpened() and capture.read()[0]):
            return 0
        if _last_frame_reads(capture, written):
            return written
    finally:
        capture.release()
    return _frames_grabbed(path, written)


def _last_frame_reads(capture, written: int) -> bool:
    """Whether a capture whose first frame was read counts `written` frames and reads
    the last of them."""
    if written <= 1:
        return True
    if not capture.get(cv2.CAP_PROP_FRAME_COUNT) >= written:
        return False
    capture.set(cv2.CAP_PROP_POS_FRAMES, written - 1)
    return capture.grab()


def _frames_grabbed(path: str, most: int) -> int:
    """The frames of the video at `path` that can be grabbed in order, up to `most`."""
    capture = cv2.VideoCapture(path)
    try:
        count = 0
        while count < most and capture.grab():
            count += 1
        return count
    finally:
        capture.release()


class RunSummary:
    """What a run reports, kept as counters: O(1) memory however long the run."""

    def __init__(self):
        self.frames = 0
        self.commands = 0
        self.dropped_frames = 0
        self.frames_without_odometry: int | None = None  # threaded runs: skipped, no pose
        self.states: dict[str, int] = {}
        self.final_target_id: int | None = None
        self.capture_to_command_ms: dict | None = None  # threaded runs: median and p95
        self.source_in_use = False  # a capture thread still reads it (a hung camera)

    def add_result(self, result: FrameResult) -> None:
        self.frames += 1
        status = result.target.status.value
        self.states[status] = self.states.get(status, 0) + 1
        self.final_target_id = result.target.target_id

    def add_command(self, command: VelocityCommand) -> None:
        self.commands += 1


def checked_frames(first: Frame, rest, source_name: str, yield_first: bool = True):
    """The frames of a stream, refusing one whose size differs from the first's (the
    camera model and the tracks belong to one image size). A live camera's first frame
    is left out (`yield_first` false): it was read to learn the size before the models
    loaded, seconds before the run, and would be stamped as new when it is not."""
    size = first.image.shape[:2]
    if yield_first:
        yield first
    for index, frame in enumerate(rest, start=1):
        if frame.image.shape[:2] != size:
            h, w = frame.image.shape[:2]
            raise ValueError(
                f"source {source_name}: frame {index} is {w}x{h}, but the stream started at "
                f"{size[1]}x{size[0]}; a size change mid-stream is not supported"
            )
        yield frame


# The outputs OpenCV writes: it crashes the process on a name that is not UTF-8.
OPENCV_OUTPUTS = ("--output-video", "--frames-dir")


def check_output_paths(args) -> None:
    """Refuse, before anything is opened or written, outputs that would overwrite an
    input (the video, camera, configuration or replayed log) or each other, and files
    in folders that do not exist or cannot be written in: found at the end of a run (or
    at its first frame, the base already armed), such a mistake has already cost an
    input or a truncated log."""
    inputs = {"source": args.source, "--camera": args.camera, "--config": args.config,
              "--replay": args.replay}  # fmt: skip
    outputs = {"--output-video": args.output_video, "--log": args.log,
               "--frames-dir": args.frames_dir}  # fmt: skip
    refuse_overwriting(inputs, outputs)
    for name, value in outputs.items():
        if value:
            check_output_path(name, value)


def check_output_path(name: str, value: str) -> None:
    """One output of `check_output_paths`, `name` its option."""
    if name in OPENCV_OUTPUTS:
        refuse_non_utf8_name(value, name)
    path = Path(value).resolve()
    if name == "--frames-dir":
        if path.exists() and not path.is_dir():
            raise ValueError(f"--frames-dir {value} is a file, not a folder")
        # frames are named by index: an earlier run's would stay among this one's
        if path.is_dir() and any(p.stem.isdigit() for p in path.glob("*.jpg")):
            raise ValueError(f"--frames-dir {value} already holds annotated frames of "
                             "another run, which this run's would be mixed with; "
                             "give an empty or new folder")  # fmt: skip
        refuse_unwritable(path / "000000.jpg", name, "the annotated frames go there")
        return
    if path.is_dir():
        raise ValueError(f"{name} {value} is a folder; give a file name")
    if not path.parent.is_dir():
        raise ValueError(f"{name} {value}: the folder {path.parent} does not exist")
    if name == "--output-video" and path.suffix.lower() not in VIDEO_FOURCCS:
        # found at the first frame, after the base was connected, armed and switched
        raise ValueError(f"--output-video {value}: name it .mp4 or .avi (the video "
                         "format follows the name)")  # fmt: skip
    refuse_unwritable(path, name)


def main(args) -> dict:
    if args.max_frames is not None and args.max_frames < 1:
        raise ValueError(f"--max-frames must be >= 1, got {args.max_frames}")
    check_output_paths(args)
    if args.folder_fps is not None and (not Path(args.source).is_dir() or is_bag(args.source)):
        log.warning("--folder-fps is an image folder's frame rate: %s plays at its own",
                    args.source)  # fmt: skip
    args.folder_fps = args.folder_fps or DEFAULT_FOLDER_FPS
    config = Config.load(args.config) if args.config else Config()
    config = base_connection(args, config)
    # a replay opens no base; any MAVLink connection (the simulated rover's too) is one
    drives_base = bool(config.mavlink.connection) and not args.replay
    check_pose_measured(args.camera, drives_base, log.warning)
    if args.replay:
        ignored = [name for name, value in (("--log", args.log), ("--output-video",
                   args.output_video), ("--frames-dir", args.frames_dir),
                   ("--max-frames", args.max_frames), ("--mavlink", args.mavlink),
                   ("--realtime", args.realtime), ("--odom-topic", args.odom_topic),
                   ("--skeletons-topic", args.skeletons_topic)) if value]  # fmt: skip
        if ignored:  # a replay compares a log with the source; it drives, writes, cuts nothing
            raise ValueError(f"--replay takes no {', '.join(ignored)}: it re-runs the whole "
                             "log against its source (with the log's own topics, driving "
                             "no base) and reports whether they agree")  # fmt: skip
        return replay(args, config)
    source = open_source(args.source, args.image_topic, args.odom_topic, args.camera_info_topic,
                         config.ros.max_odometry_age_s, args.skeletons_topic,
                         folder_fps=args.folder_fps)  # fmt: skip
    summary = RunSummary()
    try:  # released on every path, a failure before the run included (a camera stays busy)
        return _run_source(args, config, source, summary)
    finally:
        close_source(source, args.source, summary.source_in_use)


def close_source(source, name: str, in_use: bool) -> None:
    """Release the source, unless the capture thread is still inside a read of it (a
    camera that hangs): releasing it there frees what the read uses (OpenCV's capture is
    not thread-safe); the process's exit releases it instead."""
    if in_use:
        log.warning("source %s: not released, a read of it has not returned; the "
                    "process's exit releases it", name)  # fmt: skip
        return
    source.close()


def close_base(base) -> None:
    """`base.close()` on a helper thread, waited for BASE_CLOSE_WAIT_S at most: a base
    whose close hangs (a third-party driver stuck on its link) must not hang `follow
    run`'s exit nor keep the outputs from closing; the control loop's last zero went out
    before. An error that close raises in time is raised here, as from this thread."""
    wait_s, failure = BASE_CLOSE_WAIT_S, []

    def close() -> None:
        try:
            base.close()
        except Exception as exc:
            failure.append(exc)

    if not stop_within(close, wait_s, name="base-close"):
        log.warning("base %s has not closed after %g s: going on without it (the "
                    "process's exit ends it)", type(base).__name__, wait_s)  # fmt: skip
    elif failure:
        raise failure[0]


def base_connection(args, config: Config) -> Config:
    """The configuration with the base the command line asks for: `--mavlink` over the
    configuration's connection, `--no-base` none at all (a configuration that names the
    robot's base, checked on the view first, must not switch it to guided and drive)."""
    if args.no_base and args.mavlink:
        raise ValueError("--no-base and --mavlink contradict each other: give one")
    if args.no_base:
        return config.replace("mavlink", connection="")
    if args.mavlink:
        return config.replace("mavlink", connection=args.mavlink)
    return config


def source_camera(camera_file, source, width: int, height: int) -> CameraModel:
    """The camera model of a run: the camera file, with a bag's CameraInfo over it where
    the bag has one, scaled to the frames' size."""
    camera = CameraModel.load(camera_file)
    if getattr(source, "camera_info", None) is not None:
        from follow.rosmsg import camera_from_info

        camera = camera_from_info(source.camera_info, camera)
    return camera_for_frames(camera, width, height)


def _run_source(args, config: Config, source, summary: RunSummary) -> dict:
    """`main` on an opened source, which the caller closes."""
    bag_odometry = source.odometry_at if getattr(source, "odometry", None) is not None else None
    if bag_odometry and (args.realtime or config.mavlink.connection):
        raise ValueError("a bag's odometry is replayed frame by frame only: leave out "
                         "--realtime and the MAVLink connection (--mavlink or "
                         "[mavlink] connection in the configuration)")  # fmt: skip
    frames = iter(source)
    first = next(frames, None)
    if first is None:
        raise ValueError(f"source {args.source}: no frames")
    height, width = first.image.shape[:2]
    camera = source_camera(args.camera, source, width, height)
    log_person_in_view(camera, config)
    detect = source.recorded_skeletons if args.skeletons_topic else None
    perception = build_perception(config, camera, detect)
    if args.target_id is not None:
        perception.identifier.select_target(
            args.target_id, missing_warn_s=config.control.missing_target_warn_s
        )
    header = {"source": args.source, "camera": str(args.camera), "config": args.config,
              "image_size": [width, height], "target_id": args.target_id,
              "image_topic": args.image_topic, "odom_topic": args.odom_topic,
              "camera_info_topic": args.camera_info_topic}  # fmt: skip
    elapsed = None  # the frames' time: not the base's connection, nor the closing
    with ShutdownSignals() as signals:
        base = outputs = None
        try:
            # the base first: a connection that fails must not have emptied a log or a
            # video of the same name (an earlier run's, perhaps an incident's only record)
            base = open_base(config)
            signals.base = base
            outputs = Outputs(header, source.fps, args.output_video, args.frames_dir, args.log)
            frames = checked_frames(first, frames, args.source, yield_first=not source.live)
            started = time.perf_counter()
            try:
                run_frames(args, config, source, frames,
                           perception, camera, base, outputs, summary,
                           bag_odometry)  # fmt: skip
            finally:
                elapsed = time.perf_counter() - started
        except KeyboardInterrupt:
            log.warning("%s: stopping the base", signals.reason or "interrupted")
        finally:
            signals.cleaning_up = True  # a signal now is recorded, not raised in here
            try:
                if base is not None:
                    close_base(base)
            finally:
                if outputs is not None:
                    outputs.close()
    dropped = summary.dropped_frames
    result = {
        "frames": summary.frames,
        "dropped_frames": dropped,
        "fps": round(summary.frames / elapsed, 2) if elapsed else None,
        "states": summary.states,
        "final_target_id": summary.final_target_id,
        "commands": summary.commands,
        "stopped_by": signals.reason,
    }
    if summary.capture_to_command_ms is not None:
        result["capture_to_command_ms"] = summary.capture_to_command_ms
    without_odometry = getattr(source, "frames_without_odometry", summary.frames_without_odometry)
    if without_odometry is not None:
        result["frames_without_odometry"] = without_odometry
    damaged = getattr(source, "damaged_images", 0)  # a bag's image messages that do not decode
    if damaged:
        result["damaged_images"] = damaged
    skipped_images = getattr(source, "skipped_images", None)  # a bag's, by reason
    if skipped_images is not None:
        result["skipped_images"] = dict(skipped_images)
    if not args.json:
        skipped = f", {without_odometry} without odometry" if without_odometry else ""
        skipped += f", {damaged} damaged" if damaged else ""
        print(f"{summary.frames} frames at {result['fps']} fps "
              f"({dropped} dropped{skipped}); states: {summary.states}")  # fmt: skip
        latency = summary.capture_to_command_ms
        if latency and latency["median"] is not None:
            print(f"capture to command: median {latency['median']} ms, p95 {latency['p95']} ms")
    return result


def run_frames(args, config, source, frames, perception, camera, base, outputs, summary,
               bag_odometry=None) -> None:  # fmt: skip
    """The loop: threads (a live source, `--realtime`, or any run driving a base: a file
    is then played at its own stamps, with the watchdog) or, for a file without a base,
    every frame in order."""
    from follow.control.base import NullBase
    from follow.control.controller import FollowingController
    from follow.control.odometry import OdometryPolicy
    from follow.control.target import ViewCone

    view = ViewCone.from_camera(camera)
    if source.live or args.realtime or not isinstance(base, NullBase):
        runner = build_runner(perception, base, config.control, view,
                              on_command=summary.add_command)  # fmt: skip

        def on_result(frame, result):
            summary.add_result(result)
            # the outputs' own thread: waiting for the control loop holds up no frame
            command = runner.control.command_from(result, COMMAND_WAIT_S)
            outputs.write(frame, result, command)

        if not source.live:
            frames = played_at_own_stamps(frames)
        try:
            runner.run(frames, on_result=on_result, max_frames=args.max_frames,
                       stall_timeout_s=(config.control.camera_stall_timeout_s
                                        if source.live else None))  # fmt: skip
        finally:
            summary.dropped_frames = runner.dropped_frames
            summary.frames_without_odometry = runner.skipped_without_odometry
            summary.capture_to_command_ms = runner.control.latency.summary_ms()
            summary.source_in_use = runner.capture_running
            if runner.outputs_stuck:
                outputs.abandon()
        return
    controller = FollowingController(config.control, view=view)
    # NullBase: the camera is still, a fixed pose; a bag: its recorded pose at each image
    odometry = bag_odometry or OdometryPolicy(base)
    jumps = source.odometry.jumps if bag_odometry else None  # the bag's, for the tracker
    for frame, result, command in run_offline(perception, frames, controller, odometry, jumps):
        base.send(command)
        summary.add_command(command)
        if result is None:
            continue
        summary.add_result(result)
        outputs.write(frame, result, command)
        if args.max_frames and summary.frames >= args.max_frames:
            break


def _same_path(logged, given) -> bool:
    """Whether a path named in a log's header and one given now are the same: the same
    text, or two existing paths to one file."""
    if str(logged) == str(given):
        return True
    return (Path(str(logged)).exists() and Path(given).exists()
            and Path(str(logged)).resolve() == Path(given).resolve())  # fmt: skip


def check_replay_source(header: dict, log_path: str, source: str) -> None:
    """Refuse to replay a log against another source than the one it was made from (the
    skeletons would be compared with other frames, and agree by chance)."""
    logged = header.get("source")
    if logged is None:
        raise ValueError(f"--replay {log_path}: the log's header names no source")
    if _same_path(logged, source):
        return
    if Path(str(logged)).name == Path(source).name and Path(source).exists():
        # recorded from another folder (a path relative to where the run was started) or
        # moved since: the frames' sizes and numbers are checked as they are replayed
        log.warning("--replay %s: the log was recorded from %s; replaying %s, a file of "
                    "the same name", log_path, logged, source)  # fmt: skip
        return
    raise ValueError(f"--replay {log_path}: the log is of source {logged}, not {source}")


def warn_if_other_camera(header: dict, camera: str | Path) -> None:
    """A replay through another camera file than the run's is allowed (a new calibration
    tried on old data), but its tracks will differ from the run's for that reason alone."""
    logged = header.get("camera")
    if logged is None or _same_path(logged, camera):
        return
    log.warning("replaying through camera file %s; the run used %s: tracks and targets may "
                "differ for that alone", camera, logged)  # fmt: skip


def replay_target_id(header: dict, log_path: str, asked: int | None) -> int | None:
    """The track the replay selects: the run's own `--target-id` (in the log's header),
    which a replay without one used to leave out, so its targets disagreed with the
    run's from the first frame; `--target-id` given here must be the same."""
    logged = header.get("target_id")
    if logged is not None and (isinstance(logged, bool) or not isinstance(logged, int)):
        raise ValueError(f"--replay {log_path}: the header's target_id {logged!r} is no track id")
    if asked is not None and logged is not None and asked != logged:
        raise ValueError(
            f"--replay {log_path}: the run selected track {logged}, not --target-id {asked}"
        )
    return asked if asked is not None else logged


def replay_config(header: dict, log_path: str) -> Config:
    """The configuration of a replay given no `--config`: the run's own (named in the
    log's header); with the defaults in its place, a run made with other tracker or
    identifier settings disagreed with its replay."""
    logged = header.get("config")
    if logged is None:
        return Config()
    if not isinstance(logged, str) or not Path(logged).is_file():
        raise ValueError(f"--replay {log_path}: the run's configuration {logged!r} (named in "
                         "the log's header) is not there; give it with --config")  # fmt: skip
    return Config.load(logged)


def check_replay_stamp(log_path: str, source: str, record, stamp_s: float) -> None:
    """Refuse a record whose frame of the source is another image than the run's: one
    image more or less (a bag replayed with another `[ros] max_odometry_age_s`, a folder
    at another `--folder-fps`) paired every later record with the wrong image, silently.
    The log keeps stamps to 1e-6 s; beyond 1e9 s, a float's own precision counts too."""
    if abs(record.stamp_s - stamp_s) <= max(1e-6, 1e-15 * abs(stamp_s)):
        return
    index = record.frame_index
    raise ValueError(
        f"--replay {log_path}: the log's frame {index} is stamped {record.stamp_s:.6f} s, "
        f"but frame {index} of {source} is stamped {stamp_s:.6f} s: the source does not "
        "give the frames the run read (another [ros] max_odometry_age_s or --folder-fps, "
        "or another file?)"
    )


def bag_odometry_jumps(source):
    """The log of a bag's odometry jumps (None for another source), which a bag's run
    gives its tracker: without it, a replay took a reset of the odom frame for motion,
    and its targets disagreed with the run's although nothing had changed."""
    odometry = getattr(source, "odometry", None)
    return None if odometry is None else odometry.jumps


def replay(args, config: Config) -> dict:
    """Tracking and identification again on a log's skeletons and the same frames."""
    header, records = read_run_log(args.replay)
    check_replay_source(header, args.replay, args.source)
    warn_if_other_camera(header, args.camera)
    target_id = replay_target_id(header, args.replay, args.target_id)
    if not args.config:
        config = replay_config(header, args.replay)
    # the log is read a record at a time as the frames reach it: its records are in the
    # order of their frames, each frame without one (skipped by the run) is skipped again
    record = next(records, None)
    if record is None:  # not the source's fault: say so before opening it
        raise ValueError(f"the log {args.replay} holds no frame records")
    # The log holds the robot's poses; a bag's odometry is read again only so that the
    # images the run skipped for want of it are skipped again, and frame numbers agree.
    # The bag's image and camera-info topics are the run's unless given again.
    source = open_source(args.source, args.image_topic or header.get("image_topic"),
                         header.get("odom_topic"),
                         args.camera_info_topic or header.get("camera_info_topic"),
                         config.ros.max_odometry_age_s, folder_fps=args.folder_fps)  # fmt: skip
    camera = None
    perception = None
    agree = total = 0
    current: list = [[]]  # the logged skeletons of the frame being replayed
    try:
        if source.live:
            raise ValueError(f"--replay {args.replay}: {args.source} is a live camera; a "
                             "replay needs the recorded frames (a file, folder or bag)")  # fmt: skip
        for index, frame in enumerate(source):
            if record is None:
                break  # the log has ended: the rest of the source has nothing to replay
            if record.frame_index > index:
                continue
            if record.frame_index < index:  # a frame logged twice, back in time or below 0
                after = f"after frame {index - 1}" if index else "below 0"
                raise ValueError(f"--replay {args.replay}: the log's frame "
                                 f"{record.frame_index} is out of order ({after})")  # fmt: skip
            if camera is None:
                h, w = frame.image.shape[:2]
                logged = header.get("image_size")
                if logged is not None and list(logged) != [w, h]:
                    raise ValueError(
                        f"--replay {args.replay}: the log is of {logged[0]}x{logged[1]} "
                        f"frames, but {args.source} has {w}x{h} frames"
                    )
                camera = source_camera(args.camera, source, w, h)
                perception = build_perception(config, camera, detect=lambda f: current[0])
                perception.odometry_jumps = bag_odometry_jumps(source)
                if target_id is not None:
                    perception.identifier.select_target(target_id)
            check_replay_stamp(args.replay, args.source, record, frame.stamp_s)
            current[0] = record.skeletons
            robot = record.robot or Odometry.origin(record.stamp_s)
            result = perception.process(Frame(frame.image, record.stamp_s), robot, index)
            total += 1
            agree += int(result.target.target_id == record.target_id)
            record = next(records, None)
    finally:
        source.close()
    # The source ended first: the rest of the log is still checked, and counted, so that
    # a replay of part of the run (a cut video) does not pass for the whole of it.
    first_left = None if record is None else record.frame_index
    left = (record is not None) + sum(1 for _ in records)
    if total == 0:
        raise ValueError(f"log {args.replay}: no frame of it found in {args.source}")
    if left:
        log.warning("--replay %s: %d logged frames, from frame %d on, lie past the end of %s: "
                    "not replayed", args.replay, left, first_left, args.source)  # fmt: skip
    summary = {"frames": total, "target_agreement": round(agree / total, 4), "not_replayed": left}
    if not args.json:
        print(
            f"replayed {total} frames: the same target in {100 * agree / total:.1f} %"
            + (f"; {left} logged frames past the source's end not replayed" if left else "")
        )
    return summary
