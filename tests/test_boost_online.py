"""Online boosting on synthetic appearance classes: learns, adapts, is deterministic."""

from __future__ import annotations

import numpy as np
import pytest

from follow.boost.online_boosting import OnlineBoostingClassifier
from follow.ccf.features import FeatureMaps
from follow.config import IdentifyConfig

CHANNELS, H, W = 4, 16, 8


def person(rng, top: float, legs: float, noise: float = 0.08) -> FeatureMaps:
    """Maps of a synthetic person: channel 0 = upper body colour, 1 = legs colour,
    channels 2-3 = clutter common to everyone."""
    maps = rng.random((H, W, CHANNELS)) * 0.6
    maps[: H // 2, :, 0] = top
    maps[H // 2 :, :, 1] = legs
    maps[..., :2] += rng.normal(0.0, noise, (H, W, 2))
    return FeatureMaps.from_maps(np.clip(maps, 0.0, 1.0))


def train_frames(clf, rng, n, target, other):
    for _ in range(n):
        clf.train([person(rng, *target)], [person(rng, *other), person(rng, *other)])


def accuracy(clf, rng, target, other, n=40):
    pos = clf.confidence([person(rng, *target) for _ in range(n)])
    neg = clf.confidence([person(rng, *other) for _ in range(n)])
    return 0.5 * ((pos > 0).mean() + (neg < 0).mean()), pos, neg


TARGET = (0.8, 0.8)  # light shirt, light trousers
OTHER = (0.2, 0.8)  # dark shirt, light trousers
CHANGED = (0.8, 0.2)  # the other person puts on a light jacket (and has dark trousers)


def test_untrained_classifier_is_neutral():
    clf = OnlineBoostingClassifier(CHANNELS, IdentifyConfig())
    rng = np.random.default_rng(0)
    assert not clf.is_trained
    np.testing.assert_array_equal(clf.confidence([person(rng, *TARGET)]), [0.0])


def test_learns_to_separate_two_classes():
    clf = OnlineBoostingClassifier(CHANNELS, IdentifyConfig(seed=1))
    rng = np.random.default_rng(1)
    train_frames(clf, rng, 15, TARGET, OTHER)
    acc, pos, neg = accuracy(clf, rng, TARGET, OTHER)
    assert acc >= 0.95
    assert pos.mean() > 0.5 and neg.mean() < -0.5
    assert np.all(np.abs(np.concatenate([pos, neg])) <= 1.0)


def test_adapts_when_the_other_appearance_changes():
    clf = OnlineBoostingClassifier(CHANNELS, IdentifyConfig(seed=2))
    rng = np.random.default_rng(2)
    train_frames(clf, rng, 20, TARGET, OTHER)
    before, _, changed = accuracy(clf, rng, TARGET, CHANGED)
    assert changed.mean() > 0.0  # the jacket fools the classifier at first
    train_frames(clf, rng, 30, TARGET, CHANGED)
    after, pos, neg = accuracy(clf, rng, TARGET, CHANGED)
    assert after >= 0.9 > before
    assert pos.mean() > 0.3 and neg.mean() < -0.3


def test_deterministic_from_the_seed():
    def run(seed):
        clf = OnlineBoostingClassifier(CHANNELS, IdentifyConfig(seed=seed))
        rng = np.random.default_rng(3)
        train_frames(clf, rng, 5, TARGET, OTHER)
        probes = [person(np.random.default_rng(4), *p) for p in (TARGET, OTHER, CHANGED)]
        return clf.rects.copy(), clf.confidence(probes)

    (rects_a, conf_a), (rects_b, conf_b) = run(7), run(7)
    np.testing.assert_array_equal(rects_a, rects_b)
    np.testing.assert_array_equal(conf_a, conf_b)
    assert not np.array_equal(run(8)[0], rects_a)


def test_sample_banks_are_bounded_and_balance_updates():
    cfg = IdentifyConfig(sample_bank_size=4)
    clf = OnlineBoostingClassifier(CHANNELS, cfg)
    rng = np.random.default_rng(5)
    clf.train([person(rng, *TARGET)], [person(rng, *OTHER)])  # both banks non-empty
    n0 = clf.num_updates
    clf.train([person(rng, *TARGET)], [person(rng, *OTHER) for _ in range(5)])
    assert clf.num_updates - n0 == 6 + 4  # 4 banked positives replayed
    assert clf.banks.size(0) == 4 and clf.banks.size(1) == 2


def test_bad_inputs_are_rejected():
    clf = OnlineBoostingClassifier(CHANNELS, IdentifyConfig())
    rng = np.random.default_rng(6)
    with pytest.raises(ValueError, match="label"):
        clf.update(person(rng, *TARGET), 0)
    clf.update(person(rng, *TARGET), 1)
    wrong_size = FeatureMaps.from_maps(np.zeros((8, 8, CHANNELS)))
    with pytest.raises(ValueError, match="size"):
        clf.update(wrong_size, -1)
    with pytest.raises(ValueError, match="channels"):
        clf.update(FeatureMaps.from_maps(np.zeros((H, W, 2))), -1)
    with pytest.raises(ValueError, match="rect_min_fraction"):
        OnlineBoostingClassifier(CHANNELS, IdentifyConfig(rect_min_fraction=0.6))


@pytest.mark.filterwarnings("error")
@pytest.mark.parametrize("compiled", [False, True])
def test_fast_forgetting_never_leaves_an_error_count_of_zero_over_zero(compiled):
    """A selector the importance weight has not reached for a while keeps forgetting its
    counts; with a fast `selector_error_decay` they underflowed to 0 and its error was
    0 / 0 (NaN, and a ZeroDivisionError in the compiled loop)."""
    if compiled:
        pytest.importorskip("numba")
    clf = OnlineBoostingClassifier(
        CHANNELS, IdentifyConfig(seed=1, selector_error_decay=0.1), compiled=compiled
    )
    rng = np.random.default_rng(1)
    train_frames(clf, rng, 200, TARGET, TARGET)  # indistinguishable: the chain often stops
    assert (clf._correct + clf._wrong > 0.0).all()
    assert np.isfinite(clf.alpha).all()
    assert np.isfinite(clf.confidence([person(rng, *TARGET)])).all()
