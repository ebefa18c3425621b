"""Rendered appearances of simulated people, so that identification in the demo learns
from pixels rather than from ground-truth ids.

A person is drawn from their projected joints as thick limbs and a torso in clothing
colours (with an optional stripe pattern), back to front, over a floor-and-wall
background. Crude, but enough for colour and texture features to matter, and for a
distractor dressed like the target to be hard.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import cv2
import numpy as np

NECK, R_SHOULDER, L_SHOULDER, R_HIP, L_HIP = 1, 2, 5, 8, 11
ARMS = ((2, 3), (3, 4), (5, 6), (6, 7))
LEGS = ((8, 9), (9, 10), (11, 12), (12, 13))


@dataclass(frozen=True)
class Appearance:
    shirt_bgr: tuple[int, int, int]
    trousers_bgr: tuple[int, int, int]
    skin_bgr: tuple[int, int, int]
    hair_bgr: tuple[int, int, int]
    stripes_bgr: tuple[int, int, int] | None = None  # horizontal stripes on the shirt

    @classmethod
    def random(cls, rng: np.random.Generator) -> Appearance:
        def colour() -> tuple[int, int, int]:
            return tuple(int(c) for c in rng.integers(20, 236, 3))

        skin = [(60, 90, 140), (90, 130, 190), (120, 160, 215), (40, 60, 100)]
        hair = [(20, 20, 20), (30, 50, 90), (60, 90, 140), (180, 180, 180)]
        return cls(
            shirt_bgr=colour(),
            trousers_bgr=colour(),
            skin_bgr=skin[int(rng.integers(len(skin)))],
            hair_bgr=hair[int(rng.integers(len(hair)))],
            stripes_bgr=colour() if rng.random() < 0.3 else None,
        )


@dataclass(frozen=True)
class PersonView:
    """One person as the camera sees them: joints in pixels (NaN where not visible),
    distance for drawing order, and pixels per metre at that distance for limb widths."""

    keypoints_px: np.ndarray  # (18, 2)
    distance_m: float
    px_per_m: float
    appearance: Appearance


def background(image_size: tuple[int, int], horizon_v: float, seed: int = 0) -> np.ndarray:
    """A wall above the horizon and a textured floor below it (a new array to draw on).
    The same arguments give the same pixels, so each is drawn once and then copied: the
    texture took half the time of a simulated run when drawn anew every frame."""
    return _background(tuple(image_size), float(horizon_v), seed).copy()


@lru_cache(maxsize=8)
def _background(image_size: tuple[int, int], horizon_v: float, seed: int) -> np.ndarray:
    w, h = image_size
    rng = np.random.default_rng(seed)
    img = np.empty((h, w, 3), np.uint8)
    v = int(np.clip(horizon_v, 0, h))
    img[:v] = (200, 195, 185)
    img[v:] = (120, 125, 130)
    noise = rng.normal(0, 6, (h, w, 1))
    out = np.clip(img + noise, 0, 255).astype(np.uint8)
    out.flags.writeable = False  # shared by every frame: copied before drawing
    return out


def _drawable(keypoints_px: np.ndarray) -> list[bool]:
    """Per joint: finite and near enough to the image for OpenCV's integer drawing."""
    with np.errstate(invalid="ignore"):
        return (np.abs(keypoints_px) < 1e5).all(axis=1).tolist()  # NaN compares False


TORSO_MIN_WIDTH_M = 0.3  # a body seen from the side is still about this wide


def torso_quad(k: np.ndarray, px_per_m: float) -> np.ndarray:
    """The torso as a quadrilateral between shoulders and hips, at least as wide as a
    body's depth, so that a person seen from the side still shows their clothes."""
    top = 0.5 * (k[R_SHOULDER] + k[L_SHOULDER])
    bottom = 0.5 * (k[R_HIP] + k[L_HIP])
    axis = bottom - top
    length = float(np.hypot(*axis))
    if length < 1e-6:
        return np.int32([k[i] for i in (R_SHOULDER, L_SHOULDER, L_HIP, R_HIP)])
    across = np.array([-axis[1], axis[0]]) / length
    half_width = max(0.625 * abs(float((k[L_SHOULDER] - k[R_SHOULDER]) @ across)),
                     0.5 * TORSO_MIN_WIDTH_M * px_per_m)  # fmt: skip
    return np.int32([top - half_width * across, top + half_width * across,
                     bottom + half_width * across, bottom - half_width * across])  # fmt: skip


def draw_person(image: np.ndarray, view: PersonView) -> None:
    k, a, s = view.keypoints_px, view.appearance, view.px_per_m
    limb = max(1, int(0.11 * s))
    ok = _drawable(k)

    def seg(i: int, j: int, colour) -> None:
        if ok[i] and ok[j]:
            cv2.line(image, tuple(np.int32(k[i])), tuple(np.int32(k[j])), colour, limb, cv2.LINE_AA)

    for i, j in LEGS:
        seg(i, j, a.trousers_bgr)
    torso_ids = (R_SHOULDER, L_SHOULDER, L_HIP, R_HIP)
    if all(ok[i] for i in torso_ids):
        quad = torso_quad(k, s)
        cv2.fillConvexPoly(image, quad, a.shirt_bgr, cv2.LINE_AA)
        if a.stripes_bgr is not None:
            top, bottom = quad[:, 1].min(), quad[:, 1].max()
            mask = np.zeros(image.shape[:2], np.uint8)
            cv2.fillConvexPoly(mask, quad, 255)
            period = max(2, int(0.12 * s))
            rows = np.arange(top, bottom)
            rows = rows[(rows - top) // max(1, period // 2) % 2 == 0]
            rows = rows[(rows >= 0) & (rows < image.shape[0])]
            for r in rows:
                sel = mask[r] > 0
                image[r, sel] = a.stripes_bgr
    for i, j in ARMS:
        seg(i, j, a.shirt_bgr)
    if ok[NECK] and ok[0]:
        head_r = max(1, int(0.11 * s))
        centre = tuple(np.int32(k[0]))
        cv2.circle(image, centre, head_r, a.skin_bgr, -1, cv2.LINE_AA)
        cv2.ellipse(image, centre, (head_r, head_r), 0, 180, 360, a.hair_bgr, -1, cv2.LINE_AA)


def render_scene(
    image_size: tuple[int, int], horizon_v: float, views: list[PersonView], seed: int = 0
) -> np.ndarray:
    """The frame the camera would see: background, then people from far to near."""
    img = background(image_size, horizon_v, seed)
    for view in sorted(views, key=lambda v: -v.distance_m):
        draw_person(img, view)
    return img
