"""The image region a person's appearance is learnt from, cut from neck and ankle pixels.

The box is centred between the neck and the ankle (shifted by a configured fraction of
their distance) and its sides are proportional to that distance, so it covers the same
part of the body at any range. Without an ankle, the ankle is extrapolated from the hip
with an assumed body proportion, or else taken at the image bottom below the neck (the
feet of a close person are out of view).

A track's crop is the ROI of the observation associated with it in this frame; a track
without one (occluded, missed) has no crop. A track's ROI is the whole box, reaching
outside the image where its border cuts the person: the crop pads the part outside
(`follow.ccf.features.cut_crops`), so that the body keeps its shape and its place in
the crop. The box a person occupies (`person_boxes`) is clipped to the image. A person
hidden behind another still occupies a box, from the tracker's expected neck and ankle
pixels, so that a crossing is noticed while one of the two is hidden.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from follow.config import IdentifyConfig
from follow.types import Observation, TrackState

Roi = tuple[int, int, int, int]  # x0, y0, x1, y1 in pixels, half-open
R_HIP, L_HIP = 8, 11
HIP_MIN_CONFIDENCE = 0.0
# A body part's band in a crop leaves out this fraction of the part's length at each
# end (the joints, where two parts meet) and keeps the middle of the crop's width
# (the body, not the background beside it).
PART_TRIM_FRACTION = 0.1
PART_COLUMNS = (0.25, 0.75)


def _point(value, name: str) -> np.ndarray | None:
    if value is None:
        return None
    p = np.asarray(value, dtype=np.float64).reshape(-1)
    if p.shape != (2,) or not np.isfinite(p).all():
        return None
    return p


def roi_from_keypoints(
    neck_px,
    ankle_px,
    image_size: tuple[int, int],
    config: IdentifyConfig,
    hip_px=None,
    whole: bool = False,
) -> Roi | None:
    """(x0, y0, x1, y1) of a person's box clipped to the image (width, height), or None.
    With `whole`, the same box not clipped: where the image border cuts the person it
    reaches outside the image (for a crop padded there rather than stretched).

    None when the box would be degenerate (ankle not below the neck), too small
    (`min_roi_height_px`) or mostly outside the image (`min_roi_visible_fraction`).
    """
    box = _box(neck_px, ankle_px, image_size, config, hip_px)
    if box is None:
        return None
    (x0, y0, x1, y1), visible, unclipped = box
    if visible < config.min_roi_visible_fraction or (y1 - y0) < config.min_roi_height_px:
        return None
    return unclipped if whole else (x0, y0, x1, y1)


def body_box(neck_px, ankle_px, image_size: tuple[int, int], config: IdentifyConfig,
             hip_px=None) -> Roi | None:  # fmt: skip
    """The part of the image a person covers, as `roi_from_keypoints` cuts it but with
    none of its filters for a usable crop: a person close to the camera, feet out of
    view, still hides whoever stands behind them."""
    box = _box(neck_px, ankle_px, image_size, config, hip_px)
    return None if box is None else box[0]


def clip_roi(roi: Roi, image_size: tuple[int, int]) -> Roi:
    """The part of a ROI inside the image (width, height)."""
    x0, y0, x1, y1 = roi
    return max(0, x0), max(0, y0), min(int(image_size[0]), x1), min(int(image_size[1]), y1)


def _box(neck_px, ankle_px, image_size, config: IdentifyConfig, hip_px=None):
    """((x0, y0, x1, y1) clipped to the image, the share of the whole box inside it, the
    whole box), or None for no neck, an ankle not below it, or a clipped box under 2 px
    either way."""
    width, height = int(image_size[0]), int(image_size[1])
    if width <= 0 or height <= 0:
        raise ValueError(f"roi_from_keypoints: image_size must be positive, got {image_size}")
    neck = _point(neck_px, "neck")
    if neck is None:
        return None
    ankle = _point(ankle_px, "ankle")
    if ankle is None:
        hip = _point(hip_px, "hip")
        if hip is not None and hip[1] > neck[1]:
            ankle = neck + (hip - neck) * config.neck_ankle_per_neck_hip
        else:
            ankle = np.array([neck[0], float(height)])
    axis = ankle - neck
    length_px = math.hypot(axis[0], axis[1])
    if axis[1] <= 0.5 * length_px or length_px <= 0.0:  # ankle not below the neck
        return None
    box_h = config.roi_height_per_neck_ankle * length_px
    box_w = config.roi_width_per_neck_ankle * length_px
    centre = neck + (0.5 + config.roi_center_offset_per_neck_ankle) * axis
    fx0, fy0 = centre[0] - 0.5 * box_w, centre[1] - 0.5 * box_h
    fx1, fy1 = fx0 + box_w, fy0 + box_h
    unclipped = (int(round(fx0)), int(round(fy0)), int(round(fx1)), int(round(fy1)))
    x0, y0, x1, y1 = clip_roi(unclipped, (width, height))
    if x1 - x0 < 2 or y1 - y0 < 2:
        return None
    return (x0, y0, x1, y1), (x1 - x0) * (y1 - y0) / (box_w * box_h), unclipped


def body_rows(config: IdentifyConfig) -> tuple[float, float, float]:
    """Where the neck, the hips and the ankles fall in a crop cut by
    `roi_from_keypoints`, as fractions of its height from the top."""
    height = config.roi_height_per_neck_ankle
    neck = 0.5 - (0.5 + config.roi_center_offset_per_neck_ankle) / height
    hip = neck + 1.0 / (config.neck_ankle_per_neck_hip * height)
    return neck, hip, neck + 1.0 / height


def part_bands(config: IdentifyConfig) -> dict[str, tuple[float, float, float, float]]:
    """The torso (neck to hips) and the legs (hips to ankles) in a crop: (top, bottom,
    left, right) as fractions of its height and width."""
    neck, hip, ankle = body_rows(config)
    left, right = PART_COLUMNS
    out = {}
    for name, (top, bottom) in (("torso", (neck, hip)), ("legs", (hip, ankle))):
        trim = PART_TRIM_FRACTION * (bottom - top)
        out[name] = (top + trim, bottom - trim, left, right)
    return out


def track_rois(
    tracks: Sequence[TrackState], image_size: tuple[int, int], config: IdentifyConfig
) -> dict[int, Roi]:
    """track id -> ROI for the tracks with an observation this frame and a usable box:
    the whole box, reaching outside the image where its border cuts the person (the
    crop is padded there, `cut_crops`)."""
    out = {}
    for track in tracks:
        obs = track.observation
        if obs is None:
            continue
        ankle = obs.ankle_px if obs.ankle_px is not None else track.expected_ankle_px
        roi = roi_from_keypoints(obs.neck_px, ankle, image_size, config, hip_px=hip_of(obs),
                                 whole=True)  # fmt: skip
        if roi is not None:
            out[track.track_id] = roi
    return out


def person_boxes(
    tracks: Sequence[TrackState],
    rois: dict[int, Roi],
    image_size: tuple[int, int],
    config: IdentifyConfig,
) -> dict[int, Roi]:
    """track id -> the box a person occupies in the image: its ROI clipped to the image
    when seen, else (`body_box`, no crop filters) the box of its observed keypoints, or
    of the tracker's expected neck and ankle pixels (a person hidden behind another)."""
    out = {i: clip_roi(roi, image_size) for i, roi in rois.items()}
    for track in tracks:
        if track.track_id in out:
            continue
        obs = track.observation
        if obs is not None:
            ankle = obs.ankle_px if obs.ankle_px is not None else track.expected_ankle_px
            box = body_box(obs.neck_px, ankle, image_size, config, hip_px=hip_of(obs))
        elif track.expected_neck_px is not None and track.expected_ankle_px is not None:
            box = body_box(track.expected_neck_px, track.expected_ankle_px, image_size, config)
        else:
            box = None
        if box is not None:
            out[track.track_id] = box
    return out


def covered_fraction(box, other) -> float:
    """Fraction of `box`'s area (x0, y0, x1, y1) that `other` covers."""
    w = min(box[2], other[2]) - max(box[0], other[0])
    h = min(box[3], other[3]) - max(box[1], other[1])
    area = (box[2] - box[0]) * (box[3] - box[1])
    return max(0, w) * max(0, h) / area if area > 0 else 0.0


def hip_of(observation: Observation) -> np.ndarray | None:
    """Mean of the detected hips of the observation's skeleton, if any."""
    skeleton = observation.skeleton
    if skeleton is None:
        return None
    hips = [skeleton.keypoints_px[k] for k in (R_HIP, L_HIP) if skeleton.has(k, HIP_MIN_CONFIDENCE)]
    return np.mean(hips, axis=0) if hips else None
