"""`follow ros2`: run the ROS 2 node (see follow/ros2/node.py and docs/ros2.md)."""

from __future__ import annotations

import argparse

from follow.camera import CameraModel
from follow.config import Config


def add_arguments(p) -> None:
    # Not required by argparse: given after --ros-args (which takes everything after
    # it) it is missing here, and main says why.
    p.add_argument("--camera",
                   help="camera file, required: the camera's pose on the robot (and "
                   "intrinsics when ros.camera_info_topic is empty)")  # fmt: skip
    p.add_argument("--config", help="TOML configuration; ROS parameters `section.key` override it")
    p.add_argument("--ros-args", dest="ros_args", nargs=argparse.REMAINDER, default=[],
                   help="ROS arguments, last: everything after it is ROS's, e.g. "
                   "--ros-args -p ros.publish_cmd_vel:=true -r __ns:=/robot")  # fmt: skip


def main(args) -> dict:
    if args.camera is None:
        late = [o for o in ("--camera", "--config", "--json") if o in (args.ros_args or [])]
        if late:
            raise ValueError(f"{', '.join(late)} came after --ros-args, which takes everything "
                             "after it: give --ros-args last")  # fmt: skip
        raise ValueError("--camera is required: the camera file with the camera's pose")
    try:
        import rclpy  # noqa: F401
    except ImportError as exc:
        raise RuntimeError(
            "follow ros2 needs ROS 2's Python packages: pip install 'follow[ros2]' "
            f"(ROS 2 Kilted wheels for Python 3.11), or source a ROS 2 installation ({exc})"
        ) from None
    from follow.ros2.node import run

    config = Config.load(args.config) if args.config else Config()
    summary = run(config, CameraModel.load(args.camera), args.ros_args or [], args.camera)
    if not args.json:
        print(f"{summary.get('frames', 0)} frames; the base was left stopped")
    return summary
