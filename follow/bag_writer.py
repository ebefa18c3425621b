"""Writing robot bags (images, odometry, camera info) with `rosbags`, no ROS needed.

The format follows the path: `.bag` is ROS 1, `.mcap` one MCAP file, a name without a
suffix or ending in a date's digits (runs/2024.05.01) a ROS 2 bag directory (MCAP
storage); any other suffix is refused. Used by the demo's `--bag` and by tests that turn
a video into the bag a robot would have recorded.
"""

from __future__ import annotations

import os
import shutil
import tempfile
from pathlib import Path

import numpy as np

from follow.camera import CameraModel
from follow.rosmsg import camera_info_fields, image_fields, quaternion_of_yaw, stamp_fields
from follow.types import Odometry

WRITTEN_BAG_SUFFIXES = (".bag", ".mcap")  # ROS 1, one ROS 2 MCAP file; else a ROS 2 folder


def check_bag_path(path: str | Path) -> None:
    """Refuse a bag to write that exists already or is named as no bag is, before any
    other output of the run is opened (the checks `BagWriter` makes, without rosbags)."""
    path = Path(path)
    if path.exists():
        raise FileExistsError(f"bag {path} exists already; not overwriting it")
    suffix = path.suffix
    if suffix not in WRITTEN_BAG_SUFFIXES and not _names_a_bag_folder(suffix):
        raise ValueError(f"bag {path}: name a .mcap or .bag file, or a folder (a ROS 2 "
                         f"bag, named without a suffix or with a date: runs/2024.05.01), "
                         f"not a {suffix} file")  # fmt: skip


def _names_a_bag_folder(suffix: str) -> bool:
    """No suffix, or digits alone (a date: runs/2024.05.01). Any other (run.txt, run.db3,
    run.mp4) would name a ROS 2 bag folder as a file of another kind."""
    digits = suffix[1:]
    return not suffix or (digits.isascii() and digits.isdigit())


