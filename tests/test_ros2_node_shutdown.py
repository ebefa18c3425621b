"""The ROS 2 node's last command is zero however it ends: `shutdown` stops the control
loop before it waits for a frame still in the pose network, and a node destroyed
without `shutdown` (by a process that hosts it) stops the base first. In process, with
a stand-in detector; runs where rclpy imports."""

from __future__ import annotations

import itertools
import threading
import time

import numpy as np
import pytest
from ros2_support import isolated_rclpy, skip_without_ros2
from waiting import wait_for

from follow.camera import CameraModel, CameraPose
from follow.config import Config
from follow.pipeline import FrameResult
from follow.rosmsg import image_fields, quaternion_of_yaw, stamp_fields
from follow.types import Observation, Odometry, TargetEstimate, TargetStatus, TrackState

try:
    import rclpy  # noqa: F401 - the import is the check
    from builtin_interfaces.msg import Time
    from nav_msgs.msg import Odometry as OdometryMsg
    from sensor_msgs.msg import Image
    from std_msgs.msg import Header

    from follow.ros2.node import FollowNode
except ImportError as exc:  # pragma: no cover - depends on the installation
    skip_without_ros2(exc)

CAMERA = CameraModel.from_fov((320, 240), 70.0, CameraPose(height_m=1.0))
SEEN = Observation(np.array([160.0, 100.0]), np.array([160.0, 200.0]))


ros_context = pytest.fixture(scope="module", autouse=True)(isolated_rclpy)


_FILLS = itertools.count()  # a new picture for each image message


def _header(stamp_s: float, frame_id: str) -> Header:
    return Header(stamp=Time(**stamp_fields(stamp_s)), frame_id=frame_id)


def _odometry(stamp_s: float) -> OdometryMsg:
    msg = OdometryMsg(header=_header(stamp_s, "odom"), child_frame_id="base_link")
    q, o = quaternion_of_yaw(0.0), msg.pose.pose.orientation
    o.x, o.y, o.z, o.w = q["x"], q["y"], q["z"], q["w"]
    return msg


def _image(stamp_s: float) -> Image:
    fields = image_fields(np.full((240, 320, 3), next(_FILLS) % 256, np.uint8))
    return Image(header=_header(stamp_s, "camera"), **{**fields, "data": fields["data"].tobytes()})


def _result(stamp_s: float) -> FrameResult:
    """The target tracked 3 m ahead: the controller drives towards it."""
    track = TrackState(7, np.array([3.0, 0.0, 0.0, 0.0, 1.5]), np.eye(5) * 0.01, True, stamp_s,
                       observation=SEEN)  # fmt: skip
    return FrameResult(0, stamp_s, Odometry.origin(stamp_s), [], [track],
                       TargetEstimate(TargetStatus.TRACKING, 7, {7: 0.9}, stamp_s, True))  # fmt: skip


def _driving_node(detect):
    """A node with cmd_vel on, fresh odometry fed every 20 ms, whose published twists
    are recorded; (node, twists, stop feeding)."""
    config = Config().replace("identify", identifier="channels")
    config = config.replace("ros", publish_cmd_vel=True, camera_info_topic="", max_image_age_s=1.0)
    node = FollowNode(config.replace("control", target_timeout_s=2.0), CAMERA, detect=detect)
    twists: list = []
    node.pub_cmd_vel.publish = twists.append
    done = threading.Event()

    def feed():
        while not done.wait(0.02):
            node._on_odometry(_odometry(node.now_s()))

    threading.Thread(target=feed, daemon=True).start()
    return node, twists, done


def _moving(twist) -> bool:
    return twist.linear.x != 0.0 or twist.angular.z != 0.0


def test_shutdown_stops_the_base_before_waiting_for_the_pose_network():
    """On a CPU the network takes a second a frame: the base must not drive on the last
    result while shutdown waits for it."""
    inside, release = threading.Event(), threading.Event()

    def slow_detect(frame):
        inside.set()
        release.wait(10.0)
        return []

    node, twists, done = _driving_node(slow_detect)
    stopper = threading.Thread(target=node.shutdown)
    try:
        node._images.put(_image(node.now_s()))
        assert inside.wait(3.0), "the image never reached the pose network"
        node.results.put(_result(node.now_s()))
        node.control.notify()
        assert wait_for(lambda: bool(twists) and _moving(twists[-1]), 3.0), "the base never drove"
        stopper.start()
        time.sleep(0.5)  # the network is still busy with the image
        driving = node.control._thread.is_alive()
        last = twists[-1]
    finally:
        release.set()
        stopper.join(15.0)
        done.set()
        node.destroy_node()
    assert not _moving(last), f"still driving at {last.linear.x} m/s during shutdown"
    assert not driving, "the control loop still ran while shutdown waited for the network"


def test_destroying_the_node_stops_the_base_first():
    """A process that hosts the node may destroy it without `shutdown`: its publishers
    go, and a control loop left running can no longer send the zero."""
    node, twists, done = _driving_node(lambda frame: [])
    try:
        node.results.put(_result(node.now_s()))
        node.control.notify()
        assert wait_for(lambda: bool(twists) and _moving(twists[-1]), 3.0), "the base never drove"
    finally:
        done.set()
        node.destroy_node()
    assert twists and not _moving(twists[-1])
    assert not node.control._thread.is_alive() and node.control.error is None
