"""ROI from neck/ankle pixels: proportions, clipping, degenerate and tiny cases."""

from __future__ import annotations

import numpy as np
import pytest

from follow.ccf.features import cut_crops
from follow.ccf.roi import person_boxes, roi_from_keypoints, track_rois
from follow.config import IdentifyConfig
from follow.types import Observation, TrackState

CFG = IdentifyConfig()
SIZE = (640, 480)


def test_box_is_centred_between_neck_and_ankle_with_configured_sides():
    cfg = IdentifyConfig(roi_center_offset_per_neck_ankle=0.0)
    x0, y0, x1, y1 = roi_from_keypoints((320, 100), (320, 300), SIZE, cfg)
    assert (x0 + x1) / 2 == pytest.approx(320, abs=1)
    assert (y0 + y1) / 2 == pytest.approx(200, abs=1)
    assert y1 - y0 == pytest.approx(cfg.roi_height_per_neck_ankle * 200, abs=1)
    assert x1 - x0 == pytest.approx(cfg.roi_width_per_neck_ankle * 200, abs=1)


def test_box_scales_with_the_person():
    near = roi_from_keypoints((300, 50), (300, 350), SIZE, CFG)
    far = roi_from_keypoints((300, 150), (300, 225), SIZE, CFG)
    assert (near[3] - near[1]) == pytest.approx(4 * (far[3] - far[1]), rel=0.05)


def test_box_is_clipped_to_the_image():
    x0, y0, x1, y1 = roi_from_keypoints((620, 60), (620, 400), SIZE, CFG)
    assert x1 == SIZE[0] and y0 >= 0 and x0 < 620


def test_mostly_outside_is_skipped():
    assert roi_from_keypoints((650, 100), (650, 300), SIZE, CFG) is None


def test_tiny_person_is_skipped():
    cfg = IdentifyConfig(min_roi_height_px=24.0)
    assert roi_from_keypoints((300, 200), (300, 210), SIZE, cfg) is None
    assert roi_from_keypoints((300, 200), (300, 240), SIZE, cfg) is not None


@pytest.mark.parametrize(
    "neck, ankle",
    [((300, 200), (300, 200)), ((300, 300), (300, 100)), ((100, 200), (400, 210)),
     ((np.nan, 200), (300, 300)), (None, (300, 300))],
)  # fmt: skip
def test_degenerate_keypoints_give_none(neck, ankle):
    assert roi_from_keypoints(neck, ankle, SIZE, CFG) is None


def test_without_ankle_the_hip_gives_the_scale():
    with_ankle = roi_from_keypoints((300, 100), (300, 370), SIZE, CFG)
    from_hip = roi_from_keypoints((300, 100), None, SIZE, CFG, hip_px=(300, 200))
    assert from_hip == with_ankle  # neck-hip 100 px x 2.7 = neck-ankle 270 px


def test_without_ankle_or_hip_the_feet_are_assumed_at_the_image_bottom():
    roi = roi_from_keypoints((300, 240), None, SIZE, CFG)
    assert roi == roi_from_keypoints((300, 240), (300, SIZE[1]), SIZE, CFG)
    assert roi_from_keypoints((300, 470), None, SIZE, CFG) is None  # too little left


def test_bad_image_size_is_an_error():
    with pytest.raises(ValueError, match="image_size"):
        roi_from_keypoints((1, 1), (1, 50), (0, 480), CFG)


def test_a_person_cut_by_the_image_border_is_padded_not_stretched():
    """The same person seen whole and with the left fifth of their box outside the
    image: the crop of the cut one shows the body at the same size and place (the part
    outside padded), not the visible part stretched over the whole crop. The box the
    person occupies, which the overlap rules compare, stays inside the image."""
    rng = np.random.default_rng(0)
    wide = rng.integers(0, 256, (480, 800, 3), np.uint8)
    shift = 160  # the cut image starts here: 28 of the box's 136 columns fall outside
    cut = np.ascontiguousarray(wide[:, shift:])

    def crop_and_box(image, neck_x):
        h, w = image.shape[:2]
        track = TrackState(1, np.zeros(5), np.eye(5), True, 0.0,
                           observation=Observation((neck_x, 100.0), (neck_x, 370.0)))  # fmt: skip
        rois = track_rois([track], (w, h), CFG)
        crop = cut_crops(image, [rois[1]], (CFG.crop_width_px, CFG.crop_height_px))[0]
        return crop, person_boxes([track], rois, (w, h), CFG)[1]

    whole_crop, whole_box = crop_and_box(wide, 200.0)
    cut_crop, cut_box = crop_and_box(cut, 200.0 - shift)
    padded = int(np.ceil(28 / 136 * CFG.crop_width_px)) + 1  # and one column it blurs into
    assert np.array_equal(cut_crop[:, padded:], whole_crop[:, padded:])
    assert cut_box == (0, whole_box[1], whole_box[2] - shift, whole_box[3])
