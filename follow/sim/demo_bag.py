"""The demo's run as a robot bag (`follow demo --bag out.mcap`): what the robot saw and
knew, plus the simulation's exact truth, so that `follow run` can replay it.

Topics: the rendered camera images (`/camera/image_raw`) and their `CameraInfo`, the
odometry the base reported (`/odom`, stamped at each frame), the synthetic detector's
skeletons (`/detections/skeletons`, JSON in std_msgs/String, the run log's format), and
the ground truth: the robot's true pose (`/ground_truth/robot`) and every person's
position (`/ground_truth/people`, JSON {id: [x, y]} in `odom`). Beside the bag, the
camera file and the configuration the demo ran with (`<bag>.camera.yaml`, `<bag>.toml`).
"""

from __future__ import annotations

import json
from pathlib import Path

from follow.bag_writer import BagWriter
from follow.camera import CameraModel
from follow.runlog import skeleton_to_json
from follow.types import Frame, Odometry, Skeleton

IMAGE_TOPIC = "/camera/image_raw"
CAMERA_INFO_TOPIC = "/camera/camera_info"
ODOM_TOPIC = "/odom"
SKELETONS_TOPIC = "/detections/skeletons"
TRUE_ROBOT_TOPIC = "/ground_truth/robot"
TRUE_PEOPLE_TOPIC = "/ground_truth/people"


def companion_paths(bag_path: str | Path) -> tuple[Path, Path]:
    """The camera file and configuration written beside a demo bag."""
    bag_path = Path(bag_path)
    return bag_path.with_suffix(".camera.yaml"), bag_path.with_suffix(".toml")


class DemoBag:
    """Writes one frame of the demo at a time."""

    def __init__(self, path: str | Path, camera: CameraModel, identifier: str, seed: int):
        self.camera = camera
        self.writer = BagWriter(path)
        camera_file, config_file = companion_paths(path)
        camera.save(camera_file)
        config_file.write_text(f'[identify]\nidentifier = "{identifier}"\nseed = {seed}\n')

    def write(self, frame: Frame, skeletons: list[Skeleton], odometry: Odometry,
              robot_true: Odometry, people: dict[int, tuple[float, float]]) -> None:  # fmt: skip
        stamp = frame.stamp_s
        w = self.writer
        w.write_camera_info(CAMERA_INFO_TOPIC, stamp, self.camera, "camera")
        if odometry is not None:  # before the base reports, the bag has no pose
            w.write_odometry(
                ODOM_TOPIC, Odometry(odometry.x_m, odometry.y_m, odometry.yaw_rad, stamp)
            )
        w.write_image(IMAGE_TOPIC, stamp, frame.image, "camera")
        w.write_string(SKELETONS_TOPIC, stamp, json.dumps([skeleton_to_json(s) for s in skeletons]))
        w.write_odometry(TRUE_ROBOT_TOPIC, Odometry(robot_true.x_m, robot_true.y_m,
                                                    robot_true.yaw_rad, stamp))  # fmt: skip
        w.write_string(TRUE_PEOPLE_TOPIC, stamp,
                       json.dumps({str(k): [round(float(v), 4) for v in xy]
                                   for k, xy in people.items()}))  # fmt: skip

    def close(self) -> None:
        self.writer.close()

    def abort(self) -> None:
        """Remove the bag of a run that failed part-way (see BagWriter.abort)."""
        self.writer.abort()
