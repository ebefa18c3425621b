"""A bag's frame rate (the rate `--output-video` is written at) comes from the images'
header stamps, the times frames are played by: the recorder's receive times, whose
clock may step, once gave 0.005 fps and a 2 s recording as a video hours long."""

from __future__ import annotations

import logging

import numpy as np
import pytest

from follow.bag import BagSource
from follow.bag_writer import BagWriter
from follow.capture import FALLBACK_FPS
from follow.rosmsg import image_fields, stamp_fields

TOPIC = "/camera/image_raw"


def write_image(bag: BagWriter, record_s: float, header_s: float, seed: int) -> None:
    """An image stamped `header_s` in its header, recorded at `record_s`."""
    types = bag.typestore.types
    stamp = types["builtin_interfaces/msg/Time"](**stamp_fields(header_s))
    header = types["std_msgs/msg/Header"](stamp=stamp, frame_id="camera")
    image = np.random.default_rng(seed).integers(0, 255, (48, 64, 3), dtype=np.uint8)
    bag.write(TOPIC, record_s, types["sensor_msgs/msg/Image"](header=header, **image_fields(image)))


def frame_rate(path, records_s: list[float], headers_s: list[float]) -> float:
    """BagSource's fps of a bag of images recorded at `records_s`, stamped `headers_s`."""
    with BagWriter(path) as bag:
        for k, (record_s, header_s) in enumerate(zip(records_s, headers_s, strict=True)):
            write_image(bag, record_s, header_s, k)
    source = BagSource(str(path), TOPIC)
    source.close()
    return source.fps


def test_a_recorder_clock_that_stepped_leaves_the_rate_of_the_images_stamps(tmp_path):
    header_s = [1000.0 + 0.1 * k for k in range(20)]
    record_s = [t + (3600.0 if k >= 10 else 0.0) for k, t in enumerate(header_s)]
    assert frame_rate(tmp_path / "step.mcap", record_s, header_s) == pytest.approx(10)


def test_a_gap_in_the_images_leaves_their_rate(tmp_path):
    header_s = [1000.0 + 0.1 * k + (60.0 if k >= 10 else 0.0) for k in range(20)]
    assert frame_rate(tmp_path / "gap.mcap", header_s, header_s) == pytest.approx(10)


def test_a_rate_no_video_is_trusted_at_is_warned_of_and_replaced(tmp_path, caplog):
    header_s = [1000.0 + 200.0 * k for k in range(5)]
    with caplog.at_level(logging.WARNING, logger="follow.bag"):
        fps = frame_rate(tmp_path / "slow.mcap", header_s, header_s)
    assert fps == FALLBACK_FPS
    assert "the images' frame rate, 0.005 fps (by their stamps), is outside 1-240 fps" in (
        caplog.text
    )