class BagWriter:
    """One bag being written; topics are added on their first message."""

    def __init__(self, path: str | Path):
        try:
            from rosbags.typesys import Stores, get_typestore
        except ImportError:
            raise RuntimeError("writing bags needs rosbags: pip install 'follow[bag]'") from None
        self.path = Path(path)
        check_bag_path(self.path)
        suffix = self.path.suffix
        self.ros1 = suffix == ".bag"
        self._single_mcap = suffix == ".mcap"
        # Written in a hidden folder beside the bag, not in a temp folder that may be on
        # another file system: the last step is then a rename, and a run killed on the way
        # never leaves part of a bag under its name (it would read back as a valid,
        # shorter recording).
        try:
            self._tmp: Path | None = Path(tempfile.mkdtemp(
                prefix=f".{self.path.name}.", suffix=".tmp", dir=self.path.parent
            ))  # fmt: skip
        except OSError as exc:
            raise OSError(f"cannot write the bag {self.path}: {exc.strerror or exc}") from exc
        target = self._tmp / self.path.name
        if self.ros1:
            from rosbags.rosbag1 import Writer

            self.typestore = get_typestore(Stores.ROS1_NOETIC)
            self._writer = Writer(target)
        else:  # rosbags writes a directory; of a single `.mcap`, its one file is kept
            from rosbags.rosbag2 import StoragePlugin, Writer

            self.typestore = get_typestore(Stores.ROS2_KILTED)
            self._writer = Writer(target, version=9, storage_plugin=StoragePlugin.MCAP)
        try:
            self._writer.open()
        except BaseException:
            self._remove_tmp()
            raise
        self._connections: dict[str, object] = {}
        self._seq = 0

    def _types(self, name: str):
        return self.typestore.types[name]

    def _header(self, stamp: float, frame_id: str):
        fields = {"stamp": self._types("builtin_interfaces/msg/Time")(**stamp_fields(stamp)),
                  "frame_id": frame_id}  # fmt: skip
        if self.ros1:
            self._seq += 1
            fields["seq"] = self._seq
        return self._types("std_msgs/msg/Header")(**fields)

    def write(self, topic: str, stamp: float, msg) -> None:
        """One message, recorded at `stamp` seconds."""
        msgtype = msg.__msgtype__
        if topic not in self._connections:
            self._connections[topic] = self._writer.add_connection(
                topic, msgtype, typestore=self.typestore
            )
        serialize = self.typestore.serialize_ros1 if self.ros1 else self.typestore.serialize_cdr
        self._writer.write(self._connections[topic], int(round(stamp * 1e9)),
                           serialize(msg, msgtype))  # fmt: skip

    def write_image(self, topic: str, stamp: float, image_bgr: np.ndarray, frame_id: str) -> None:
        Image = self._types("sensor_msgs/msg/Image")
        self.write(
            topic, stamp, Image(header=self._header(stamp, frame_id), **image_fields(image_bgr))
        )

    def write_string(self, topic: str, stamp: float, text: str) -> None:
        """A std_msgs/String (it has no header: the bag's record time is `stamp`)."""
        self.write(topic, stamp, self._types("std_msgs/msg/String")(data=text))

    def write_odometry(self, topic: str, pose: Odometry, frame_id: str = "odom",
                       child_frame_id: str = "base_link") -> None:  # fmt: skip
        t = self._types
        point = t("geometry_msgs/msg/Point")(x=pose.x_m, y=pose.y_m, z=0.0)
        orientation = t("geometry_msgs/msg/Quaternion")(**quaternion_of_yaw(pose.yaw_rad))
        zero = t("geometry_msgs/msg/Vector3")(x=0.0, y=0.0, z=0.0)
        msg = t("nav_msgs/msg/Odometry")(
            header=self._header(pose.stamp_s, frame_id),
            child_frame_id=child_frame_id,
            pose=t("geometry_msgs/msg/PoseWithCovariance")(
                pose=t("geometry_msgs/msg/Pose")(position=point, orientation=orientation),
                covariance=np.zeros(36),
            ),
            twist=t("geometry_msgs/msg/TwistWithCovariance")(
                twist=t("geometry_msgs/msg/Twist")(linear=zero, angular=zero),
                covariance=np.zeros(36),
            ),
        )
        self.write(topic, pose.stamp_s, msg)

    def write_camera_info(
        self, topic: str, stamp: float, camera: CameraModel, frame_id: str
    ) -> None:
        fields = camera_info_fields(camera)
        if self.ros1:
            fields = {(k.upper() if k in ("d", "k", "r", "p") else k): v for k, v in fields.items()}
        roi = self._types("sensor_msgs/msg/RegionOfInterest")(
            x_offset=0, y_offset=0, height=0, width=0, do_rectify=False
        )
        msg = self._types("sensor_msgs/msg/CameraInfo")(
            header=self._header(stamp, frame_id), binning_x=0, binning_y=0, roi=roi, **fields
        )
        self.write(topic, stamp, msg)

    def close(self) -> None:
        """Finish the bag. It appears under its name whole, or not at all: a failure on
        the way removes what was written."""
        try:
            self._writer.close()
            written = self._tmp / self.path.name
            if self._single_mcap:
                (written,) = written.glob("*.mcap")
            if self.path.exists():  # made meanwhile: neither overwritten nor merged
                raise FileExistsError(f"bag {self.path} appeared while writing; not overwriting it")
            os.replace(written, self.path)  # the same folder: atomic
        finally:
            self._remove_tmp()

    def _remove_tmp(self) -> None:
        if self._tmp is not None:
            shutil.rmtree(self._tmp, ignore_errors=True)
            self._tmp = None

    def abort(self) -> None:
        """Close and remove what was written: a bag cut short by a failure would read
        back as a valid, shorter recording."""
        try:
            self._writer.close()
        finally:
            self._remove_tmp()

    def __enter__(self) -> BagWriter:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()
