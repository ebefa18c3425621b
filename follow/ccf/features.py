"""Feature maps of person crops and their integral images.

A `FeatureMaps` holds, per channel, the integral image of one person's feature maps, so
that the mean of any rectangle costs four look-ups. Rectangles are given in normalised
coordinates ([0, 1] of the map's width and height), which makes a weak classifier
independent of the crop's resolution.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import cv2
import numpy as np

from follow.types import InvalidInput

Roi = tuple[int, int, int, int]


@dataclass(frozen=True)
class FeatureMaps:
    """Per-channel integral images (C, H+1, W+1) of maps with values in about [0, 1]."""

    integral: np.ndarray

    def __post_init__(self):
        if self.integral.ndim != 3 or self.integral.shape[1] < 2 or self.integral.shape[2] < 2:
            raise InvalidInput(
                f"feature integral: expected (C, H+1, W+1), got {self.integral.shape}"
            )

    @classmethod
    def from_maps(cls, maps: np.ndarray) -> FeatureMaps:
        """From maps (C, H, W)."""
        return cls(integral_images(maps[None])[0])

    @property
    def num_channels(self) -> int:
        return int(self.integral.shape[0])

    @property
    def map_size(self) -> tuple[int, int]:
        """(height, width) of the maps."""
        return int(self.integral.shape[1]) - 1, int(self.integral.shape[2]) - 1

    def rect_means(self, channels: np.ndarray, rects: np.ndarray) -> np.ndarray:
        """Means over rectangles (..., 4) = (x0, y0, x1, y1) normalised, on `channels` (...)."""
        idx = RectIndex.build(np.asarray(rects), self.map_size)
        return idx.means(self.integral[None], np.asarray(channels))[0]


def integral_images(maps: np.ndarray) -> np.ndarray:
    """Integral images (B, C, H+1, W+1) float64 of maps (B, C, H, W), zero first row/col."""
    b, c, h, w = maps.shape
    out = np.zeros((b, c, h + 1, w + 1), dtype=np.float64)
    np.cumsum(maps, axis=2, dtype=np.float64, out=out[:, :, 1:, 1:])
    np.cumsum(out[:, :, 1:, 1:], axis=3, out=out[:, :, 1:, 1:])
    return out


@dataclass(frozen=True)
class RectIndex:
    """Integer corners of normalised rectangles on maps of one size (each side >= 1 px)."""

    r0: np.ndarray
    c0: np.ndarray
    r1: np.ndarray
    c1: np.ndarray
    inv_area: np.ndarray

    @classmethod
    def build(cls, rects: np.ndarray, map_size: tuple[int, int]) -> RectIndex:
        h, w = map_size
        c0 = np.clip(np.floor(rects[..., 0] * w + 0.5).astype(np.intp), 0, w - 1)
        r0 = np.clip(np.floor(rects[..., 1] * h + 0.5).astype(np.intp), 0, h - 1)
        c1 = np.clip(np.floor(rects[..., 2] * w + 0.5).astype(np.intp), c0 + 1, w)
        r1 = np.clip(np.floor(rects[..., 3] * h + 0.5).astype(np.intp), r0 + 1, h)
        return cls(r0, c0, r1, c1, 1.0 / ((r1 - r0) * (c1 - c0)))

    def means(self, integrals: np.ndarray, channels: np.ndarray) -> np.ndarray:
        """Rectangle means for a stack of integrals (B, C, H+1, W+1): (B, *rect shape)."""
        return _box_sum(integrals, channels, self) * self.inv_area


def _box_sum(integrals: np.ndarray, channels: np.ndarray, idx: RectIndex) -> np.ndarray:
    return (
        integrals[:, channels, idx.r1, idx.c1]
        - integrals[:, channels, idx.r0, idx.c1]
        - integrals[:, channels, idx.r1, idx.c0]
        + integrals[:, channels, idx.r0, idx.c0]
    )


@runtime_checkable
class FeatureExtractor(Protocol):
    """Turns person crops into feature maps; all people of a frame in one batch."""

    name: str
    num_channels: int
    crop_size: tuple[int, int]  # (width, height) every crop is resized to

    def extract(self, image_bgr: np.ndarray, rois: Sequence[Roi]) -> list[FeatureMaps]:
        """Feature maps of each ROI (x0, y0, x1, y1) of a BGR uint8 image."""
        ...

    def extract_crops(self, crops_bgr: Sequence[np.ndarray]) -> list[FeatureMaps]:
        """Feature maps of whole BGR uint8 crops."""
        ...


def check_image(image_bgr: np.ndarray, what: str = "image") -> None:
    if (
        not isinstance(image_bgr, np.ndarray)
        or image_bgr.ndim != 3
        or image_bgr.shape[2] != 3
        or image_bgr.dtype != np.uint8
    ):
        raise InvalidInput(
            f"{what}: expected an HxWx3 uint8 BGR array, got "
            f"{getattr(image_bgr, 'shape', type(image_bgr).__name__)} "
            f"{getattr(image_bgr, 'dtype', '')}"
        )
    if image_bgr.shape[0] < 2 or image_bgr.shape[1] < 2:
        raise InvalidInput(f"{what}: too small ({image_bgr.shape[1]}x{image_bgr.shape[0]})")


def cut_crops(image_bgr: np.ndarray, rois: Sequence[Roi], crop_size: tuple[int, int]) -> np.ndarray:
    """ROIs of an image resized to crop_size (width, height): (N, H, W, 3) uint8."""
    check_image(image_bgr)
    ih, iw = image_bgr.shape[:2]
    width, height = crop_size
    out = np.empty((len(rois), height, width, 3), dtype=np.uint8)
    for i, roi in enumerate(rois):
        x0, y0, x1, y1 = (int(v) for v in roi)
        x0, y0, x1, y1 = max(0, x0), max(0, y0), min(iw, x1), min(ih, y1)
        if x1 - x0 < 1 or y1 - y0 < 1:
            raise InvalidInput(f"ROI {roi} is empty inside a {iw}x{ih} image")
        out[i] = _resize(image_bgr[y0:y1, x0:x1], crop_size)
    return out


def resize_crops(crops_bgr: Sequence[np.ndarray], crop_size: tuple[int, int]) -> np.ndarray:
    """Whole crops resized to crop_size (width, height): (N, H, W, 3) uint8."""
    width, height = crop_size
    out = np.empty((len(crops_bgr), height, width, 3), dtype=np.uint8)
    for i, crop in enumerate(crops_bgr):
        check_image(crop, f"crop {i}")
        out[i] = _resize(crop, crop_size)
    return out


def _resize(image: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """Area averaging when shrinking (no aliasing), bilinear when enlarging."""
    shrinking = image.shape[0] >= size[1] and image.shape[1] >= size[0]
    return cv2.resize(image, size, interpolation=cv2.INTER_AREA if shrinking else cv2.INTER_LINEAR)
