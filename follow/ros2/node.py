"""The `follow` ROS 2 node: camera images and odometry in; the target for Nav2's
following server, every track, the identifier's state and diagnostics out; optionally
cmd_vel from the project's own controller.

It runs the same stack as `follow run` (`build_perception`, `Perception`, the
`FollowingController` in the shared `ControlLoop`) on threads of its own, so the executor
keeps taking odometry and requests while a frame is processed: the pose network on the
newest image, and (with `[control] overlap_stages`) tracking, identification and the
publishers of the previous image beside it, in order. Safety as in
`follow run`: an image older than `max_image_age_s`, odometry older than
`max_odometry_age_s`, a lost target or a stop request give a zero cmd_vel, and so does
shutdown (SIGINT, SIGTERM or SIGHUP; a second signal while it shuts down publishes zero
and exits at once); a camera file whose pose is a placeholder, not measured,
publishes no cmd_vel at all (the node refuses to start with `ros.publish_cmd_vel`).
"""

from __future__ import annotations

import dataclasses
import logging
import os
import signal
import statistics
import threading
import time
from collections import deque

import rclpy
from geometry_msgs.msg import PoseArray, PoseStamped, Twist
from nav_msgs.msg import Odometry as OdometryMsg
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
from rclpy.signals import SignalHandlerOptions
from sensor_msgs.msg import CameraInfo, CompressedImage, Image
from std_msgs.msg import Int32, String
from std_srvs.srv import Trigger
from visualization_msgs.msg import MarkerArray

from follow.camera import CameraModel, check_pose_measured
from follow.capture import LatestSlot
from follow.config import Config, ConfigError
from follow.freshness import is_ahead
from follow.handoff import Handoff
from follow.odometry_buffer import OdometryBuffer
from follow.pipeline import ControlLoop, FrameResult, overlaps_stages
from follow.repeated_image import RepeatedImages
from follow.ros2 import messages
from follow.ros2.gate import CmdVelGate, ReselectableController, check_ros_config
from follow.rosmsg import (
    camera_from_info,
    camera_info_key,
    image_fields,
    image_from_msg,
    odometry_from_msg,
    stamp_s,
)
from follow.shutdown import SIGNALS, stop_within
from follow.types import Frame, InvalidInput, Odometry, TargetStatus, VelocityCommand

log = logging.getLogger(__name__)

NODE_NAME = "follow"
ODOMETRY_QUEUE = 50  # odometry messages held while the executor is busy
SILENT_TOPIC_WARNING_S = 5.0  # how often a topic that delivered nothing yet is named
CLOCK_STEP_S = 1.0  # an image this much older than the last one: a clock went back
HOST_SIGNALS_FIX = (
    "A process hosting FollowNode with ros.publish_cmd_vel must call "
    "rclpy.init(signal_handler_options=SignalHandlerOptions.NO), handle SIGINT and SIGTERM "
    "itself and call destroy_node() before rclpy.shutdown(), as follow.ros2.node.run "
    "(`follow ros2`) does"
)


def parameters_over(node: Node, config: Config) -> Config:
    """Every config key declared as a ROS parameter `section.key` (default: the TOML's
    value); the values the node was started with override the TOML."""
    from rcl_interfaces.msg import ParameterDescriptor
    from rclpy.exceptions import ParameterException

    changed: dict[str, dict] = {}
    declared: list[str] = []
    for section in dataclasses.fields(config):
        values = getattr(config, section.name)
        for field in dataclasses.fields(values):
            default, name = getattr(values, field.name), f"{section.name}.{field.name}"
            declared.append(name)
            # a key of two types (`overlap_stages`: "auto", true or false) takes either
            either = ParameterDescriptor(dynamic_typing="|" in str(field.type))
            try:
                value = node.declare_parameter(name, default, either).value
            except ParameterException as exc:
                raise ConfigError(f"ROS parameter {name}: {exc}") from None
            if value != default:
                changed.setdefault(section.name, {})[field.name] = value
    _refuse_unknown_parameters(node, declared)
    _refuse_changes(node, declared)
    return Config.from_dict(changed, source="ROS parameters", base=config)


