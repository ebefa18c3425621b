"""PETS 2009 frames dressed as a robot's recording: the imported camera, a few frames,
and a synthetic odometry track (the robot creeping forward and turning slowly), shared
by the bag and ROS 2 tests."""

from __future__ import annotations

import math
from pathlib import Path

from follow.camera import CameraModel
from follow.capture import FrameSource
from follow.types import Frame, Odometry

START_S = 1000.0  # a bag's stamps are wall-clock seconds, not frame indices
CONFIG_TOML = "[pose]\ninput_height_px = 368\ninput_height_from_camera = false\n"


def robot_pose(stamp_s: float) -> Odometry:
    """The synthetic odometry: 0.2 m/s forward along a 0.05 rad/s turn."""
    t = stamp_s - START_S
    return Odometry(0.2 * t * math.cos(0.025 * t), 0.2 * t * math.sin(0.025 * t), 0.05 * t, stamp_s)


def pets_camera(data_path, out: Path) -> tuple[CameraModel, Path]:
    """The PETS View_001 camera, imported from its Tsai calibration and saved in `out`."""
    from calib.tsai import TsaiCamera

    camera, _ = TsaiCamera.from_xml(data_path("pets2009_s2l1/View_001.xml")).to_camera_model()
    camera.save(out / "pets.yaml")
    return camera, out / "pets.yaml"


def pets_frames(data_path, count: int) -> list[Frame]:
    """The first `count` frames of View_001, stamped from START_S."""
    source = FrameSource(str(data_path("pets2009_s2l1/View_001.avi")))
    frames = []
    try:
        for frame in source:
            frames.append(Frame(frame.image, START_S + frame.stamp_s))
            if len(frames) == count:
                break
    finally:
        source.close()
    return frames
