"""Drawings that let a person check a calibration at a glance.

A 1 m grid on the floor, the horizon and (for a board view) the detected corners, drawn
through the camera model itself, lens distortion included: if the grid lines do not run
along straight floor features and the board's squares, the calibration is wrong.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from follow.camera import CameraModel

GRID_COLOUR = (0, 220, 0)  # BGR
AXIS_COLOUR = (0, 0, 255)
HORIZON_COLOUR = (255, 160, 0)
TEXT_COLOUR = (255, 255, 255)
SAMPLES_PER_M = 20  # points per metre along a grid line (curves through the distortion)
HORIZON_SAMPLES = 721
HORIZON_DISTANCE_M = 1.0e5
VALID_RADIUS_MARGIN = 1.05
MIN_DEPTH_M = 0.05
MAX_GRID_LINES = 10_000  # each way; a finer grid is a solid fill that takes minutes to draw


def _camera_for(image: np.ndarray, camera: CameraModel) -> CameraModel:
    """The camera scaled to the image's size (a resized frame of the same view)."""
    h, w = image.shape[:2]
    return camera.for_image_size(w, h)


def _draw_segments(image, segments, colour, thickness) -> None:
    for seg in segments:
        poly = np.round(seg * 16).astype(np.int32).reshape(-1, 1, 2)
        cv2.polylines(image, [poly], False, colour, thickness, cv2.LINE_AA, shift=4)


def _max_valid_radius(camera: CameraModel) -> float:
    """Largest undistorted normalised radius seen in the image (a little more).

    Beyond it a fitted distortion polynomial may fold back, drawing points that are far
    outside the view inside the image; such points are not drawn.
    """
    w, h = camera.image_size
    t = np.linspace(0.0, 1.0, 33)
    border = np.concatenate(
        [
            np.column_stack([t * (w - 1), np.zeros_like(t)]),
            np.column_stack([t * (w - 1), np.full_like(t, h - 1)]),
            np.column_stack([np.zeros_like(t), t * (h - 1)]),
            np.column_stack([np.full_like(t, w - 1), t * (h - 1)]),
        ]
    )
    rays = camera.pixel_rays_base(border) @ camera.rotation_base_from_cam  # camera frame
    radius = np.hypot(rays[:, 0], rays[:, 1]) / rays[:, 2]
    return float(np.nanmax(radius) * VALID_RADIUS_MARGIN)  # NaN: a pixel with no ray


def _polyline_segments(camera: CameraModel, points_base: np.ndarray) -> list[np.ndarray]:
    """Projected runs of consecutive points that are in front of the camera and in view."""
    pixels = camera.project(points_base)
    pc = camera.base_to_camera(points_base)
    ok = pc[:, 2] > MIN_DEPTH_M
    with np.errstate(divide="ignore", invalid="ignore"):
        radius = np.hypot(pc[:, 0], pc[:, 1]) / pc[:, 2]
    ok &= radius <= _max_valid_radius(camera)
    ok &= np.isfinite(pixels).all(axis=1)
    segments, current = [], []
    for p, good in zip(pixels, ok, strict=True):
        if good:
            current.append(p)
        elif current:
            segments.append(np.array(current))
            current = []
    if current:
        segments.append(np.array(current))
    return [s for s in segments if len(s) >= 2]


def visible_ground_extent(camera: CameraModel, max_range_m: float) -> tuple[float, ...] | None:
    """(x_min, x_max, y_min, y_max) of the floor seen in the image, within `max_range_m`."""
    w, h = camera.image_size
    us, vs = np.linspace(0, w - 1, 33), np.linspace(0, h - 1, 25)
    uu, vv = np.meshgrid(us, vs)
    ground = camera.back_project_to_ground(np.column_stack([uu.ravel(), vv.ravel()]))
    ground = ground[np.isfinite(ground).all(axis=1)]
    if ground.size == 0:
        return None
    offset = ground - camera.position_base[:2]
    dist = np.linalg.norm(offset, axis=1)
    far = dist > max_range_m
    ground[far] = camera.position_base[:2] + offset[far] * (max_range_m / dist[far])[:, None]
    return (ground[:, 0].min(), ground[:, 0].max(), ground[:, 1].min(), ground[:, 1].max())