def _refuse_unknown_parameters(node: Node, declared: list[str]) -> None:
    """A `-p` override that names no parameter (a typo: `control.max_forwrd_speed_mps`)
    would otherwise be dropped in silence and the default used."""
    import difflib

    overrides = getattr(node, "_parameter_overrides", {})  # rclpy keeps them here
    unknown = [name for name in overrides
               if not node.has_parameter(name) and not name.startswith("qos_overrides.")]  # fmt: skip
    if unknown:
        hints = [f"{name} (did you mean {close[0]}?)" if close else name for name in unknown
                 for close in [difflib.get_close_matches(name, declared, n=1)]]  # fmt: skip
        raise ConfigError(f"unknown ROS parameter(s): {', '.join(hints)}")


def _refuse_changes(node: Node, declared: list[str]) -> None:
    """The configuration is read once, at start-up: a `ros2 param set` of one of its
    keys would report success (unchecked, e.g. out of range) and change nothing, say
    `ros.publish_cmd_vel` turned off while the node drives on."""
    from rcl_interfaces.msg import SetParametersResult

    names = set(declared)

    def refuse(parameters) -> SetParametersResult:
        fixed = [p.name for p in parameters if p.name in names]
        if not fixed:
            return SetParametersResult(successful=True)
        return SetParametersResult(successful=False, reason=(
            f"{', '.join(fixed)}: read at start-up only; restart the node with "
            "-p section.key:=value"))  # fmt: skip

    node.add_on_set_parameters_callback(refuse)


def _describe(key: tuple | None) -> str:
    if key is None:
        return "no image yet"
    width, height, info = key
    if info is None:
        return f"{width}x{height} images"
    info_width, info_height, model, k, d = info
    return (f"{width}x{height} images, camera_info {info_width}x{info_height} {model or 'no'} "
            f"distortion, fx {k[0]:g} fy {k[4]:g} cx {k[2]:g} cy {k[5]:g}, d {list(d)}")  # fmt: skip


def perception_status(processed_recently: bool, failed_frames: int,
                      last_error: str | None) -> tuple[bool, str]:  # fmt: skip
    """The diagnostics' level (OK or not) and message for one period: where frames fail,
    the message names the newest failure, so an operator sees why nothing gets through
    rather than only that nothing does."""
    if not failed_frames:
        return (
            processed_recently,
            "running" if processed_recently else "no frames processed recently",
        )
    failures = f"{failed_frames} frame(s) failed since the last report, the newest: {last_error}"
    return processed_recently, f"running; {failures}" if processed_recently else failures


