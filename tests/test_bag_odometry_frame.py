"""A bag's odometry topic carrying two publishers' frames (an `odom` and a `map`
estimate): only the frame of the first sample is kept, as the ROS 2 node keeps only
`ros.odom_frame`'s; both blended swung each image's pose between the two frames."""

from __future__ import annotations

import logging

import numpy as np
import pytest

from follow.bag import BagSource
from follow.bag_writer import BagWriter
from follow.types import Odometry

TOPIC = "/camera/image_raw"
SPEED_MPS = 0.5
MAP_OFFSET_M = 0.15  # where the `map` estimate puts the robot, ahead of `odom`'s


def write_bag(path, frame_of_sample) -> None:
    """50 Hz odometry of a robot at SPEED_MPS, sample k in `frame_of_sample(k)` (offset
    by MAP_OFFSET_M in "map"), and images in between."""
    rng = np.random.default_rng(0)
    with BagWriter(path) as bag:
        for k in range(60):
            t = 999.9 + 0.01 * k
            frame = frame_of_sample(k)
            x_m = SPEED_MPS * (t - 1000.0) + (MAP_OFFSET_M if frame == "map" else 0.0)
            bag.write_odometry("/odom", Odometry(x_m, 0.0, 0.0, t), frame_id=frame)
            if k % 7 == 3 and k < 55:
                image = rng.integers(0, 255, (48, 64, 3), dtype=np.uint8)
                bag.write_image(TOPIC, t + 0.004, image, "camera")


def pose_errors_m(path) -> list[float]:
    """Each image's pose from the bag, less the robot's position in the first frame."""
    source = BagSource(str(path), TOPIC, "/odom")
    errors = [source.odometry_at(f.stamp_s).x_m - SPEED_MPS * (f.stamp_s - 1000.0)
              for f in source]  # fmt: skip
    source.close()
    assert len(errors) == 8
    return errors


def test_samples_of_another_frame_are_dropped_with_one_warning(tmp_path, caplog):
    path = tmp_path / "two_frames.mcap"
    write_bag(path, lambda k: "odom" if k % 2 == 0 else "map")
    with caplog.at_level(logging.WARNING, logger="follow.bag"):
        errors = pose_errors_m(path)
    assert errors == pytest.approx([0.0] * len(errors), abs=1e-9)
    (warning,) = [r.getMessage() for r in caplog.records if "frame" in r.getMessage()]
    assert "30 odometry message(s) on /odom skipped: in frame 'map', not 'odom'" in warning


@pytest.mark.parametrize(
    "frame_of_sample",
    [lambda k: "", lambda k: "odom" if k % 2 == 0 else "", lambda k: "/odom" if k % 2 else "odom"],
    ids=["no frame ids", "some without a frame id", "a leading slash"],
)
def test_odometry_in_one_frame_is_all_kept(tmp_path, caplog, frame_of_sample):
    path = tmp_path / "one_frame.mcap"
    write_bag(path, frame_of_sample)
    with caplog.at_level(logging.WARNING, logger="follow.bag"):
        errors = pose_errors_m(path)
    assert errors == pytest.approx([0.0] * len(errors), abs=1e-9)
    assert not caplog.records
