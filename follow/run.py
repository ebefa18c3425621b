"""`follow run`: follow a person from a camera or a video, optionally driving a base.

Live sources (a camera index or a GStreamer pipeline) and `--realtime` run capture,
perception and control in their own threads on the wall clock. A file without
`--realtime` is processed frame by frame, every frame, reproducibly. Ctrl-C or an error
sends the base a zero command and flushes the log.
"""

from __future__ import annotations

import logging
import time
from pathlib import Path

import cv2
import numpy as np

from follow.camera import CameraModel
from follow.capture import FrameSource, LatestSlot, open_source
from follow.config import Config
from follow.pipeline import ControlLoop, FrameResult, Perception, ThreadedRunner, run_offline
from follow.render import annotate, top_down
from follow.runlog import RunLogWriter, read_run_log
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
    p.add_argument("--camera", required=True, help="camera file (YAML/JSON, from follow-calib)")
    p.add_argument("--config", help="TOML configuration (defaults: the paper's values)")
    p.add_argument("--mavlink", help="MAVLink connection string, e.g. udpin:0.0.0.0:14550")
    p.add_argument("--target-id", type=int, help="follow this track id instead of the nearest")
    p.add_argument("--output-video", help="write the annotated video here (.mp4 or .avi)")
    p.add_argument("--frames-dir", help="write annotated frames (with a top-down view) here")
    p.add_argument("--log", help="write a JSON-lines log of every frame here")
    p.add_argument(
        "--realtime", action="store_true", help="play a file at its frame rate with threads"
    )
    p.add_argument("--max-frames", type=int, help="stop after this many frames")
    p.add_argument(
        "--replay",
        metavar="LOG",
        help="re-run tracking and identification on the skeletons of a log and the same "
        "source, and report whether the targets agree",
    )


