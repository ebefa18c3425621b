"""Sanity figures for a calibration from annotated person boxes (PETS 2009 style).

A calibration of a fixed camera can be checked without a survey: people walk at about
1 m/s and stand 1.6-1.9 m tall. Each annotated box's bottom centre is back-projected to
the ground (walking speed from consecutive frames), and the ray through its top centre
is met with the vertical through that ground point (stature).

The annotation XML: `<frame number=N><objectlist><object id=I><box xc yc w h/>`, pixels.
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

import numpy as np


class BoxFileError(ValueError):
    """An annotation file that cannot be read: the message names the file and the place."""


def _rays_and_centre(camera, pixels: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Viewing rays and camera centre of a `TsaiCamera` (world) or `CameraModel` (base)."""
    if hasattr(camera, "pixel_rays_world"):
        return camera.pixel_rays_world(pixels), camera.position_world_m
    return camera.pixel_rays_base(pixels), camera.position_base


@dataclass(frozen=True)
class Box:
    frame: int
    person_id: int
    xc_px: float
    yc_px: float
    w_px: float
    h_px: float


# A frame number past this is a typing error, not a video: 11 hours at 25 fps (and every
# frame up to it would be read).
MAX_FRAME_NUMBER = 1_000_000


def read_boxes(path: str | Path) -> list[Box]:
    """All boxes of an annotation file, in file order."""
    path = Path(path)
    try:
        root = ET.parse(path).getroot()
    except OSError as exc:
        raise BoxFileError(f"box file {path}: cannot read ({exc.strerror})") from None
    except ET.ParseError as exc:
        raise BoxFileError(f"box file {path}: not valid XML ({exc})") from None
    boxes = []
    for frame in root.iter("frame"):
        try:
            number = int(frame.get("number", ""))
        except ValueError:
            raise BoxFileError(
                f"box file {path}: <frame> has no integer 'number' ({frame.get('number')!r})"
            ) from None
        if not 0 <= number <= MAX_FRAME_NUMBER:
            raise BoxFileError(f"box file {path}: frame number {number} is outside "
                               f"0..{MAX_FRAME_NUMBER}")  # fmt: skip
        for obj in frame.iter("object"):
            box = obj.find("box")
            try:
                person_id = int(obj.get("id", ""))
                if box is None:
                    raise ValueError("no <box>")
                values = [float(box.get(k, "")) for k in ("xc", "yc", "w", "h")]
            except ValueError as exc:
                raise BoxFileError(
                    f"box file {path}: frame {number}, object {obj.get('id')!r}: "
                    f"needs an integer id and a <box> with numeric xc, yc, w, h ({exc})"
                ) from None
            if not all(math.isfinite(v) for v in values) or values[2] <= 0 or values[3] <= 0:
                raise BoxFileError(
                    f"box file {path}: frame {number}, object {person_id}: the box needs "
                    f"finite xc, yc and a positive w, h, got {values}"
                )
            boxes.append(Box(number, person_id, *values))
    if not boxes:
        raise BoxFileError(f"box file {path}: no <frame>/<object>/<box> entries")
    return boxes


def statures_m(camera, boxes: list[Box]) -> np.ndarray:
    """Implied body height of each box (NaN when its foot point is above the horizon)."""
    feet = np.array([[b.xc_px, b.yc_px + b.h_px / 2.0] for b in boxes])
    heads = np.array([[b.xc_px, b.yc_px - b.h_px / 2.0] for b in boxes])
    ground = camera.back_project_to_plane(feet, 0.0)
    rays, centre = _rays_and_centre(camera, heads)
    horizontal = rays[:, :2]
    with np.errstate(divide="ignore", invalid="ignore"):
        s = np.sum((ground[:, :2] - centre[:2]) * horizontal, axis=1) / np.sum(
            horizontal * horizontal, axis=1
        )
    return centre[2] + s * rays[:, 2]


def walking_speeds_mps(camera, boxes: list[Box], fps: float) -> np.ndarray:
    """Ground speed of each person between consecutive annotated frames."""
    if not (math.isfinite(fps) and fps > 0):
        raise ValueError(f"fps must be positive, got {fps}")
    feet = np.array([[b.xc_px, b.yc_px + b.h_px / 2.0] for b in boxes])
    ground = camera.back_project_to_plane(feet, 0.0)[:, :2]
    last: dict[int, tuple[int, np.ndarray]] = {}
    speeds = []
    for box, point in zip(boxes, ground, strict=True):
        previous = last.get(box.person_id)
        if previous is not None and box.frame > previous[0]:
            dt = (box.frame - previous[0]) / fps
            speeds.append(float(np.linalg.norm(point - previous[1])) / dt)
        last[box.person_id] = (box.frame, point)
    return np.array(speeds)


def motion_figures(camera, boxes: list[Box], fps: float) -> dict:
    """Median walking speed and stature implied by the boxes through `camera`."""
    speeds = walking_speeds_mps(camera, boxes, fps)
    statures = statures_m(camera, boxes)
    speeds = speeds[np.isfinite(speeds)]
    statures = statures[np.isfinite(statures)]
    return {
        "boxes": len(boxes),
        "median_walking_speed_mps": float(np.median(speeds)) if speeds.size else math.nan,
        "median_stature_m": float(np.median(statures)) if statures.size else math.nan,
    }
