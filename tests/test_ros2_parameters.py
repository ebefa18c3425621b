"""ROS parameters override the configuration by name; a name that is no parameter (a
typo) is refused with the nearest real one, never dropped in silence. Runs where rclpy
imports."""

from __future__ import annotations

import pytest
from ros2_support import skip_without_ros2

from follow.config import Config, ConfigError

try:
    import rclpy
    from rclpy.node import Node

    from follow.ros2.node import parameters_over
except ImportError as exc:  # pragma: no cover - depends on the installation
    skip_without_ros2(exc)


def _parameters(*overrides: str) -> Config:
    context = rclpy.Context()
    args = ["follow", "--ros-args", *[a for o in overrides for a in ("-p", o)]]
    rclpy.init(args=args, context=context)
    node = Node("follow_parameters_test", context=context)
    try:
        return parameters_over(node, Config())
    finally:
        node.destroy_node()
        rclpy.shutdown(context=context)


def test_a_parameter_overrides_its_key():
    assert _parameters("control.target_timeout_s:=0.4").control.target_timeout_s == 0.4


def test_a_key_of_two_types_takes_either():
    """`[control] overlap_stages` is "auto", true or false: the parameter declared with
    the default's type would refuse the other."""
    assert _parameters("control.overlap_stages:=false").control.overlap_stages is False
    assert _parameters("control.overlap_stages:=auto").control.overlap_stages == "auto"


def test_a_misspelt_parameter_is_refused_with_the_nearest_name():
    with pytest.raises(ConfigError, match=r"control\.max_forwrd_speed_mps \(did you mean "
                       r"control\.max_forward_speed_mps\?\)"):  # fmt: skip
        _parameters("control.max_forwrd_speed_mps:=1.0")


def test_a_change_at_run_time_is_refused_by_name():
    """The configuration is read once, at start-up: `ros2 param set` must not report a
    change (say, `ros.publish_cmd_vel` off) that the node does not make."""
    from rclpy.parameter import Parameter

    context = rclpy.Context()
    rclpy.init(args=["follow"], context=context)
    node = Node("follow_parameters_test", context=context)
    try:
        parameters_over(node, Config())
        results = node.set_parameters([Parameter("ros.publish_cmd_vel", value=False),
                                       Parameter("control.max_forward_speed_mps", value=9.0)])
        assert [r.successful for r in results] == [False, False]
        assert "ros.publish_cmd_vel" in results[0].reason and "restart" in results[0].reason
        assert node.get_parameter("control.max_forward_speed_mps").value == 1.5
    finally:
        node.destroy_node()
        rclpy.shutdown(context=context)


def test_a_failed_control_loop_is_an_error_in_the_diagnostics():
    from diagnostic_msgs.msg import DiagnosticStatus

    from follow.ros2 import messages

    levels = [messages.diagnostics(1.0, "follow", {}, ok, "m", failed=failed).status[0].level
              for ok, failed in ((True, False), (False, False), (True, True))]  # fmt: skip
    assert levels == [DiagnosticStatus.OK, DiagnosticStatus.WARN, DiagnosticStatus.ERROR]


def test_the_diagnostics_name_why_frames_fail():
    """A node whose every frame raises said only "no frames processed recently"."""
    from follow.ros2.node import perception_status

    assert perception_status(True, 0, None) == (True, "running")
    assert perception_status(False, 0, "ValueError: old") == (False, "no frames processed recently")
    ok, message = perception_status(False, 12, "ValueError: image 640x480, camera 1280x720")
    assert not ok and "12 frame(s) failed" in message and "camera 1280x720" in message
    ok, message = perception_status(True, 1, "KeyError: 'x'")
    assert ok and message.startswith("running;") and "KeyError" in message
