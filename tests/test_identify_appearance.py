"""The appearance model learns the target's crop mirrored as a second positive."""

from __future__ import annotations

import numpy as np
import pytest

from follow.ccf.channels import ChannelFeatureExtractor
from follow.config import IdentifyConfig
from follow.identify.appearance import AppearanceModel

CFG = IdentifyConfig(identifier="channels")


def _half_and_half(rng, left_bgr, right_bgr) -> np.ndarray:
    """A 128x48 crop whose shirt is one colour on its left half, another on its right."""
    crop = np.full((128, 48, 3), 110, np.uint8)
    crop[20:60, :24], crop[20:60, 24:] = left_bgr, right_bgr
    crop[60:] = (60, 60, 60)
    return np.clip(crop + rng.normal(0, 5, crop.shape), 0, 255).astype(np.uint8)


def _model(mirrored: str) -> AppearanceModel:
    config = IdentifyConfig(identifier="channels", mirrored_positives=mirrored)
    return AppearanceModel(config, ChannelFeatureExtractor((48, 128)))


def test_the_mirrored_positive_is_the_feature_maps_of_the_flipped_crop():
    crop = _half_and_half(np.random.default_rng(0), (40, 40, 200), (200, 60, 40))
    model = _model("always")
    (mirrored,) = model.mirrored_positives(crop)
    (flipped,) = model.extractor.extract_crops([crop[:, ::-1].copy()])
    (plain,) = model.extractor.extract_crops([crop])
    assert np.array_equal(mirrored.integral, flipped.integral)
    assert not np.array_equal(mirrored.integral, plain.integral)
    assert _model("never").mirrored_positives(crop) == []
    # by default only beside a re-id cue: the classifier alone keeps one positive a frame
    assert _model("with_reid").mirrored_positives(crop) == []


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_target_seen_from_its_other_side_is_more_readily_accepted(seed):
    """Learnt from one side of a two-coloured shirt (with recoloured negatives), the
    target turned round (its crop mirrored) passes the strict re-identification bar with
    mirrored positives, and not even the lowest bar without."""
    rng = np.random.default_rng(seed)
    scores = {}
    for mirrored in ("always", "never"):
        model = _model(mirrored)
        for _ in range(10):
            crop = _half_and_half(rng, (40, 40, 200), (200, 60, 40))
            (appearance,) = model.describe_crops([crop])
            model.learn([appearance], [], model.synthetic_negatives(crop, 6),
                        model.mirrored_positives(crop))  # fmt: skip
        turned = model.describe_crops([_half_and_half(rng, (200, 60, 40), (40, 40, 200))])
        scores[mirrored] = float(model.confidence(turned)[0])
    assert scores["always"] >= CFG.reid_strict_confidence > CFG.reid_confidence > scores["never"]
