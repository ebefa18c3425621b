"""The no-filter baseline: each observation's ankle pixel back-projected to the floor.

It is what the tracker is measured against: no motion model, no height, no memory.
Observations without an ankle (or with one on or above the horizon) give nothing.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence

import numpy as np

from follow.camera import CameraModel
from follow.config import TrackerConfig
from follow.frames import base_to_odom
from follow.types import Observation, Odometry
from follow.ukf.models import population_ankle_height_m
from follow.ukf.tracker import check_observation

log = logging.getLogger(__name__)


class DirectBaseline:
    """Ground positions straight from the ankle pixels, one per observation."""

    def __init__(self, camera: CameraModel, config: TrackerConfig | None = None):
        self.camera = camera
        self.config = config if config is not None else TrackerConfig()

    def update(
        self,
        observations: Sequence[Observation],
        stamp_s: float,
        robot: Odometry | None = None,
    ) -> list[np.ndarray | None]:
        """Per observation (same order): its ground position (2,) in `odom`, or None."""
        if not math.isfinite(stamp_s):
            log.warning("ignoring a frame with a non-finite timestamp %r", stamp_s)
            return [None] * len(observations)
        robot = robot if robot is not None else Odometry.origin(stamp_s)
        out: list[np.ndarray | None] = []
        for o in observations:
            o = check_observation(o, self.camera, self.config.max_outside_image_px)
            if o is None or o.ankle_px is None:
                out.append(None)
                continue
            p = self.camera.back_project_to_plane(o.ankle_px, population_ankle_height_m(self.config))
            out.append(None if np.isnan(p).any() else base_to_odom(p[:2], robot))
        return out