class FollowNode(Node):
    """Subscribes, runs perception and control, publishes (see the module doc)."""

    def __init__(self, config: Config, mounted: CameraModel, detect=None, camera_file=None):
        super().__init__(NODE_NAME)
        self.config = parameters_over(self, config)
        ros = self.config.ros
        check_ros_config(ros)
        if camera_file is not None:  # the file `mounted` was read from: a measured pose?
            check_pose_measured(camera_file, ros.publish_cmd_vel, self.get_logger().warning)
        if ros.publish_cmd_vel:
            check_host_signals(self.get_logger())
        self.mounted = mounted
        self.model_name = "given detector"
        self._pose_backend: str | None = None
        if detect is None:
            from follow.pose.detector import PoseDetector
            from follow.pose.input_size import pose_config_for_camera

            # warmed up at the camera's image size, every input height it may run at
            detector = PoseDetector(pose_config_for_camera(self.config.pose, mounted),
                                    frame_size=mounted.image_size)  # fmt: skip
            self.model_name = f"{detector.model_path.name} on {detector.backend_name}"
            self._pose_backend = detector.backend_name

            def detect(frame: Frame):
                return detector.detect(frame.image)

        self._detect = detect
        self.perception = None
        self._pending_target: int | None = None  # selected, not yet taken by the identifier
        self._lock = threading.Lock()  # perception: the pose thread vs the one concluding
        # The operator's requests and what they change; held for no frame, so a request
        # never waits for perception.
        self._choice_lock = threading.Lock()
        self.following = True
        self._choices = 0  # operator's choices (select, stop) so far, changed under _choice_lock
        self.camera_info = None
        self.odometry = OdometryBuffer(ros.max_odometry_age_s) if ros.odom_topic else None
        self.frames = 0
        self.images_received = 0  # messages on ros.image_topic, whatever became of them
        self.odometry_received = 0  # messages on ros.odom_topic
        self.frames_without_odometry = 0
        self.odometry_dropped = 0  # odometry messages in another frame or unusable
        self._camera_key: tuple | None = None  # the image size and camera_info perceived with
        self.stale_frames = 0  # images unstamped, out of order, ahead, or repeated
        self.errors = 0
        self.last_error: str | None = None  # the newest frame failure, for the diagnostics
        self._errors_reported = 0
        self._last_stamp: float | None = None
        self._repeats = RepeatedImages()
        self._recent: deque = deque(maxlen=300)  # (wall time, timing_ms) per frame
        self._images = LatestSlot()
        self.results = LatestSlot()  # newest FrameResult for the control loop

        self._make_publishers()
        self._make_subscriptions()
        self.gate: CmdVelGate | None = None
        self.control: ControlLoop | None = None
        if ros.publish_cmd_vel:
            self.gate = CmdVelGate(self._publish_twist, self.now_s, ros.max_odometry_age_s)
            self.control = ControlLoop(
                ReselectableController(self.config.control), self.gate, self.results,
                self.config.control.control_rate_hz, ros.max_image_age_s, clock=self.now_s,
            )  # fmt: skip
        self.create_timer(ros.diagnostics_period_s, self._publish_diagnostics)
        self._stopping = threading.Event()
        # With the stages overlapped (`overlap_stages`; "auto": a GPU runs the network)
        # the pose network infers the next image on this thread while the previous one is
        # tracked, identified and published on another.
        overlap = overlaps_stages(self.config.control.overlap_stages, self._pose_backend)
        self._handoff = Handoff() if overlap else None
        self._workers = [threading.Thread(target=self._perceive, name="pose", daemon=True)]
        if self._handoff is not None:
            self._workers.append(
                threading.Thread(target=self._conclude_handed, name="perception", daemon=True)
            )
        for worker in self._workers:
            worker.start()
        if self.control is not None:
            self.control.start()
        self.get_logger().info(
            f"following people in {ros.image_topic} ({self.model_name}); "
            f"cmd_vel {'on ' + ros.cmd_vel_topic if ros.publish_cmd_vel else 'off'}"
        )

    # ------------------------------------------------------------------ wiring
    def _make_publishers(self) -> None:
        self.pub_target = self.create_publisher(PoseStamped, "~/target", 10)
        self.pub_tracks = self.create_publisher(PoseArray, "~/tracks", 10)
        self.pub_markers = self.create_publisher(MarkerArray, "~/track_markers", 10)
        self.pub_state = self.create_publisher(String, "~/target_state", 10)
        self.pub_image = None
        if self.config.ros.publish_annotated_image:
            self.pub_image = self.create_publisher(Image, "~/image_annotated", 2)
        from diagnostic_msgs.msg import DiagnosticArray

        self.pub_diagnostics = self.create_publisher(DiagnosticArray, "/diagnostics", 10)
        self.pub_cmd_vel = self.create_publisher(Twist, self.config.ros.cmd_vel_topic, 10)

    def _make_subscriptions(self) -> None:
        ros = self.config.ros
        image_type = CompressedImage if ros.image_topic.endswith("/compressed") else Image
        # Best effort takes images from reliable and best-effort publishers alike.
        self.create_subscription(image_type, ros.image_topic, self._on_image_msg,
                                 qos_profile_sensor_data)  # fmt: skip
        if ros.camera_info_topic:
            self.create_subscription(CameraInfo, ros.camera_info_topic, self._on_camera_info,
                                     qos_profile_sensor_data)  # fmt: skip
        if ros.odom_topic:
            odometry_qos = QoSProfile(
                depth=ODOMETRY_QUEUE, reliability=ReliabilityPolicy.BEST_EFFORT
            )
            self.create_subscription(OdometryMsg, ros.odom_topic, self._on_odometry, odometry_qos)
        self.create_subscription(Int32, "~/select_target", self._on_select_target, 10)
        self.create_service(Trigger, "~/stop_following", self._on_stop_following)

    def now_s(self) -> float:
        return self.get_clock().now().nanoseconds * 1e-9

    # ------------------------------------------------------------------ inputs
    def _on_image_msg(self, msg) -> None:
        self.images_received += 1
        self._images.put(msg)

    def _on_camera_info(self, msg) -> None:
        self.camera_info = msg

    def _on_odometry(self, msg) -> None:
        """A pose in `ros.odom_frame` (the frame tracks are kept and published in); one in
        another frame, unusable (NaN, no orientation), unstamped or stamped ahead of the node's
        clock (never fresh, `follow.freshness`) is dropped with a warning: the odometry
        then goes stale and the base stops, but the node lives on."""
        self.odometry_received += 1
        odom_frame = self.config.ros.odom_frame
        frame_id = str(msg.header.frame_id)
        if frame_id and frame_id.lstrip("/") != odom_frame.lstrip("/"):
            self.odometry_dropped += 1
            self.get_logger().warning(
                f"odometry dropped: in frame {frame_id!r}, not ros.odom_frame {odom_frame!r} "
                "(set ros.odom_frame to the odometry's frame)", throttle_duration_sec=5.0,
            )  # fmt: skip
            return
        try:
            pose = odometry_from_msg(msg)
        except InvalidInput as exc:
            self.odometry_dropped += 1
            self.get_logger().warning(f"odometry dropped: {exc}", throttle_duration_sec=5.0)
            return
        if pose.stamp_s == 0.0:  # never fresh: the base would stop with no word of why
            self.odometry_dropped += 1
            self.get_logger().warning(
                "odometry dropped: its header has no stamp (zero): the base driver must "
                "stamp each pose with its time", throttle_duration_sec=5.0,
            )  # fmt: skip
            return
        now = self.now_s()
        if is_ahead(now, pose.stamp_s):
            self.odometry_dropped += 1
            self.get_logger().warning(
                f"odometry dropped: stamped {pose.stamp_s - now:.2f} s ahead of the node's "
                "clock (the base driver's clock disagrees: synchronise the clocks)",
                throttle_duration_sec=5.0,
            )  # fmt: skip
            return
        self.odometry.add(pose)
        if self.gate is not None:
            self.gate.update_odometry(pose)

    def _on_select_target(self, msg) -> None:
        """A track id to follow; a negative id: the nearest person again. The newest
        result tracks the target chosen before: it is dropped (the base stops) until a
        frame is concluded with the new choice, so the robot never drives on toward the
        person the operator just chose against, not even for a command being computed from
        it at this moment; and the controller forgets that target until the new one is
        tracked (no search turn toward where it was last seen). All at once: the
        identifier takes the choice before the next frame (`_take_choice`), so neither
        this nor a request queued behind it waits for the frame being processed."""
        with self._choice_lock:
            self._drop_the_chosen_against()
            self.following = True
            self._choices += 1
            self._pending_target = msg.data
            if self.gate is not None:
                self.gate.following = True
        self.get_logger().info(f"target selected: {msg.data if msg.data >= 0 else 'nearest'}")

    def _drop_the_chosen_against(self) -> None:
        """The newest result dropped and the controller's target forgotten: the control
        loop sends zero from its next tick (a tick under way too) until a frame concluded
        with the new choice tracks its target."""
        if self.control is not None:
            # first: a tick that takes the emptied slot must not search for the old one
            self.control.controller.forget_target()
            self.control.clear_result()
        else:
            self.results.put(None)

    def _on_stop_following(self, request, response):
        """Zero on cmd_vel at once, and for every command after it: neither step waits
        for the frame being tracked and identified (the perception lock, held for tens of
        ms, hundreds on a slow CPU). The node's callbacks share one mutually exclusive
        group, so no `~/select_target` comes between the two steps."""
        if self.gate is not None:
            self.gate.stop_following(self.now_s())
        with self._choice_lock:
            self.following = False
            self._choices += 1
        response.success = True
        response.message = "stopped following; publish a track id on ~/select_target to resume"
        return response

    # ------------------------------------------------------------------ perception
    def _perceive(self) -> None:
        """Each newest image through the pose network, then (handed over, or here)
        through tracker, identifier and the publishers."""
        try:
            for msg in self._images.items(self._stopping, poll_s=0.2):
                try:
                    detected = self._detect_in(msg)
                    if detected is None:
                        continue
                    if self._handoff is None:
                        self._conclude(*detected)
                    elif not self._handoff.give(detected, self._stopping):
                        return
                except Exception as exc:  # one bad frame must not end the node; control goes stale
                    self._frame_failed(exc)
        finally:
            if self._handoff is not None:
                self._handoff.close()

    def _conclude_handed(self) -> None:
        for detected in self._handoff.items(poll_s=0.2):
            try:
                self._conclude(*detected)
            except Exception as exc:  # one bad frame must not end the node; control goes stale
                self._frame_failed(exc)

    def _frame_failed(self, exc: Exception) -> None:
        self.errors += 1
        self.last_error = f"{type(exc).__name__}: {exc}"
        log.exception("frame failed")

    def _perception_for(self, width: int, height: int):
        """The perception built for the first image's size and camera_info; an image of
        another size, or a camera_info that changed, is refused (ValueError): people
        would be placed on the floor with the wrong camera, nearer or farther than they
        are."""
        key = (
            width,
            height,
            None if self.camera_info is None else camera_info_key(self.camera_info),
        )
        if self.perception is not None:
            if key != self._camera_key:
                raise ValueError(
                    f"the camera changed since perception started ({_describe(self._camera_key)}"
                    f" -> {_describe(key)}): images are dropped and the base stopped; restart "
                    "the node to follow with the new camera"
                )
            return self.perception
        from follow.run import build_perception, camera_for_frames

        camera = self.mounted
        if self.config.ros.camera_info_topic:
            if self.camera_info is None:
                self.get_logger().warning("waiting for camera_info", throttle_duration_sec=5.0)
                return None
            camera = camera_from_info(self.camera_info, self.mounted)
        camera = camera_for_frames(camera, width, height)
        from follow.person_in_view import log_person_in_view

        log_person_in_view(camera, self.config)
        if self.control is not None:  # as in follow run: no blind drive out of the view
            from follow.control.target import ViewCone

            self.control.controller.view = ViewCone.from_camera(camera)
        self.perception = build_perception(self.config, camera, detect=self._detect,
                                           pose_backend=self._pose_backend)  # fmt: skip
        if self.odometry is not None:  # jumps told between samples, for the tracker
            self.perception.odometry_jumps = self.odometry.jumps
        self._camera_key = key
        return self.perception

    def _detect_in(self, msg):
        """(frame, robot pose, detections, the image's header) of an image message, or None
        for an image that is dropped (unstamped, out of order or stamped ahead of the
        clock, unreadable or too small, without odometry, or before the camera is known)."""
        ros = self.config.ros
        stamp = stamp_s(msg.header)
        if stamp == 0.0:
            self.stale_frames += 1  # taken, it would make every later image out of order
            self.get_logger().warning(
                "image dropped: its header has no stamp (zero): the camera driver must "
                "stamp each image with its capture time", throttle_duration_sec=5.0,
            )  # fmt: skip
            return None
        now = self.now_s()
        if is_ahead(now, stamp):  # as the last one processed, it would block later images
            self.stale_frames += 1
            self.get_logger().warning(
                f"image dropped: stamped {stamp - now:.2f} s ahead of the node's clock (the "
                "camera's clock disagrees: synchronise the clocks)", throttle_duration_sec=5.0,
            )  # fmt: skip
            return None
        if self._last_stamp is not None and stamp <= self._last_stamp:
            self.stale_frames += 1
            if self._last_stamp - stamp > CLOCK_STEP_S:
                self.get_logger().warning(
                    f"image stamped {self._last_stamp - stamp:.1f} s before the last one "
                    "processed (a clock stepped back?): images are dropped, and the base "
                    "stopped, until they are newer", throttle_duration_sec=5.0,
                )  # fmt: skip
            return None
        try:  # checked (too small?) before its size can fix the camera perceived with
            frame = Frame(image_from_msg(msg), stamp)
        except InvalidInput as exc:
            self.get_logger().warning(f"image dropped: {exc}", throttle_duration_sec=5.0)
            return None
        image = frame.image
        if self._repeats.is_repeat(image):  # a frozen driver stamping its last image anew
            self.stale_frames += 1
            self.get_logger().warning(
                "image dropped: the same image as one of the last few (a frozen camera driver?)",
                throttle_duration_sec=5.0,
            )
            return None
        if self.odometry is not None:
            self.odometry.wait_until(stamp, ros.max_odometry_age_s)
            robot = self.odometry.at(stamp)
            if robot is None:
                self.frames_without_odometry += 1
                self.get_logger().warning(
                    f"image dropped: no odometry within {ros.max_odometry_age_s} s of its stamp",
                    throttle_duration_sec=5.0,
                )
                return None
        else:
            robot = Odometry.origin(stamp)
        with self._lock:
            try:
                perception = self._perception_for(image.shape[1], image.shape[0])
            except ValueError as exc:  # a camera_info or camera file that cannot be used
                self.get_logger().error(f"image dropped: {exc}", throttle_duration_sec=5.0)
                return None
        if perception is None:
            return None
        self._last_stamp = stamp
        return frame, robot, perception.detect_people(frame), msg.header

    def _conclude(self, frame: Frame, robot: Odometry, detections, image_header) -> None:
        with self._lock:
            choice = self._take_choice()
            result = self.perception.conclude(frame, robot, self.frames, detections)
        following = self._hand_to_control(result, choice)
        self.frames += 1
        self._recent.append((time.monotonic(), result.timing_ms))
        if self.control is not None:
            self.control.notify()
        self._publish(result, frame.image, following, image_header, choice)

    def _take_choice(self) -> int:
        """The operator's newest selection, handed to the identifier before a frame is
        concluded (under `_lock`); the count of choices that frame is concluded with."""
        with self._choice_lock:
            selected, self._pending_target = self._pending_target, None
            choice = self._choices
        if selected is None:
            return choice
        if selected >= 0:
            self.perception.identifier.select_target(selected)
        else:
            self.perception.identifier.select_nearest()
        return choice

    def _hand_to_control(self, result: FrameResult, choice: int) -> bool:
        """`result` for the controller, unless the operator chose since its frame was
        concluded (`choice`): concluded with the old choice, it would drive toward the
        person just chosen against after the selection dropped the results before it.
        Whether following."""
        with self._choice_lock:
            if self._choices == choice:
                if self.control is not None and result.target.status == TargetStatus.TRACKING:
                    self.control.controller.target_tracked()  # concluded with the newest choice
                self.results.put(result)
            return self.following

    # ------------------------------------------------------------------ outputs
    def _publish(self, result: FrameResult, image, following: bool, image_header,
                 choice: int) -> None:  # fmt: skip
        """Everything about one image, stamped with that image's own stamp; `choice`: the
        operator's choices counted when it was concluded."""
        frame_id, stamp = self.config.ros.odom_frame, image_header.stamp
        self.pub_tracks.publish(messages.tracks_pose_array(result, frame_id, stamp))
        self.pub_markers.publish(messages.track_markers(result, frame_id, stamp))
        name = getattr(self.perception.identifier, "name", "identifier")
        self.pub_state.publish(messages.target_state(result, str(name), following))
        target = messages.target_pose(result, frame_id, stamp,
                                      self.config.control.target_timeout_s)  # fmt: skip
        if target is not None:
            self._publish_target(target, choice)
        if self.pub_image is not None:
            from follow.render import annotate

            command = self.gate.last_sent if self.gate is not None else None
            picture = annotate(image, result.skeletons, result.tracks, result.target, command)
            self.pub_image.publish(Image(header=messages.header(stamp, image_header.frame_id),
                                         **image_fields(picture)))  # fmt: skip

    def _publish_target(self, target: PoseStamped, choice: int) -> None:
        """Under the choices' lock, and only while following with no choice made since
        the frame was concluded: Nav2 would be led on after `~/stop_following` returned,
        or toward the person just deselected on `~/select_target`."""
        with self._choice_lock:
            if self.following and self._choices == choice:
                self.pub_target.publish(target)

    def _publish_twist(self, command: VelocityCommand) -> None:
        self.pub_cmd_vel.publish(messages.twist(command))

    def _publish_diagnostics(self) -> None:
        self._warn_of_silent_topics()
        period = self.config.ros.diagnostics_period_s
        now = time.monotonic()
        # a copy first: the perception thread appends while this timer reads
        recent = [timing for wall, timing in list(self._recent) if now - wall <= period]
        values = {"fps": f"{len(recent) / period:.2f}", "model": self.model_name,
                  "frames": str(self.frames),
                  "frames_without_odometry": str(self.frames_without_odometry),
                  "odometry_dropped": str(self.odometry_dropped),
                  "stale_frames": str(self.stale_frames), "errors": str(self.errors),
                  "following": str(self.following)}  # fmt: skip
        for stage in ("pose", "tracker", "identify"):
            stage_ms = [t[stage] for t in recent if stage in t]
            if stage_ms:
                values[f"{stage}_ms"] = f"{statistics.median(stage_ms):.1f}"
        if self.gate is not None:
            values["cmd_vel_blocked"] = str(self.gate.blocked)
            values["watchdog_trips"] = str(self.control.watchdog_trips)
        failed_frames, self._errors_reported = self.errors - self._errors_reported, self.errors
        ok, message = perception_status(bool(recent), failed_frames, self.last_error)
        failed = self.control is not None and self.control.error is not None
        if failed:  # it stopped the base and sends nothing more: say so, every period
            message = (f"control loop failed ({type(self.control.error).__name__}: "
                       f"{self.control.error}); the base is stopped: restart the node")  # fmt: skip
        self.pub_diagnostics.publish(
            messages.diagnostics(
                self.now_s(), "follow: perception", values, ok, message, failed=failed
            )  # fmt: skip
        )

    def _warn_of_silent_topics(self) -> list[str]:
        """A topic that has delivered nothing since the start (a typo in its name, a
        driver not running) is said on the console, not only in /diagnostics; the
        topics said."""
        ros = self.config.ros
        silent = [(what, topic) for what, topic, count in (
            ("image", ros.image_topic, self.images_received),
            ("odometry", ros.odom_topic, self.odometry_received),
        ) if topic and count == 0]  # fmt: skip
        for what, topic in silent:
            self.get_logger().warning(
                f"no {what} received on {topic} yet: is the topic right (ros2 topic list) "
                "and its driver running? Nothing is followed until it arrives",
                throttle_duration_sec=SILENT_TOPIC_WARNING_S,
            )
        return [topic for _, topic in silent]

    # ------------------------------------------------------------------ shutdown
    def shutdown(self) -> dict:
        """Stop control, then perception; the base's last command is zero (or an error
        says that it could not be published)."""
        if self.control is not None:
            self.control.stop()  # first: waiting for the pose thread must not drive on
        self._stopping.set()
        self._images.close()
        for worker in self._workers:
            worker.join(timeout=10.0)
        if self.config.ros.publish_cmd_vel:
            self._publish_last_zero()
        return {
            "frames": self.frames,
            "frames_without_odometry": self.frames_without_odometry,
            "odometry_dropped": self.odometry_dropped,
            "stale_frames": self.stale_frames,
            "errors": self.errors,
            "cmd_vel_blocked": self.gate.blocked if self.gate is not None else 0,
        }

    def _publish_last_zero(self) -> None:
        """The base's last command, zero. Where it cannot be published (rclpy's own
        signal handler shut the context down before the host destroyed the node) the
        error says so, and the shutdown goes on: the node must still leave the graph."""
        try:
            self._publish_twist(VelocityCommand.stop(self.now_s()))
        except Exception as exc:  # RCLError: the publisher's context is invalid
            self.get_logger().error(_no_last_zero(exc, context_ok=self.context.ok()))

    def destroy_node(self) -> None:
        """`shutdown` first, unless done: a process hosting the node may destroy it
        without, and once the publishers are gone the control loop cannot send zero.
        The node is destroyed whatever the shutdown met."""
        stopping = getattr(self, "_stopping", None)  # None: __init__ failed before threads
        try:
            if stopping is not None and not stopping.is_set():
                self.shutdown()
        finally:
            super().destroy_node()


