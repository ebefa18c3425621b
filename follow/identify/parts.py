"""The colours of a person's torso and of their legs, and the target's as learnt.

The boosted classifier and the re-id network each see a whole crop, most of which is
head and torso: a stranger in the target's shirt and other trousers can score like the
target on both. Here each part has its own coarse colour histogram (8 hues for coloured
pixels, 3 grey levels for the others: coarse, so that a change of light, focus or
compression leaves one person's parts within the bar; each pixel's vote shared between
neighbouring bins, so that nothing jumps at a bin's edge), and a
re-identification candidate must match the colours the target was seen in, part by part
(`reid_part_colour_distance`; docs/identification.md, *Every part must match*).
"""

from __future__ import annotations

import cv2
import numpy as np

from follow.ccf.roi import part_bands
from follow.config import IdentifyConfig
from follow.identify.gallery import add_keeping_diverse

PARTS = ("torso", "legs")
HUE_BINS, GREY_BINS = 8, 3
PART_BINS = HUE_BINS + GREY_BINS
MIN_CHROMA = 50  # saturation and value (0-255) below which a pixel's hue means nothing
CHROMA_RAMP = 30  # grey to coloured over this span of saturation and value around it


def part_colours(crops_bgr: np.ndarray, config: IdentifyConfig) -> np.ndarray:
    """(N, 2, PART_BINS) colour histograms of the torso and the legs of each crop (N
    crops of one size, cut by `roi_from_keypoints`); each histogram sums to 1."""
    crops = np.asarray(crops_bgr)
    if crops.ndim != 4 or crops.shape[-1] != 3 or crops.dtype != np.uint8:
        raise ValueError(
            f"part_colours: expected (N, H, W, 3) uint8 crops, got {crops.shape} {crops.dtype}"
        )
    n, height, width = crops.shape[:3]
    out = np.zeros((n, len(PARTS), PART_BINS), np.float32)
    if n == 0:
        return out
    bands = part_bands(config)
    for p, name in enumerate(PARTS):
        top, bottom, left, right = bands[name]
        (y0, y1), (x0, x1) = _span(top, bottom, height), _span(left, right, width)
        band = np.ascontiguousarray(crops[:, y0:y1, x0:x1]).reshape(-1, x1 - x0, 3)
        out[:, p] = _histograms(cv2.cvtColor(band, cv2.COLOR_BGR2HSV).reshape(n, -1, 3))
    return out


def _span(start: float, end: float, size: int) -> tuple[int, int]:
    """Pixel indices [first, last) of the fractions `start`-`end` of `size`, within it and
    at least one: a crop geometry the configuration accepts (one shorter than neck to
    ankle, or shifted far) can put part of a band, or all of it, outside the crop."""
    first = min(max(int(round(start * size)), 0), size - 1)
    return first, min(size, max(first + 1, int(round(end * size))))


def _histograms(hsv: np.ndarray) -> np.ndarray:
    """(N, PART_BINS) normalised histograms of (N, pixels, 3) uint8 HSV pixels (OpenCV's
    ranges: hue 0-179, saturation and value 0-255). Each pixel's vote is shared linearly
    between the two nearest bins of each axis, and between the coloured and the grey
    bins around `MIN_CHROMA`: a colour on a bin's edge, or a little lighter or darker,
    moves its votes a little, never all at once. (Computed as weighted counts of each
    hue and each value, then spread over the bins by the tables below.)"""
    n = len(hsv)
    h, s, v = (hsv[..., k].astype(np.int64) for k in range(3))
    chroma = _CHROMA[np.minimum(s, v)]
    rows = np.arange(n)[:, None]
    hues = np.bincount((rows * 180 + h).ravel(), chroma.ravel(), minlength=n * 180)
    greys = np.bincount((rows * 256 + v).ravel(), (1.0 - chroma).ravel(), minlength=n * 256)
    counts = np.concatenate(
        [hues.reshape(n, 180) @ _HUE_SHARES, greys.reshape(n, 256) @ _GREY_SHARES], axis=1
    )
    return counts / np.maximum(counts.sum(axis=1, keepdims=True), 1e-12)


def _shares(positions: np.ndarray, bins: int, circular: bool = False) -> np.ndarray:
    """(len(positions), bins): each continuous bin position (bin k centred on k) shared
    linearly between its two neighbouring bins, clamped at the ends unless `circular`."""
    if not circular:
        positions = np.clip(positions, 0.0, bins - 1.0)
    lower = np.floor(positions)
    upper_share = positions - lower
    lower = lower.astype(np.int64)
    upper = (lower + 1) % bins if circular else np.minimum(lower + 1, bins - 1)
    lower = lower % bins
    out = np.zeros((len(positions), bins))
    rows = np.arange(len(positions))
    np.add.at(out, (rows, lower), 1.0 - upper_share)
    np.add.at(out, (rows, upper), upper_share)
    return out


# Each hue's (0-179) and each value's (0-255) share of the bins, and how coloured a pixel
# is by the smaller of its saturation and value (0-255).
_HUE_SHARES = _shares(np.arange(180) * HUE_BINS / 180.0 - 0.5, HUE_BINS, circular=True)
_GREY_SHARES = _shares(np.arange(256) * GREY_BINS / 256.0 - 0.5, GREY_BINS)
_CHROMA = np.clip((np.arange(256) - (MIN_CHROMA - CHROMA_RAMP / 2)) / CHROMA_RAMP, 0.0, 1.0)


def colour_distances(colours: np.ndarray, gallery: np.ndarray) -> np.ndarray:
    """(N, G, 2) Hellinger distance (0 same, 1 nothing in common) of each part of each
    of N (N, 2, bins) histograms to the same part of each of G (G, 2, bins)."""
    overlap = np.einsum("npb,gpb->ngp", np.sqrt(colours), np.sqrt(gallery))
    return np.sqrt(np.clip(1.0 - overlap, 0.0, 1.0))


class PartGallery:
    """The target's part colours from the frames it was learnt in, kept diverse
    (`add_keeping_diverse`), so that the colours of other views and other light stay."""

    def __init__(self, size: int):
        if size < 2:
            raise ValueError(f"a part-colour gallery needs room for 2 entries, got {size}")
        self._colours = np.zeros((size, len(PARTS), PART_BINS), np.float32)
        self._size = 0

    def __len__(self) -> int:
        return self._size

    def add(self, colours: np.ndarray) -> None:
        colours = np.asarray(colours, np.float32).reshape(len(PARTS), PART_BINS)
        self._size = add_keeping_diverse(
            self._colours, self._size, colours,
            lambda a, b: -colour_distances(a, b).mean(axis=2),
        )  # fmt: skip

    def distances(self, colours: np.ndarray) -> np.ndarray:
        """(N,) the distance of each of N (N, 2, bins) histograms from the target's
        colours in its least alike part: per part the nearest entry of the gallery (a
        shirt seen in one frame, trousers in another), then the larger of the two."""
        if self._size == 0:
            raise ValueError("part-colour gallery is empty")
        nearest = colour_distances(np.asarray(colours, np.float32), self._colours[: self._size])
        return nearest.min(axis=1).max(axis=1)