def build_perception(config: Config, camera: CameraModel, detect=None) -> Perception:
    """The standard stack: pose network (unless `detect` is given), UKF, identifier."""
    from follow.boost.factory import build_identifier
    from follow.pose.observations import skeletons_to_observations
    from follow.ukf.tracker import PeopleTracker

    if detect is None:
        from follow.pose.detector import PoseDetector

        detector = PoseDetector(config.pose)

        def detect(frame: Frame):
            return detector.detect(frame.image)

    def to_observations(skeletons):
        return skeletons_to_observations(skeletons, camera.image_size, config.pose)

    return Perception(
        detect,
        to_observations,
        PeopleTracker(camera, config.tracker),
        build_identifier(config.identify),
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
            self.frames_dir.mkdir(parents=True, exist_ok=True)
        self.fps = fps
        self._writer = None
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
                fourcc = cv2.VideoWriter_fourcc(*("mp4v" if self.video_path.endswith(".mp4") else "MJPG"))
                self._writer = cv2.VideoWriter(
                    self.video_path, fourcc, self.fps, (canvas.shape[1], canvas.shape[0])
                )
                if not self._writer.isOpened():
                    raise OSError(f"cannot write video {self.video_path}")
            self._writer.write(canvas)
        if self.frames_dir:
            cv2.imwrite(str(self.frames_dir / f"{result.frame_index:06d}.jpg"), canvas)

    def close(self) -> None:
        if self._writer is not None:
            self._writer.release()
        if self.log is not None:
            self.log.close()


def main(args) -> dict:
    config = Config.load(args.config) if args.config else Config()
    if args.mavlink:
        config = config.replace("mavlink", connection=args.mavlink)
    if args.replay:
        return replay(args, config)
    source = open_source(args.source, args.image_topic, args.odom_topic, args.camera_info_topic,
                         config.ros.max_odometry_age_s, args.skeletons_topic)  # fmt: skip
    bag_odometry = source.odometry_at if getattr(source, "odometry", None) is not None else None
    if bag_odometry and args.realtime:
        raise ValueError("--realtime does not replay a bag's odometry; leave it out")
    frames = iter(source)
    first = next(frames, None)
    if first is None:
        raise ValueError(f"source {args.source}: no frames")
    height, width = first.image.shape[:2]
    camera = CameraModel.load(args.camera)
    if getattr(source, "camera_info", None) is not None:
        from follow.rosmsg import camera_from_info

        camera = camera_from_info(source.camera_info, camera)
    camera = camera_for_frames(camera, width, height)
    detect = source.recorded_skeletons if args.skeletons_topic else None
    perception = build_perception(config, camera, detect)
    if args.target_id is not None:
        perception.identifier.select_target(args.target_id)

    def all_frames():
        yield first
        yield from frames

    header = {"source": args.source, "camera": str(args.camera), "config": args.config,
              "image_size": [width, height]}  # fmt: skip
    outputs = Outputs(header, source.fps, args.output_video, args.frames_dir, args.log)
    base = open_base(config)
    from follow.control.controller import FollowingController

    controller = FollowingController(config.control)
    results: list[FrameResult] = []
    commands: list[VelocityCommand] = []
    started = time.perf_counter()
    dropped = 0
    try:
        if source.live or args.realtime:
            slot = LatestSlot()
            control = ControlLoop(
                controller, base, slot, config.control.control_rate_hz,
                config.control.target_timeout_s, on_command=commands.append,
            )  # fmt: skip
            runner = ThreadedRunner(perception, control, base)

            def on_result(frame, result):
                results.append(result)
                outputs.write(frame, result, control.last_command)

            runner.run(all_frames(), pace_hz=None if source.live else source.fps,
                       on_result=on_result, max_frames=args.max_frames)  # fmt: skip
            dropped = runner.dropped_frames
        else:
            for count, (frame, result, command) in enumerate(
                run_offline(perception, all_frames(), controller, bag_odometry), start=1
            ):
                base.send(command)
                commands.append(command)
                results.append(result)
                outputs.write(frame, result, command)
                if args.max_frames and count >= args.max_frames:
                    break
    except KeyboardInterrupt:
        log.warning("interrupted: stopping the base")
    finally:
        base.close()
        outputs.close()
        source.close()
    elapsed = time.perf_counter() - started
    states: dict[str, int] = {}
    for r in results:
        states[r.target.status.value] = states.get(r.target.status.value, 0) + 1
    summary = {
        "frames": len(results),
        "dropped_frames": dropped,
        "fps": round(len(results) / elapsed, 2) if elapsed > 0 else None,
        "states": states,
        "final_target_id": results[-1].target.target_id if results else None,
        "commands": len(commands),
    }
    if hasattr(source, "frames_without_odometry"):
        summary["frames_without_odometry"] = source.frames_without_odometry
    if not args.json:
        print(f"{summary['frames']} frames at {summary['fps']} fps "
              f"({dropped} dropped); states: {states}")  # fmt: skip
    return summary


def replay(args, config: Config) -> dict:
    """Tracking and identification again on a log's skeletons and the same frames."""
    header, records = read_run_log(args.replay)
    records = list(records)
    by_index = {r.frame_index: r for r in records}
    source = FrameSource(args.source)
    camera = None
    perception = None
    agree = total = 0
    current: list = [[]]  # the logged skeletons of the frame being replayed
    try:
        for index, frame in enumerate(source):
            record = by_index.get(index)
            if record is None:
                continue
            if camera is None:
                h, w = frame.image.shape[:2]
                camera = camera_for_frames(CameraModel.load(args.camera), w, h)
                perception = build_perception(config, camera, detect=lambda f: current[0])
                if args.target_id is not None:
                    perception.identifier.select_target(args.target_id)
            current[0] = record.skeletons
            robot = record.robot or Odometry.origin(record.stamp_s)
            result = perception.process(Frame(frame.image, record.stamp_s), robot, index)
            total += 1
            agree += int(result.target.target_id == record.target_id)
    finally:
        source.close()
    if total == 0:
        raise ValueError(f"log {args.replay}: no frame of it found in {args.source}")
    summary = {"frames": total, "target_agreement": round(agree / total, 4)}
    if not args.json:
        print(f"replayed {total} frames: the same target in {100 * agree / total:.1f} %")
    return summary