def _no_last_zero(exc: Exception, context_ok: bool) -> str:
    """The error of a last zero cmd_vel that could not be published: the base drives on
    its last command until its own cmd_vel timeout, and the host must know why."""
    why = f"{type(exc).__name__}: {exc}"
    if not context_ok:
        why = (f"the ROS context was shut down before the node ({why}); rclpy's default "
               "signal handlers do that on Ctrl-C. " + HOST_SIGNALS_FIX)  # fmt: skip
    return (
        "the base did not get the shutdown's zero cmd_vel: it keeps its last command, "
        f"moving if that was, until its own cmd_vel timeout stops it. Cause: {why}"
    )


def check_host_signals(logger) -> bool:
    """Warn (once, at construction) where rclpy's own signal handlers are installed: on
    Ctrl-C they shut the context down before the host can destroy the node, and the
    node's last zero cmd_vel can then not be published. True when warned."""
    from rclpy.signals import get_current_signal_handlers_options

    if get_current_signal_handlers_options() == SignalHandlerOptions.NO:
        return False
    logger.warning("rclpy's signal handlers are installed: on Ctrl-C or SIGTERM they shut "
                   "the ROS context down before the node, and the base does not get its "
                   "last zero cmd_vel. " + HOST_SIGNALS_FIX)  # fmt: skip
    return True