def draw_ground_grid(
    image: np.ndarray,
    camera: CameraModel,
    step_m: float = 1.0,
    max_range_m: float = 10.0,
    thickness: int = 1,
) -> np.ndarray:
    """Draw lines x = k*step and y = k*step on the floor (in `base`); axes x=0, y=0 in red."""
    if not (math.isfinite(step_m) and step_m > 0):
        raise ValueError(f"grid step must be positive metres, got {step_m}")
    camera = _camera_for(image, camera)
    extent = visible_ground_extent(camera, max_range_m)
    if extent is None:
        return image
    x0, x1, y0, y1 = extent
    lines = max(x1 - x0, y1 - y0) / step_m
    if lines > MAX_GRID_LINES:
        raise ValueError(
            f"a grid step of {step_m:g} m draws {lines:.3g} lines across the "
            f"{max(x1 - x0, y1 - y0):.1f} m of floor in view, more than {MAX_GRID_LINES}: "
            "give a larger grid step"
        )
    xs = np.arange(math.floor(x0 / step_m), math.ceil(x1 / step_m) + 1) * step_m
    ys = np.arange(math.floor(y0 / step_m), math.ceil(y1 / step_m) + 1) * step_m
    for fixed_x in (True, False):
        values, span = (xs, (ys[0], ys[-1])) if fixed_x else (ys, (xs[0], xs[-1]))
        n = max(2, int((span[1] - span[0]) * SAMPLES_PER_M) + 1)
        run = np.linspace(span[0], span[1], n)
        for value in values:
            if fixed_x:
                pts = np.column_stack([np.full(n, value), run, np.zeros(n)])
            else:
                pts = np.column_stack([run, np.full(n, value), np.zeros(n)])
            colour = AXIS_COLOUR if abs(value) < 1e-9 else GRID_COLOUR
            _draw_segments(image, _polyline_segments(camera, pts), colour, thickness)
    return image


def draw_horizon(image: np.ndarray, camera: CameraModel, thickness: int = 2) -> np.ndarray:
    """The horizon: the image of floor points infinitely far away, in every direction."""
    camera = _camera_for(image, camera)
    azimuth = np.linspace(-math.pi, math.pi, HORIZON_SAMPLES)
    centre = camera.position_base
    pts = np.column_stack(
        [
            centre[0] + HORIZON_DISTANCE_M * np.cos(azimuth),
            centre[1] + HORIZON_DISTANCE_M * np.sin(azimuth),
            np.zeros_like(azimuth),
        ]
    )
    _draw_segments(image, _polyline_segments(camera, pts), HORIZON_COLOUR, thickness)
    return image


def draw_text_lines(image: np.ndarray, lines: list[str]) -> np.ndarray:
    """White text on a dark band along the top of the image."""
    scale = max(0.45, image.shape[1] / 1300.0)
    (_, text_h), baseline = cv2.getTextSize("Hg", cv2.FONT_HERSHEY_SIMPLEX, scale, 1)
    step = text_h + baseline + 6
    band = image[: step * len(lines) + 6]
    band[:] = (band * 0.35).astype(image.dtype)
    for i, line in enumerate(lines):
        origin = (8, 4 + step * i + text_h + 2)
        cv2.putText(
            image, line, origin, cv2.FONT_HERSHEY_SIMPLEX, scale, TEXT_COLOUR, 1, cv2.LINE_AA
        )
    return image


def calibration_overlay(
    image: np.ndarray,
    camera: CameraModel,
    corners_px: np.ndarray | None = None,
    pattern_size: tuple[int, int] | None = None,
    grid_step_m: float = 1.0,
    max_range_m: float = 10.0,
    lines: list[str] | None = None,
) -> np.ndarray:
    """A BGR copy of `image` with the ground grid, the horizon and the detected corners.

    `image` may be of another size than the camera's (same aspect): the camera is scaled.
    """
    out = np.asarray(image)
    if out.ndim == 2:
        out = cv2.cvtColor(out, cv2.COLOR_GRAY2BGR)
    else:
        out = out.copy()
    camera = _camera_for(out, camera)
    draw_ground_grid(out, camera, grid_step_m, max_range_m)
    draw_horizon(out, camera)
    if corners_px is not None and pattern_size is not None:
        corners = np.asarray(corners_px, dtype=np.float32).reshape(-1, 1, 2)
        cv2.drawChessboardCorners(out, tuple(pattern_size), corners, True)
    if lines:
        draw_text_lines(out, lines)
    return out
