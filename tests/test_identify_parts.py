"""Part colours: the torso's and the legs' histograms, their distance, the gallery."""

from __future__ import annotations

import numpy as np
import pytest

from follow.ccf.roi import body_rows, part_bands, roi_from_keypoints
from follow.config import IdentifyConfig
from follow.eval.perturb import variant
from follow.identify.parts import (
    PART_BINS,
    PARTS,
    PartGallery,
    colour_distances,
    part_colours,
)

CFG = IdentifyConfig()
H, W = CFG.crop_height_px, CFG.crop_width_px
RED, BLUE, NAVY = (40, 40, 200), (200, 60, 40), (90, 40, 30)
WHITE, BLACK = (235, 235, 235), (20, 20, 20)


def crop(shirt, trousers, seed=0, noise=6.0):
    """A crop cut as `roi_from_keypoints` cuts it: shirt from the neck to the hips,
    trousers from the hips to the ankles, a grey background around a body half as wide."""
    rng = np.random.default_rng(seed)
    image = np.full((H, W, 3), 120.0)
    neck, hip, ankle = (int(round(f * H)) for f in body_rows(CFG))
    body = slice(W // 5, W - W // 5)
    image[neck:hip, body] = shirt
    image[hip:ankle, body] = trousers
    image += rng.normal(0.0, noise, image.shape)
    return np.clip(image, 0, 255).astype(np.uint8)


def distance(a, b):
    """The larger of the two parts' distances between two crops."""
    ca, cb = part_colours(np.stack([a]), CFG), part_colours(np.stack([b]), CFG)
    return float(colour_distances(ca, cb)[0, 0].max())


def test_the_crop_geometry_puts_neck_hips_and_ankles_where_the_roi_does():
    """A ROI from neck (0, 100) and ankle (0, 370): the neck, hip and ankle rows of the
    crop are those `body_rows` gives, and the bands lie between them."""
    x0, y0, x1, y1 = roi_from_keypoints((320, 100), (320, 370), (640, 480), CFG)
    neck, hip, ankle = body_rows(CFG)
    assert (100 - y0) / (y1 - y0) == pytest.approx(neck, abs=0.01)
    assert (370 - y0) / (y1 - y0) == pytest.approx(ankle, abs=0.01)
    assert (100 + 270 / CFG.neck_ankle_per_neck_hip - y0) / (y1 - y0) == pytest.approx(hip, abs=0.01)
    bands = part_bands(CFG)
    assert neck < bands["torso"][0] < bands["torso"][1] < hip
    assert hip < bands["legs"][0] < bands["legs"][1] < ankle


def test_each_part_is_a_histogram_of_its_own_colour():
    colours = part_colours(np.stack([crop(RED, BLUE)]), CFG)[0]
    assert colours.shape == (len(PARTS), PART_BINS)
    assert np.allclose(colours.sum(axis=1), 1.0)
    torso, legs = colours
    # one colour each, no background: all votes in the two bins nearest the hue
    assert np.sort(torso)[-2:].sum() > 0.95 and np.sort(legs)[-2:].sum() > 0.95
    assert colour_distances(colours[None, :1], colours[None, 1:])[0, 0, 0] > 0.9


@pytest.mark.parametrize("trousers", [BLUE, WHITE, (40, 180, 40)])
def test_other_trousers_are_far_the_same_clothes_are_near(trousers):
    target = crop(RED, BLACK)
    assert distance(target, crop(RED, BLACK, seed=1)) < 0.2 < CFG.reid_part_colour_distance
    assert distance(target, crop(RED, trousers, seed=1)) > 0.9


@pytest.mark.parametrize("name", ["dark", "bright", "low_contrast", "noise", "blur", "jpeg50"])
def test_the_same_clothes_stay_within_the_bar_under_a_change_of_light_or_focus(name):
    """The perturbation suite's pixel changes (docs/robustness.md) on the same person
    seen again: the coarse bins keep their parts within `reid_part_colour_distance`."""
    target = crop(RED, NAVY)
    seen = variant(name).apply(crop(RED, NAVY, seed=2), 7)
    assert distance(target, seen) < CFG.reid_part_colour_distance


def test_the_gallery_keeps_distinct_views_and_answers_with_the_worst_part():
    gallery = PartGallery(2)
    red_black = part_colours(np.stack([crop(RED, BLACK)]), CFG)[0]
    gallery.add(red_black)
    gallery.add(part_colours(np.stack([crop(RED, BLACK, seed=3)]), CFG)[0])
    blue_white = part_colours(np.stack([crop(BLUE, WHITE)]), CFG)[0]
    gallery.add(blue_white)  # full: one of the two alike red-black views goes
    assert len(gallery) == 2
    probes = part_colours(np.stack([crop(RED, BLACK, 4), crop(BLUE, WHITE, 4),
                                    crop(RED, WHITE, 4), crop(BLUE, BLACK, 4)]), CFG)  # fmt: skip
    near, near_too, mixed, mixed_too = gallery.distances(probes)
    assert near < 0.2 and near_too < 0.2
    # each part is nearest some view (red shirt from one, white trousers from another),
    # so a mix of the two views' clothes passes: the rule asks every part to be of the
    # target's colours, not of one frame's
    assert mixed < 0.2 and mixed_too < 0.2


def test_an_empty_gallery_and_bad_crops_are_errors():
    with pytest.raises(ValueError, match="empty"):
        PartGallery(4).distances(np.zeros((1, len(PARTS), PART_BINS)))
    with pytest.raises(ValueError, match="room for 2"):
        PartGallery(1)
    with pytest.raises(ValueError, match="uint8 crops"):
        part_colours(np.zeros((2, H, W), np.uint8), CFG)
    with pytest.raises(ValueError, match="float32"):  # the shape is right, the type is not
        part_colours(np.zeros((2, H, W, 3), np.float32), CFG)
    assert part_colours(np.zeros((0, H, W, 3), np.uint8), CFG).shape == (0, 2, PART_BINS)


@pytest.mark.parametrize(
    "geometry",
    [
        {"roi_height_per_neck_ankle": 0.8},  # the crop shorter than neck to ankle
        {"roi_center_offset_per_neck_ankle": 1.0},  # the body above the crop
        {"roi_center_offset_per_neck_ankle": -1.0},  # the body below it
    ],
)
def test_a_crop_that_holds_only_part_of_the_body_still_gives_each_part_colours(geometry):
    """A crop geometry the configuration accepts may put a band partly or wholly outside
    the crop: each part's histogram comes from the rows of its band inside the crop, or
    the crop's edge row, never from an empty slice (which OpenCV refuses)."""
    config = IdentifyConfig(**geometry)
    colours = part_colours(np.stack([crop(RED, BLUE), crop(BLUE, WHITE)]), config)
    assert colours.shape == (2, len(PARTS), PART_BINS)
    assert np.allclose(colours.sum(axis=2), 1.0)
