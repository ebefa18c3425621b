"""The robot's side of a loop back to the `follow ros2` node, for tests and the bench:
starts the node as a process on a ROS domain of its own (localhost only), publishes
camera frames, CameraInfo and odometry as a robot would, and records what the node
publishes."""

from __future__ import annotations

import json
import os
import random
import subprocess
import sys
import threading
import time
from pathlib import Path

import rclpy
import rclpy.executors

from follow.rosmsg import stamp_s
from follow.types import Odometry


def at_stamp(received: list, stamp: float, stamp_of):
    """The message stamped `stamp` (float seconds keep ~0.2 us at today's epoch)."""
    return next((m for _, m in received if abs(stamp_of(m) - stamp) < 1e-6), None)


def isolated_environment() -> dict[str, str]:
    """Environment for a private ROS graph: a random domain, discovery on localhost
    (ROS_AUTOMATIC_DISCOVERY_RANGE since Jazzy; ROS_LOCALHOST_ONLY for older ones)."""
    return {**os.environ, "ROS_DOMAIN_ID": str(random.randrange(1, 100)),
            "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST", "ROS_LOCALHOST_ONLY": "1"}  # fmt: skip


class NodeExited(RuntimeError):
    """The node process ended while the robot side waited on it."""


def wait_for(predicate, timeout_s: float, process: subprocess.Popen | None = None) -> bool:
    """Whether `predicate()` came true within `timeout_s` (checked every 20 ms)."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if predicate():
            return True
        if process is not None and process.poll() is not None:
            raise NodeExited(f"follow ros2 exited with {process.returncode}")
        time.sleep(0.02)
    return False


def start_node(camera_file: Path, config_file: Path, env: dict[str, str], log_file,
               ros_args: tuple[str, ...] = ()) -> subprocess.Popen:  # fmt: skip
    """`follow ros2` as a child process; its JSON summary comes on stdout at exit."""
    command = [sys.executable, "-m", "follow.cli", "ros2", "--camera", str(camera_file),
               "--config", str(config_file), "--json"]  # fmt: skip
    if ros_args:
        command += ["--ros-args", *ros_args]
    return subprocess.Popen(command, env=env, stdout=subprocess.PIPE, stderr=log_file, text=True)


class RobotSide:
    """The robot's side: publishes camera and odometry, records what the node says."""

    def __init__(self, context: rclpy.Context):
        from diagnostic_msgs.msg import DiagnosticArray
        from geometry_msgs.msg import PoseArray, PoseStamped, Twist
        from nav_msgs.msg import Odometry as OdometryMsg
        from sensor_msgs.msg import CameraInfo, Image
        from std_msgs.msg import Int32, String
        from std_srvs.srv import Trigger
        from visualization_msgs.msg import MarkerArray

        self.types = {"Image": Image, "CameraInfo": CameraInfo, "Odometry": OdometryMsg,
                      "Int32": Int32}  # fmt: skip
        self.node = rclpy.create_node("follow_robot_side", context=context)
        self.pub_image = self.node.create_publisher(Image, "/camera/image_raw", 10)
        self.pub_info = self.node.create_publisher(CameraInfo, "/camera/camera_info", 10)
        self.pub_odom = self.node.create_publisher(OdometryMsg, "/odom", 50)
        self.pub_select = self.node.create_publisher(Int32, "/follow/select_target", 10)
        self.received: dict[str, list] = {
            k: []
            for k in ("tracks", "markers", "target", "state", "cmd", "diagnostics", "annotated")
        }
        for key, kind, topic in [("tracks", PoseArray, "/follow/tracks"),
                                 ("markers", MarkerArray, "/follow/track_markers"),
                                 ("target", PoseStamped, "/follow/target"),
                                 ("state", String, "/follow/target_state"),
                                 ("cmd", Twist, "/cmd_vel"),
                                 ("diagnostics", DiagnosticArray, "/diagnostics"),
                                 ("annotated", Image, "/follow/image_annotated")]:  # fmt: skip
            self.node.create_subscription(kind, topic, self._recorder(key), 50)
        self.stop_following = self.node.create_client(Trigger, "/follow/stop_following")
        self.executor = rclpy.executors.SingleThreadedExecutor(context=context)
        self.executor.add_node(self.node)
        self._spin = threading.Thread(target=self.executor.spin, daemon=True)
        self._spin.start()
        self.pose: Odometry | None = None
        self._lock = threading.Lock()
        self._heartbeat = threading.Event()
        self._beat: threading.Thread | None = None

    def _recorder(self, key):
        return lambda msg: self.received[key].append((time.monotonic(), msg))

    def now_s(self) -> float:
        return self.node.get_clock().now().nanoseconds * 1e-9

    def publish_odometry(self, pose: Odometry, stamp: float) -> None:
        from follow.rosmsg import quaternion_of_yaw, stamp_fields

        msg = self.types["Odometry"]()
        msg.header.stamp.sec, msg.header.stamp.nanosec = stamp_fields(stamp).values()
        msg.header.frame_id, msg.child_frame_id = "odom", "base_link"
        msg.pose.pose.position.x, msg.pose.pose.position.y = pose.x_m, pose.y_m
        q = quaternion_of_yaw(pose.yaw_rad)
        msg.pose.pose.orientation.z, msg.pose.pose.orientation.w = q["z"], q["w"]
        self.pub_odom.publish(msg)

    def start_odometry(self, period_s: float = 0.05) -> None:
        """Odometry at 20 Hz, stamped now, at the pose of the latest frame."""

        def beat():
            while not self._heartbeat.wait(period_s):
                with self._lock:
                    if self.pose is not None:
                        self.publish_odometry(self.pose, self.now_s())

        self._beat = threading.Thread(target=beat, daemon=True)
        self._beat.start()

    def publish_frame(self, image, camera, pose: Odometry, stamp: float | None = None) -> float:
        """The pose stamped at the image's instant, CameraInfo and the image; its stamp."""
        from follow.rosmsg import camera_info_fields, image_fields, stamp_fields

        with self._lock:
            stamp = self.now_s() if stamp is None else stamp
            self.publish_odometry(pose, stamp)
            self.pose = pose
        info = self.types["CameraInfo"](**camera_info_fields(camera))
        msg = self.types["Image"](**{**image_fields(image), "data": image.tobytes()})
        for m in (info, msg):
            m.header.stamp.sec, m.header.stamp.nanosec = stamp_fields(stamp).values()
            m.header.frame_id = "camera"
        self.pub_info.publish(info)
        self.pub_image.publish(msg)
        return stamp_s(msg.header)

    def wait_for_node(self, process: subprocess.Popen, timeout_s: float = 90.0) -> None:
        """Until the node subscribes to the camera and the target selection, and its
        outputs are matched here."""
        if not wait_for(lambda: self.pub_image.get_subscription_count() > 0
                        and self.pub_select.get_subscription_count() > 0
                        and self.node.count_publishers("/follow/tracks") > 0,
                        timeout_s, process):  # fmt: skip
            raise TimeoutError(f"follow ros2 did not subscribe within {timeout_s} s")
        time.sleep(1.0)  # discovery done both ways, not only on this side

    def send_frame(self, image, camera, pose: Odometry, process, stamp: float | None = None,
                   timeout_s: float = 60.0, resend_s: float = 1.0):  # fmt: skip
        """Publish one frame (stamped `stamp`, default now) and wait for the node's tracks
        of it. A best-effort image can be lost, so it is sent again with the same stamp
        every `resend_s` (the node drops an image not newer than the last it processed).
        (stamp, published_s, answered_s) with monotonic times."""
        published_s = time.monotonic()
        stamp = self.publish_frame(image, camera, pose, stamp)
        for _ in range(max(1, int(timeout_s / resend_s))):
            if wait_for(lambda: self.tracks_at(stamp) is not None, resend_s, process):
                answered_s = next(t for t, m in self.received["tracks"]
                                  if abs(stamp_s(m.header) - stamp) < 1e-6)  # fmt: skip
                return stamp, published_s, answered_s
            self.publish_frame(image, camera, pose, stamp)
        raise TimeoutError(f"no tracks for the frame stamped {stamp:.3f} after {timeout_s} s")

    def state_at(self, stamp: float, timeout_s: float = 2.0) -> dict | None:
        """The node's `~/target_state` of a frame (it follows the tracks), as a dict."""

        def find():
            states = [(t, json.loads(m.data)) for t, m in self.received["state"]]
            return at_stamp(states, stamp, lambda d: d["stamp_s"])

        wait_for(lambda: find() is not None, timeout_s)
        return find()

    def tracks_at(self, stamp: float):
        return at_stamp(self.received["tracks"], stamp, lambda m: stamp_s(m.header))

    def close(self) -> None:
        self._heartbeat.set()
        if self._beat is not None:
            self._beat.join(timeout=2.0)
        self.executor.shutdown()
        self._spin.join(timeout=2.0)
        self.node.destroy_node()
