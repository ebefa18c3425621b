"""Drawing what the robot sees and does: skeletons, tracks with their expected neck/ankle
ellipses, the target, the state machine's state and the command; and a top-down view of
the tracks around the robot."""

from __future__ import annotations

import math

import cv2
import numpy as np

from follow.frames import odom_to_base
from follow.types import Odometry, Skeleton, TargetEstimate, TrackState, VelocityCommand

# Limbs drawn for a skeleton (pairs of keypoint indices).
LIMBS = (
    (1, 2), (1, 5), (2, 3), (3, 4), (5, 6), (6, 7), (1, 8), (8, 9), (9, 10),
    (1, 11), (11, 12), (12, 13), (1, 0), (0, 14), (14, 16), (0, 15), (15, 17),
)  # fmt: skip
TARGET_BGR = (0, 0, 255)
TRACK_BGR = (255, 160, 0)
TENTATIVE_BGR = (160, 160, 160)
SKELETON_BGR = (0, 220, 255)


def _pt(p: np.ndarray) -> tuple[int, int]:
    return int(round(float(p[0]))), int(round(float(p[1])))


def draw_skeletons(image: np.ndarray, skeletons: list[Skeleton]) -> None:
    for s in skeletons:
        for a, b in LIMBS:
            if s.has(a) and s.has(b):
                cv2.line(image, _pt(s.keypoints_px[a]), _pt(s.keypoints_px[b]), SKELETON_BGR, 1)
        for k in range(len(s.keypoints_px)):
            if s.has(k):
                cv2.circle(image, _pt(s.keypoints_px[k]), 2, SKELETON_BGR, -1)


def draw_ellipse(image, mean_px, cov_px, color, n_sigma: float = 2.0) -> None:
    """The n-sigma ellipse of a 2-D Gaussian in pixels."""
    if mean_px is None or cov_px is None or not np.isfinite(mean_px).all():
        return
    vals, vecs = np.linalg.eigh(0.5 * (cov_px + cov_px.T))
    vals = np.clip(vals, 1e-6, 1e8)
    axes = (int(n_sigma * math.sqrt(vals[1])), int(n_sigma * math.sqrt(vals[0])))
    angle = math.degrees(math.atan2(vecs[1, 1], vecs[0, 1]))
    if max(axes) > 5 * max(image.shape):
        return
    cv2.ellipse(image, _pt(mean_px), axes, angle, 0, 360, color, 1)


def annotate(
    image: np.ndarray,
    skeletons: list[Skeleton],
    tracks: list[TrackState],
    target: TargetEstimate | None,
    command: VelocityCommand | None,
) -> np.ndarray:
    """A copy of the frame with everything the robot knows drawn on it."""
    out = image.copy()
    draw_skeletons(out, skeletons)
    target_id = target.target_id if target is not None else None
    for t in tracks:
        color = TARGET_BGR if t.track_id == target_id else (
            TRACK_BGR if t.confirmed else TENTATIVE_BGR
        )
        draw_ellipse(out, t.expected_neck_px, t.expected_neck_cov, color)
        draw_ellipse(out, t.expected_ankle_px, t.expected_ankle_cov, color)
        if t.expected_neck_px is not None and np.isfinite(t.expected_neck_px).all():
            conf = target.confidences.get(t.track_id) if target is not None else None
            label = f"{t.track_id}" + ("" if conf is None else f" {conf:+.2f}")
            x, y = _pt(t.expected_neck_px)
            cv2.putText(out, label, (x + 4, y - 6), cv2.FONT_HERSHEY_SIMPLEX, 0.4, color, 1)
    lines = []
    if target is not None:
        lines.append(f"{target.status.value}  target={target.target_id}")
    if command is not None:
        lines.append(f"cmd v={command.forward_mps:+.2f} m/s  w={command.yaw_rate_radps:+.2f} rad/s")
    for i, text in enumerate(lines):
        y = 16 + 16 * i
        cv2.putText(out, text, (6, y), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 0, 0), 3)
        cv2.putText(out, text, (6, y), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (255, 255, 255), 1)
    return out


def top_down(
    tracks: list[TrackState],
    target_id: int | None,
    robot: Odometry | None,
    size_px: int = 360,
    range_m: float = 12.0,
) -> np.ndarray:
    """A square view in the robot frame: robot at the bottom centre, x up, 1 m grid."""
    img = np.full((size_px, size_px, 3), 255, np.uint8)
    scale = size_px / range_m
    origin = np.array([size_px / 2.0, size_px - 10.0])

    def to_px(xy_base: np.ndarray) -> tuple[int, int]:
        return _pt(origin + scale * np.array([-xy_base[1], -xy_base[0]]))

    for m in range(-int(range_m), int(range_m) + 1):
        cv2.line(img, to_px((m, -range_m)), to_px((m, range_m)), (230, 230, 230), 1)
        cv2.line(img, to_px((0, m)), to_px((range_m, m)), (230, 230, 230), 1)
    robot = robot or Odometry.origin()
    cv2.circle(img, to_px((0.0, 0.0)), 6, (40, 40, 40), -1)
    cv2.line(img, to_px((0.0, 0.0)), to_px((0.6, 0.0)), (40, 40, 40), 2)
    for t in tracks:
        p = odom_to_base(t.position_m, robot)
        color = TARGET_BGR if t.track_id == target_id else (
            TRACK_BGR if t.confirmed else TENTATIVE_BGR
        )
        cv2.circle(img, to_px(p), 5, color, -1)
        cv2.putText(img, str(t.track_id), to_px(p + (0.3, -0.3)), cv2.FONT_HERSHEY_SIMPLEX,
                    0.4, color, 1)  # fmt: skip
    return img
