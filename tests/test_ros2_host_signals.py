"""A process that hosts FollowNode the usual rclpy way (`rclpy.init()` with rclpy's own
signal handlers, spin, Ctrl-C, `destroy_node` in `finally`): rclpy shuts the context
down on the signal, before the host destroys the node, so the node's last zero cmd_vel
cannot be published. The node warns of such a host when it starts, says so when it shuts
down, and is destroyed all the same. In process (a real SIGINT, caught where the host
would), with a stand-in detector; runs where rclpy imports."""

from __future__ import annotations

import random
import signal
import threading

import numpy as np
import pytest
from ros2_support import skip_without_ros2
from waiting import wait_for

from follow.camera import CameraModel, CameraPose
from follow.config import Config
from follow.pipeline import FrameResult
from follow.rosmsg import quaternion_of_yaw, stamp_fields
from follow.types import Observation, Odometry, TargetEstimate, TargetStatus, TrackState

try:
    import rclpy
    from builtin_interfaces.msg import Time
    from nav_msgs.msg import Odometry as OdometryMsg
    from rclpy.signals import SignalHandlerOptions
    from std_msgs.msg import Header

    from follow.ros2.node import FollowNode
except ImportError as exc:  # pragma: no cover - depends on the installation
    skip_without_ros2(exc)

CAMERA = CameraModel.from_fov((320, 240), 70.0, CameraPose(height_m=1.0))
SEEN = Observation(np.array([160.0, 100.0]), np.array([160.0, 200.0]))
NO_ZERO = "the base did not get the shutdown's zero cmd_vel"
HOST_WARNING = "rclpy's signal handlers are installed"


def _odometry(stamp_s: float) -> OdometryMsg:
    msg = OdometryMsg(header=Header(stamp=Time(**stamp_fields(stamp_s)), frame_id="odom"))
    q, o = quaternion_of_yaw(0.0), msg.pose.pose.orientation
    o.x, o.y, o.z, o.w = q["x"], q["y"], q["z"], q["w"]
    return msg


def _result(stamp_s: float) -> FrameResult:
    """The target tracked 3 m ahead: the controller drives towards it."""
    track = TrackState(7, np.array([3.0, 0.0, 0.0, 0.0, 1.5]), np.eye(5) * 0.01, True, stamp_s,
                       observation=SEEN)  # fmt: skip
    target = TargetEstimate(TargetStatus.TRACKING, 7, {7: 0.9}, stamp_s, True)
    return FrameResult(0, stamp_s, Odometry.origin(stamp_s), [], [track], target)


def _node(publish_cmd_vel: bool = True) -> FollowNode:
    config = Config().replace("identify", identifier="channels")  # no model files needed
    config = config.replace("ros", publish_cmd_vel=publish_cmd_vel, camera_info_topic="")
    return FollowNode(config.replace("control", target_timeout_s=2.0), CAMERA,
                      detect=lambda frame: [])  # fmt: skip


def _drive(node: FollowNode) -> tuple[list, threading.Event]:
    """Fresh odometry and a fresh result toward the target every 20 ms, the twists that
    reached the publisher recorded (one that raised did not); (twists, stop feeding) once
    the base drives."""
    sent: list = []
    publish = node.pub_cmd_vel.publish

    def recorded(msg) -> None:
        publish(msg)
        sent.append(msg)

    node.pub_cmd_vel.publish = recorded
    done = threading.Event()

    def feed() -> None:
        while not done.wait(0.02):
            node._on_odometry(_odometry(node.now_s()))
            node.results.put(_result(node.now_s() - 0.02))
            node.control.notify()

    threading.Thread(target=feed, daemon=True).start()
    assert wait_for(lambda: bool(sent) and sent[-1].linear.x > 0.0, 5.0), "the base never drove"
    return sent, done


def test_ctrl_c_with_rclpy_s_signal_handlers_is_said_and_the_node_still_destroyed(capfd):
    """rclpy's own SIGINT handler shuts the context down before the host's `finally`
    destroys the node: the last zero raised out of `destroy_node`, which then never
    destroyed the node, and nothing said that the base drives on."""
    rclpy.init(
        domain_id=random.randint(100, 200), signal_handler_options=SignalHandlerOptions.SIGINT
    )
    try:
        node = _node()
        sent, done = _drive(node)
        with pytest.raises(KeyboardInterrupt):  # rclpy's handler passes it on: Ctrl-C
            signal.raise_signal(signal.SIGINT)
        assert wait_for(lambda: not rclpy.ok(), 5.0), "rclpy's handler kept the context"
        try:
            node.destroy_node()  # the host's `finally`
        finally:
            done.set()
    finally:
        rclpy.try_shutdown()  # rclpy's handler uninstalled, pytest's SIGINT back
    err = capfd.readouterr().err
    assert list(node.publishers) == [], "the node was not destroyed"
    assert sent[-1].linear.x > 0.0  # what the base really got last: a moving command
    said = [line for line in err.splitlines() if NO_ZERO in line]
    assert len(said) == 1 and "ERROR" in said[0], err[-2000:]
    assert "context was shut down" in said[0] and "SignalHandlerOptions.NO" in said[0]


@pytest.mark.parametrize(("options", "publish_cmd_vel", "warned"), [
    (SignalHandlerOptions.ALL, True, True),
    (SignalHandlerOptions.SIGINT, True, True),
    (SignalHandlerOptions.NO, True, False),  # the host handles signals, as `follow ros2`
    (SignalHandlerOptions.ALL, False, False),  # no cmd_vel: no zero to lose
])  # fmt: skip
def test_a_host_with_rclpy_s_signal_handlers_is_warned_at_start_up(
    options, publish_cmd_vel, warned, capfd
):
    """Before Ctrl-C, where the host can still be fixed: without `SignalHandlerOptions.NO`
    its Ctrl-C leaves the base on its last command (above)."""
    rclpy.init(domain_id=random.randint(100, 200), signal_handler_options=options)
    try:
        capfd.readouterr()
        node = _node(publish_cmd_vel)
        node.shutdown()
        node.destroy_node()
    finally:
        rclpy.try_shutdown()
    warnings = [line for line in capfd.readouterr().err.splitlines() if HOST_WARNING in line]
    assert len(warnings) == (1 if warned else 0), warnings
    if warned:
        assert "WARN" in warnings[0] and "SignalHandlerOptions.NO" in warnings[0]
        assert "destroy_node() before rclpy.shutdown()" in warnings[0]
