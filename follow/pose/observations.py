"""Skeletons -> the neck/ankle observations the tracker uses."""

from __future__ import annotations

import numpy as np

from follow.config import PoseConfig
from follow.types import L_ANKLE, NECK, R_ANKLE, Observation, Skeleton


def ankle_point(skeleton: Skeleton, min_confidence: float) -> np.ndarray | None:
    """Mean of the two ankles when both pass `min_confidence`, else the one that does."""
    seen = [skeleton.keypoints_px[k] for k in (R_ANKLE, L_ANKLE) if skeleton.has(k, min_confidence)]
    if not seen:
        return None
    return np.mean(seen, axis=0)


def touches_border(skeleton: Skeleton, image_size: tuple[int, int], margin_px: float) -> bool:
    """Whether any found keypoint lies within `margin_px` of the image edge, i.e. the
    person may be cut off and the ankle (or the neck) may not be the real one."""
    width, height = image_size
    pts = skeleton.keypoints_px[np.isfinite(skeleton.keypoints_px).all(axis=1)]
    if len(pts) == 0:
        return False
    x, y = pts[:, 0], pts[:, 1]
    return bool(
        (x < margin_px).any()
        or (y < margin_px).any()
        or (x > width - 1 - margin_px).any()
        or (y > height - 1 - margin_px).any()
    )


def skeletons_to_observations(
    skeletons: list[Skeleton], image_size: tuple[int, int], config: PoseConfig
) -> list[Observation]:
    """One Observation per skeleton whose neck passes the confidence threshold.

    `image_size` is (width, height) of the frame the skeletons were detected in.
    Skeletons without a neck are dropped: the tracker's measurement model needs it.
    """
    out = []
    for skeleton in skeletons:
        if not skeleton.has(NECK, config.keypoint_min_confidence):
            continue
        out.append(
            Observation(
                neck_px=skeleton.keypoints_px[NECK],
                ankle_px=ankle_point(skeleton, config.keypoint_min_confidence),
                touches_border=touches_border(skeleton, image_size, config.border_margin_px),
                skeleton=skeleton,
            )
        )
    return out
