"""A synthetic skeleton detector for the simulated world.

It projects every person's 18 joints into the camera at the detector's resolution and
spoils them the way a real detector does: Gaussian pixel noise, keypoints missed at
random, keypoints outside the image (or, for ankles, too near its border) lost, and
keypoints hidden behind people nearer to the camera. Each skeleton comes with the id of
the person it belongs to, for evaluation.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from follow.camera import CameraModel
from follow.frames import odom_to_base
from follow.pose.observations import ankle_point
from follow.sim.world import WorldFrame
from follow.types import L_ANKLE, NECK, NUM_KEYPOINTS, R_ANKLE, Observation, Odometry, Skeleton

_ANKLES = (R_ANKLE, L_ANKLE)


@dataclass(frozen=True)
class DetectorNoiseConfig:
    """How the synthetic detector spoils the projected joints (pixels at its resolution)."""

    neck_sigma_px: float = 2.0
    ankle_sigma_px: float = 3.0
    joint_sigma_px: float = 3.0  # every other joint
    miss_probability: float = 0.05  # per keypoint
    ankle_border_margin_px: float = 0.0  # ankles this near the image border are lost
    occlusion: bool = True  # joints behind a nearer person's body are lost
    body_half_width_m: float = 0.22  # the occluding silhouette's half width
    min_keypoints: int = 3  # fewer visible keypoints: no skeleton
    confidence_range: tuple[float, float] = (0.4, 0.95)


@dataclass(frozen=True)
class Detection:
    """A synthetic skeleton and the ground-truth person it came from."""

    skeleton: Skeleton
    person_id: int


class SyntheticDetector:
    """Skeletons of the people in a world frame, as a camera on the robot sees them."""

    def __init__(
        self, camera: CameraModel, noise: DetectorNoiseConfig | None = None, seed: int = 0
    ):
        """`camera` is the camera at the detector's resolution."""
        self.camera = camera
        self.noise = noise if noise is not None else DetectorNoiseConfig()
        self.rng = np.random.default_rng(seed)

    def detect(self, frame: WorldFrame, robot: Odometry | None = None) -> list[Detection]:
        """Detections for one frame, nearest person first. `robot` is the camera carrier's
        true pose (the frame's own by default)."""
        robot = robot if robot is not None else frame.robot
        cam, cfg = self.camera, self.noise
        seen = []
        for person in frame.people:
            kp = person.keypoints_m
            base = np.column_stack([odom_to_base(kp[:, :2], robot), kp[:, 2]])
            depth = cam.base_to_camera(base)[:, 2]
            if depth[NECK] <= 0.1:
                continue
            seen.append((float(depth[NECK]), person, cam.project(base), base))
        seen.sort(key=lambda item: item[0])

        detections: list[Detection] = []
        silhouettes: list[tuple[float, np.ndarray]] = []  # (depth, [u0, v0, u1, v1])
        for depth, person, uv_true, base in seen:
            sigma = np.full(NUM_KEYPOINTS, cfg.joint_sigma_px)
            sigma[NECK] = cfg.neck_sigma_px
            sigma[list(_ANKLES)] = cfg.ankle_sigma_px
            uv = uv_true + self.rng.normal(size=(NUM_KEYPOINTS, 2)) * sigma[:, None]
            visible = np.isfinite(uv).all(axis=1) & cam.in_image(uv)
            visible &= self.rng.random(NUM_KEYPOINTS) >= cfg.miss_probability
            if cfg.ankle_border_margin_px > 0:
                inner = cam.in_image(uv[list(_ANKLES)], cfg.ankle_border_margin_px)
                visible[list(_ANKLES)] &= inner
            if cfg.occlusion:
                for _, (u0, v0, u1, v1) in silhouettes:
                    behind = (
                        (uv[:, 0] >= u0) & (uv[:, 0] <= u1) & (uv[:, 1] >= v0) & (uv[:, 1] <= v1)
                    )
                    visible &= ~behind
            silhouettes.append((depth, self._silhouette(uv_true, base, depth)))
            if visible.sum() < cfg.min_keypoints:
                continue
            keypoints = np.where(visible[:, None], uv, np.nan)
            conf = np.where(visible, self.rng.uniform(*cfg.confidence_range, NUM_KEYPOINTS), 0.0)
            score = float(conf[visible].mean())
            detections.append(Detection(Skeleton(keypoints, conf, score), person.person_id))
        return detections

    def _silhouette(self, uv: np.ndarray, base: np.ndarray, depth_m: float) -> np.ndarray:
        """Image box [u0, v0, u1, v1] of a person's body: the projected joints' extent,
        widened to the body's width (the joints themselves are a thin stick figure)."""
        ok = np.isfinite(uv).all(axis=1)
        if not ok.any():
            return np.array([np.inf, np.inf, -np.inf, -np.inf])
        half_w_px = self.noise.body_half_width_m * self.camera.K[0, 0] / max(depth_m, 1e-3)
        u0, v0 = uv[ok].min(axis=0)
        u1, v1 = uv[ok].max(axis=0)
        centre = 0.5 * (u0 + u1)
        u0 = min(u0, centre - half_w_px)
        u1 = max(u1, centre + half_w_px)
        head_px = 0.12 * half_w_px / self.noise.body_half_width_m  # the head above the eyes
        return np.array([u0, v0 - head_px, u1, v1])


def neck_ankle_observation(skeleton: Skeleton, min_confidence: float = 0.0) -> Observation | None:
    """The tracker's view of a skeleton: the neck (required) and the ankle point, the mean
    of both ankles when both are seen, else the one seen."""
    if not skeleton.has(NECK, min_confidence):
        return None
    ankle = ankle_point(skeleton, min_confidence)
    return Observation(skeleton.keypoints_px[NECK], ankle, skeleton=skeleton)


def observations_with_ids(
    detections: list[Detection], min_confidence: float = 0.0
) -> tuple[list[Observation], list[int]]:
    """Observations of the detections that have a neck, and their people's ids."""
    observations, ids = [], []
    for d in detections:
        o = neck_ankle_observation(d.skeleton, min_confidence)
        if o is not None:
            observations.append(o)
            ids.append(d.person_id)
    return observations, ids
