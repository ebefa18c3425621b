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

from follow.ccf.roi import clip_roi
from follow.types import InvalidInput

Roi = tuple[int, int, int, int]


@dataclass(frozen=True)
class FeatureMaps:
    """Integral images (H+1, W+1, C), float32, of one person's maps with values in about
    [0, 1]; channels last, as OpenCV computes them."""

    integral: np.ndarray

    def __post_init__(self):
        if self.integral.ndim != 3 or self.integral.shape[0] < 2 or self.integral.shape[1] < 2:
            raise InvalidInput(
                f"feature integral: expected (H+1, W+1, C), got {self.integral.shape}"
            )

    @classmethod
    def from_maps(cls, maps: np.ndarray) -> FeatureMaps:
        """From maps (H, W, C)."""
        return cls(integral_images(np.asarray(maps, dtype=np.float32)[None])[0])

    @property
    def num_channels(self) -> int:
        return int(self.integral.shape[2])

    @property
    def map_size(self) -> tuple[int, int]:
        """(height, width) of the maps."""
        return int(self.integral.shape[0]) - 1, int(self.integral.shape[1]) - 1

    def rect_means(self, channels: np.ndarray, rects: np.ndarray) -> np.ndarray:
        """Means over rectangles (..., 4) = (x0, y0, x1, y1) normalised, on `channels` (...)."""
        idx = RectIndex.build(np.asarray(rects, dtype=np.float64), self.map_size)
        ii, ch = self.integral, np.asarray(channels)
        total = ii[idx.r1, idx.c1, ch] - ii[idx.r0, idx.c1, ch] - ii[idx.r1, idx.c0, ch]
        return (total + ii[idx.r0, idx.c0, ch]) * idx.inv_area


def integral_images(maps: np.ndarray) -> list[np.ndarray]:
    """Integral images (H+1, W+1, C) float32 of maps (B, H, W, C), zero first row/col.

    float32 is exact enough for maps in [0, 1] of up to ~10^4 pixels and halves what the
    sample banks copy."""
    b, h, w, c = maps.shape
    return [
        cv2.integral(np.ascontiguousarray(m, dtype=np.float32), sdepth=cv2.CV_32F).reshape(
            h + 1, w + 1, c
        )
        for m in maps
    ]


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
        rects = np.clip(rects, 0.0, 1.0)
        c0 = np.minimum((rects[..., 0] * w + 0.5).astype(np.intp), w - 1)
        r0 = np.minimum((rects[..., 1] * h + 0.5).astype(np.intp), h - 1)
        c1 = np.maximum((rects[..., 2] * w + 0.5).astype(np.intp), c0 + 1)
        r1 = np.maximum((rects[..., 3] * h + 0.5).astype(np.intp), r0 + 1)
        return cls(r0, c0, r1, c1, 1.0 / ((r1 - r0) * (c1 - c0)))


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
    """ROIs of an image resized to crop_size (width, height): (N, H, W, 3) uint8. The
    part of a ROI outside the image (a person cut by its border) is padded with the
    image's edge pixels repeated, so that the part inside keeps its shape and its place
    in the crop instead of being stretched over the whole of it."""
    check_image(image_bgr)
    ih, iw = image_bgr.shape[:2]
    width, height = crop_size
    out = np.empty((len(rois), height, width, 3), dtype=np.uint8)
    for i, roi in enumerate(rois):
        x0, y0, x1, y1 = (int(v) for v in roi)
        cx0, cy0, cx1, cy1 = clip_roi((x0, y0, x1, y1), (iw, ih))
        if cx1 - cx0 < 1 or cy1 - cy0 < 1:
            raise InvalidInput(f"ROI {roi} is empty inside a {iw}x{ih} image")
        crop = image_bgr[cy0:cy1, cx0:cx1]
        if (cx0, cy0, cx1, cy1) != (x0, y0, x1, y1):
            crop = cv2.copyMakeBorder(
                crop, cy0 - y0, y1 - cy1, cx0 - x0, x1 - cx1, cv2.BORDER_REPLICATE
            )
        out[i] = _resize(crop, crop_size)
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
    """Area averaging when shrinking (no aliasing), bilinear when enlarging; a crop
    already of that size as it is."""
    if image.shape[1] == size[0] and image.shape[0] == size[1]:
        return image
    shrinking = image.shape[0] >= size[1] and image.shape[1] >= size[0]
    return cv2.resize(image, size, interpolation=cv2.INTER_AREA if shrinking else cv2.INTER_LINEAR)
