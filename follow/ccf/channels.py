"""A weight-free channel set (aggregated channel features): LUV colour, gradient
magnitude and gradient orientation histograms, for when no CCF weights are present.

Channels are computed on the resized crop and averaged over `shrink` x `shrink` blocks,
the same map resolution the CCF network produces; values lie in about [0, 1].
"""

from __future__ import annotations

from collections.abc import Sequence

import cv2
import numpy as np

from follow.ccf.features import FeatureMaps, Roi, cut_crops, integral_images, resize_crops

ORIENTATION_BINS = 6
SHRINK = 2
GRADIENT_NORM = 1.0  # magnitude (gray in [0, 1], Sobel / 8 per pixel) mapped to 1


class ChannelFeatureExtractor:
    """LUV (3) + gradient magnitude (1) + orientation histogram (6) = 10 channels."""

    def __init__(self, crop_size: tuple[int, int] = (48, 128), name: str = "channels"):
        self.name = name
        self.crop_size = (int(crop_size[0]), int(crop_size[1]))
        if min(self.crop_size) < 2 * SHRINK:
            raise ValueError(f"channel crop size {self.crop_size} is too small")
        self.num_channels = 3 + 1 + ORIENTATION_BINS

    def channels_of(self, crop_bgr: np.ndarray) -> np.ndarray:
        """(H/shrink, W/shrink, C) float32 channels of one crop."""
        luv = cv2.cvtColor(crop_bgr, cv2.COLOR_BGR2Luv).astype(np.float32) * (1.0 / 255.0)
        gray = cv2.cvtColor(crop_bgr, cv2.COLOR_BGR2GRAY).astype(np.float32) * (1.0 / 255.0)
        gx = cv2.Sobel(gray, cv2.CV_32F, 1, 0, ksize=3) * 0.125
        gy = cv2.Sobel(gray, cv2.CV_32F, 0, 1, ksize=3) * 0.125
        magnitude = np.sqrt(gx * gx + gy * gy) * (1.0 / GRADIENT_NORM)
        angle = np.arctan2(gy, gx) % np.pi  # unsigned orientation
        bins = np.minimum(
            (angle * (ORIENTATION_BINS / np.pi)).astype(np.int32), ORIENTATION_BINS - 1
        )
        h, w = gray.shape
        full = np.zeros((h, w, self.num_channels), dtype=np.float32)
        full[..., 0:3] = luv
        full[..., 3] = magnitude
        orient = full[..., 4:]
        np.put_along_axis(orient, bins[..., None], magnitude[..., None], axis=2)
        h2, w2 = h // SHRINK, w // SHRINK
        blocks = full[: h2 * SHRINK, : w2 * SHRINK].reshape(
            h2, SHRINK, w2, SHRINK, self.num_channels
        )
        return np.clip(blocks.mean(axis=(1, 3)), 0.0, 1.0)

    def _maps(self, crops: np.ndarray) -> list[FeatureMaps]:
        if len(crops) == 0:
            return []
        maps = np.stack([self.channels_of(c) for c in crops])
        return [FeatureMaps(ii) for ii in integral_images(maps)]

    def extract(self, image_bgr: np.ndarray, rois: Sequence[Roi]) -> list[FeatureMaps]:
        return self._maps(cut_crops(image_bgr, rois, self.crop_size))

    def extract_crops(self, crops_bgr: Sequence[np.ndarray]) -> list[FeatureMaps]:
        return self._maps(resize_crops(crops_bgr, self.crop_size))
