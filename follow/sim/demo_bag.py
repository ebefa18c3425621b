"""The demo's run as a robot bag (`follow demo --bag out.mcap`): what the robot saw and
knew, plus the simulation's exact truth, so that `follow run` can replay it.

Topics: the rendered camera images (`/camera/image_raw`) and their `CameraInfo`, the
odometry the base reported (`/odom`, stamped at each frame), the synthetic detector's
skeletons (`/detections/skeletons`, JSON in std_msgs/String, the run log's format), and
the ground truth: the robot's true pose (`/ground_truth/robot`) and every person's
position (`/ground_truth/people`, JSON {id: [x, y]} in `odom`). Beside the bag, the
camera file and the configuration the demo ran with (`demo.mcap.camera.yaml`,
`demo.mcap.toml`: the bag's whole name and a suffix), written only where neither exists.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

from follow.bag_writer import BagWriter, check_bag_path
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
    """The camera file and configuration written beside a demo bag, named after the bag's
    whole name: `robot.mcap` must not take the robot's own robot.toml, nor two dated bag
    folders (runs/2024.05.01, runs/2024.05.02) one pair of files."""
    bag_path = Path(bag_path)
    return (bag_path.parent / f"{bag_path.name}.camera.yaml",
            bag_path.parent / f"{bag_path.name}.toml")  # fmt: skip


def check_demo_bag_path(bag_path: str | Path) -> None:
    """`check_bag_path`, and neither file written beside the bag may exist (FileExistsError
    naming it): checked before the demo writes or empties anything."""
    check_bag_path(bag_path)
    for path in companion_paths(bag_path):
        if os.path.lexists(path):
            raise FileExistsError(f"{path} exists already (the demo writes it beside the bag "
                                  f"{bag_path}); not overwriting it")  # fmt: skip


class DemoBag:
    """Writes one frame of the demo at a time; the files beside the bag go with it when
    the run is aborted."""

    def __init__(self, path: str | Path, camera: CameraModel, identifier: str, seed: int):
        check_demo_bag_path(path)
        self.camera = camera
        self.writer = BagWriter(path)
        self._companions: list[Path] = []  # written by this run: removed with the bag
        camera_file, config_file = companion_paths(path)
        try:
            self._reserve(camera_file)
            camera.save(camera_file)
            self._reserve(config_file)
            config_file.write_text(f'[identify]\nidentifier = "{identifier}"\nseed = {seed}\n')
        except BaseException:
            self.abort()
            raise

    def _reserve(self, path: Path) -> None:
        """Create `path` empty, or refuse (FileExistsError) one made since the check."""
        with open(path, "x"):
            pass
        self._companions.append(path)

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
        try:
            self.writer.close()
        except BaseException:  # no bag (BagWriter.close leaves none): no files beside it
            self._remove_companions()
            raise

    def abort(self) -> None:
        """Remove the bag of a run that failed part-way (see BagWriter.abort), and the
        files written beside it."""
        try:
            self.writer.abort()
        finally:
            self._remove_companions()

    def _remove_companions(self) -> None:
        for path in self._companions:
            path.unlink(missing_ok=True)
        self._companions.clear()