def run(config: Config, camera: CameraModel, ros_args: list[str], camera_file=None) -> dict:
    """Spin the node until SIGINT, SIGTERM or SIGHUP, then stop the base and shut down; a
    second signal (a shutdown that hangs) publishes zero and exits with 128 + its number.
    `camera_file`, the file `camera` was read from, must have a measured pose for the node
    to publish cmd_vel (`follow.camera.check_pose_measured`)."""
    rclpy.init(args=["follow", "--ros-args", *ros_args] if ros_args else ["follow"],
               signal_handler_options=SignalHandlerOptions.NO)  # fmt: skip
    stop = threading.Event()
    node = None

    def on_signal(signum: int, _frame) -> None:
        if not stop.is_set():
            stop.set()  # the loop below ends and shuts the node down
            return
        # a second signal: the shutdown hangs (a worker that will not end) or is too slow
        log.error("%s during shutdown: publishing zero and exiting now",
                  signal.Signals(signum).name)  # fmt: skip
        if node is not None and config.ros.publish_cmd_vel:
            stop_within(lambda: node._publish_twist(VelocityCommand.stop(node.now_s())))
        os._exit(128 + signum)

    # SIGHUP too: a closed terminal or ssh session must stop the base, not kill the node
    previous = {sig: signal.signal(sig, on_signal) for sig in SIGNALS}
    summary: dict = {}
    try:
        node = FollowNode(config, camera, camera_file=camera_file)
        executor = SingleThreadedExecutor()
        executor.add_node(node)
        while not stop.is_set() and rclpy.ok():
            executor.spin_once(timeout_sec=0.1)
    finally:
        if node is not None:
            summary = node.shutdown()
            time.sleep(0.2)  # let the last zero command leave before the node goes
            node.destroy_node()
        rclpy.try_shutdown()
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    return summary
