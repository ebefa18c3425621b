"""The ROS 2 node with a camera file whose pose `follow-calib intrinsics` left as a
placeholder, not measured by `follow-calib ground`: with `ros.publish_cmd_vel` it refuses
to start (it would drive a base on made-up distances), naming the file and the command;
without, it starts and warns. A measured pose and a file without calibration notes
publish cmd_vel as before. In process, with a stand-in detector; runs where rclpy
imports."""

from __future__ import annotations

import random

import pytest
from ros2_support import isolated_rclpy, skip_without_ros2

from calib.camera_file import write_camera_file
from follow.camera import CameraModel, CameraPose
from follow.config import Config

try:
    import rclpy  # noqa: F401 - the import is the check

    from follow.ros2.node import FollowNode
except ImportError as exc:  # pragma: no cover - depends on the installation
    skip_without_ros2(exc)

CAMERA = CameraModel.from_fov((320, 240), 70.0, CameraPose(height_m=1.0))
CONFIG = Config().replace("identify", identifier="channels")  # no model files needed
# what `follow-calib intrinsics` writes into a new camera file, and `ground` over it
INTRINSICS_NOTES = {"intrinsics": "follow-calib intrinsics",
                    "pose": "placeholder: measure it with `follow-calib ground`"}  # fmt: skip
GROUND_NOTES = {"pose": "follow-calib ground"}


ros_context = pytest.fixture(isolated_rclpy)


class _NodeStarted(RuntimeError):
    """Raised by the stand-in node once started: `follow ros2` then ends at once."""


@pytest.fixture
def follow_ros2(tmp_path, monkeypatch):
    """`follow ros2 --camera FILE ARGS...` in process, with the real FollowNode on a
    stand-in detector that ends the command as soon as the node has started."""
    from follow import cli
    from follow.ros2 import node as node_module

    class StartOnly(node_module.FollowNode):
        def __init__(self, config, camera, **kwargs):
            super().__init__(config, camera, detect=lambda frame: [], **kwargs)
            self.shutdown()
            self.destroy_node()
            raise _NodeStarted("the node started")

    monkeypatch.setattr(node_module, "FollowNode", StartOnly)
    monkeypatch.setenv("ROS_DOMAIN_ID", str(random.randint(100, 200)))
    config = tmp_path / "robot.toml"
    config.write_text('[identify]\nidentifier = "channels"\n')  # no model files needed

    def follow(camera_file, *ros_args):
        argv = ["ros2", "--camera", str(camera_file), "--config", str(config)]
        return cli.main(argv + (["--ros-args", *ros_args] if ros_args else []))

    return follow


def _node(camera_file, publish_cmd_vel: bool):
    return FollowNode(CONFIG.replace("ros", publish_cmd_vel=publish_cmd_vel), CAMERA,
                      detect=lambda frame: [], camera_file=camera_file)  # fmt: skip


def _close(node) -> None:
    node.shutdown()
    node.destroy_node()


@pytest.mark.usefixtures("ros_context")
def test_a_placeholder_pose_publishes_no_cmd_vel(tmp_path):
    camera = tmp_path / "cam.yaml"
    write_camera_file(camera, CAMERA, INTRINSICS_NOTES)
    with pytest.raises(ValueError, match=rf"camera file {camera}: .*placeholder") as refused:
        _close(_node(camera, publish_cmd_vel=True))
    assert "`follow-calib ground`" in str(refused.value)


@pytest.mark.usefixtures("ros_context")
def test_a_placeholder_pose_without_cmd_vel_starts_with_a_warning(tmp_path, capfd):
    camera = tmp_path / "cam.yaml"
    write_camera_file(camera, CAMERA, INTRINSICS_NOTES)
    node = _node(camera, publish_cmd_vel=False)
    try:
        assert node.control is None
    finally:
        _close(node)
    err = capfd.readouterr().err
    warning = next(line for line in err.splitlines() if "placeholder" in line)
    assert "WARN" in warning and f"camera file {camera}" in warning
    assert "distances to people are not measured" in warning


@pytest.mark.usefixtures("ros_context")
@pytest.mark.parametrize("notes", [GROUND_NOTES, None], ids=["after ground", "no notes"])
def test_a_measured_pose_or_a_file_without_notes_publishes_cmd_vel(tmp_path, capfd, notes):
    """The same file is refused until `follow-calib ground` replaces the placeholder; a
    file without notes (by hand, imported) is taken as measured."""
    camera = tmp_path / "cam.yaml"
    write_camera_file(camera, CAMERA, INTRINSICS_NOTES)
    with pytest.raises(ValueError, match="placeholder"):
        _close(_node(camera, publish_cmd_vel=True))
    if notes is None:
        CAMERA.save(camera)  # `CameraModel.save` writes no notes
    else:
        write_camera_file(camera, CAMERA.with_pose(CameraPose(0.8, 0.2)), notes)
    capfd.readouterr()
    node = _node(camera, publish_cmd_vel=True)
    try:
        assert node.control is not None and node.gate is not None
    finally:
        _close(node)
    assert "placeholder" not in capfd.readouterr().err


def test_follow_ros2_with_cmd_vel_on_a_placeholder_pose_is_refused_in_one_line(
    follow_ros2, tmp_path, capfd
):
    """`ros.publish_cmd_vel` set as a ROS parameter counts as in the configuration."""
    camera = tmp_path / "cam.yaml"
    write_camera_file(camera, CAMERA, INTRINSICS_NOTES)
    assert follow_ros2(camera, "-p", "ros.publish_cmd_vel:=true") == 1
    err = [line for line in capfd.readouterr().err.splitlines() if "follow ros2" in line]
    assert len(err) == 1 and err[0].startswith(f"follow ros2: error: camera file {camera}: ")
    assert "placeholder" in err[0] and "`follow-calib ground`" in err[0]


def test_follow_ros2_without_cmd_vel_on_a_placeholder_pose_starts_and_warns(
    follow_ros2, tmp_path, capfd
):
    camera = tmp_path / "cam.yaml"
    write_camera_file(camera, CAMERA, INTRINSICS_NOTES)
    assert follow_ros2(camera) == 1
    err = capfd.readouterr().err
    assert "follow ros2: error: the node started" in err
    warning = next(line for line in err.splitlines() if "placeholder" in line)
    assert "WARN" in warning and f"camera file {camera}" in warning
