"""Online boosting for feature selection (Grabner & Bischof, CVPR 2006) on feature maps.

S selectors each hold W weak classifiers. A weak classifier looks at the mean of one
random rectangle (normalised coordinates, `rect_min_fraction`..`rect_max_fraction` of the
map per side) of one random channel and decides target / other by naive Bayes between
two incrementally updated Gaussians. Each training sample walks through the selectors
in order with an importance weight lambda: a selector's weak classifiers update their
weighted error counts, the best one becomes the selector's hypothesis with voting
weight alpha = 0.5 ln((1 - e) / e), lambda grows when it was wrong and shrinks when it
was right, and the worst weak classifier is replaced by a fresh random one (initialised
from the sample banks) with probability `replace_probability`.

For speed the Gaussians of all S x W weak classifiers learn each sample with unit weight
(the sample banks keep the classes balanced); lambda weighs the selectors' error counts.
The Gaussians have a bounded memory (`gaussian_memory_samples`) and the error counts a
forgetting factor (`selector_error_decay`), so that the classifier follows an appearance
that changes. Everything random comes from one seeded generator.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from follow.boost.sample_bank import SampleBank
from follow.ccf.features import FeatureMaps, RectIndex
from follow.config import IdentifyConfig
from follow.types import InvalidInput

MIN_SELECTOR_ERROR = 0.01  # keeps alpha finite (<= 2.3) for a flawless weak classifier
MAX_IMPORTANCE = 1e3  # cap of lambda along the selector chain
NEG, POS = 0, 1


class OnlineBoostingClassifier:
    """Target (+1) versus others (-1) on `FeatureMaps`; confidence in [-1, 1]."""

    def __init__(self, num_channels: int, config: IdentifyConfig, seed: int | None = None):
        if num_channels < 1:
            raise ValueError(f"online boosting needs at least one channel, got {num_channels}")
        if config.num_selectors < 1 or config.weak_classifiers_per_selector < 2:
            raise ValueError("online boosting needs >= 1 selector of >= 2 weak classifiers")
        if not 0.0 < config.rect_min_fraction <= config.rect_max_fraction <= 1.0:
            raise ValueError(
                "rect_min_fraction and rect_max_fraction must satisfy 0 < min <= max <= 1, got "
                f"{config.rect_min_fraction}, {config.rect_max_fraction}"
            )
        self.config = config
        self.num_channels = int(num_channels)
        self.rng = np.random.default_rng(config.seed if seed is None else seed)
        s, w = config.num_selectors, config.weak_classifiers_per_selector
        self.channels = np.zeros((s, w), dtype=np.intp)
        self.rects = np.zeros((s, w, 4))
        self.mean = np.zeros((2, s, w))
        self.var = np.zeros((2, s, w))
        self.count = np.zeros((2, s, w))
        self.correct = np.ones((s, w))
        self.wrong = np.ones((s, w))
        self.alpha = np.zeros(s)
        self.best = np.full(s, -1, dtype=np.intp)
        self.num_updates = 0
        self.banks = (SampleBank(config.sample_bank_size), SampleBank(config.sample_bank_size))
        self._map_size: tuple[int, int] | None = None
        self._index: RectIndex | None = None
        self._min_var = config.min_feature_std**2
        rows, cols = np.indices((s, w))
        self._new_weak(rows.ravel(), cols.ravel())

    # ----------------------------------------------------------------- weak classifiers
    def _new_weak(self, rows: np.ndarray, cols: np.ndarray) -> None:
        """Fresh random weak classifiers at (rows, cols), trained on the sample banks."""
        n = len(rows)
        lo, hi = self.config.rect_min_fraction, self.config.rect_max_fraction
        size = self.rng.uniform(lo, hi, size=(n, 2))
        corner = self.rng.uniform(0.0, 1.0, size=(n, 2)) * (1.0 - size)
        self.rects[rows, cols] = np.concatenate([corner, corner + size], axis=1)
        self.channels[rows, cols] = self.rng.integers(0, self.num_channels, size=n)
        self.correct[rows, cols] = 1.0
        self.wrong[rows, cols] = 1.0
        if self._map_size is not None:
            sub = RectIndex.build(self.rects[rows, cols], self._map_size)
            for name in ("r0", "c0", "r1", "c1", "inv_area"):
                getattr(self._index, name)[rows, cols] = getattr(sub, name)
        for label in (NEG, POS):
            self.mean[label, rows, cols] = 0.0
            self.var[label, rows, cols] = 0.0
            self.count[label, rows, cols] = 0.0
            bank = self.banks[label]
            if len(bank) and self._index is not None:
                f = _means(bank.integrals(), self.channels[rows, cols], self._sub(rows, cols))
                self.mean[label, rows, cols] = f.mean(axis=0)
                self.var[label, rows, cols] = f.var(axis=0)
                self.count[label, rows, cols] = min(len(bank), self.config.gaussian_memory_samples)

    def _sub(self, rows, cols) -> RectIndex:
        idx = self._index
        return RectIndex(idx.r0[rows, cols], idx.c0[rows, cols], idx.r1[rows, cols],
                         idx.c1[rows, cols], idx.inv_area[rows, cols])  # fmt: skip

    def _check(self, integral: np.ndarray) -> None:
        if integral.ndim != 3 or integral.shape[0] != self.num_channels:
            raise InvalidInput(
                f"feature maps have shape {integral.shape}, expected {self.num_channels} channels"
            )
        size = (integral.shape[1] - 1, integral.shape[2] - 1)
        if self._map_size is None:
            self._map_size = size
            self._index = RectIndex.build(self.rects, size)
        elif size != self._map_size:
            raise InvalidInput(
                f"feature maps of size {size} given to a classifier trained on {self._map_size}"
            )

    def _log_likelihood_ratio(self, x: np.ndarray, rows=None, cols=None) -> np.ndarray:
        """log N(x; target) - log N(x; others) of all weak classifiers (rows/cols None) or
        of some for a batch x (B, n); +1/-1 where only one class is known yet, 0 where neither is."""
        if rows is None:
            mean, var, count = self.mean, self.var, self.count
        else:
            mean, var, count = (a[:, None, rows, cols] for a in (self.mean, self.var, self.count))
        var = np.maximum(var, self._min_var)
        ll = -0.5 * ((x - mean) ** 2 / var + np.log(var))
        known = count > 0
        ll = np.where(known, ll, -np.inf)
        with np.errstate(invalid="ignore"):
            llr = ll[POS] - ll[NEG]
        return np.nan_to_num(llr, nan=0.0, posinf=1.0, neginf=-1.0)

    # ------------------------------------------------------------------------ training
    def update(self, maps: FeatureMaps, label: int) -> None:
        """Learn one sample: label +1 = target, -1 = someone else; stored in its bank."""
        if label not in (1, -1):
            raise ValueError(f"label must be +1 or -1, got {label}")
        self._check(maps.integral)
        cls = POS if label > 0 else NEG
        self.banks[cls].push(maps.integral)
        self._learn(maps.integral, cls)

    def train(self, positives: Sequence[FeatureMaps], negatives: Sequence[FeatureMaps]) -> None:
        """Learn one frame's samples, then replay banked samples of the rarer class until
        both classes have had as many updates (once both banks hold samples)."""
        order = [(m, 1) for m in positives] + [(m, -1) for m in negatives]
        if not order:
            return
        perm = self.rng.permutation(len(order))
        for i in perm:
            self.update(*order[i])
        deficit = len(negatives) - len(positives)
        cls = POS if deficit > 0 else NEG
        bank = self.banks[cls]
        if len(bank) == 0 or len(self.banks[1 - cls]) == 0:
            return
        for _ in range(abs(deficit)):
            self._learn(bank.sample(self.rng), cls)

    def _learn(self, integral: np.ndarray, cls: int) -> None:
        cfg = self.config
        x = _means(integral[None], self.channels, self._index)[0]
        n = np.minimum(self.count[cls] + 1.0, cfg.gaussian_memory_samples)
        rate = 1.0 / n
        delta = x - self.mean[cls]
        self.mean[cls] += rate * delta
        self.var[cls] = (1.0 - rate) * (self.var[cls] + rate * delta * delta)
        self.count[cls] = n
        label = 1.0 if cls == POS else -1.0
        hit = (np.where(self._log_likelihood_ratio(x) >= 0.0, 1.0, -1.0) == label).astype(float)
        miss = 1.0 - hit
        self.correct *= cfg.selector_error_decay
        self.wrong *= cfg.selector_error_decay

        replace = self.rng.random(cfg.num_selectors) < cfg.replace_probability
        lam = 1.0
        lams = np.zeros(cfg.num_selectors)
        worst = np.zeros(cfg.num_selectors, dtype=np.intp)
        last = cfg.num_selectors
        for s in range(cfg.num_selectors):
            lams[s] = lam
            corr = self.correct[s] + lam * hit[s]
            wrong = self.wrong[s] + lam * miss[s]
            self.correct[s] = corr
            self.wrong[s] = wrong
            err = wrong / (corr + wrong)
            b = int(err.argmin())
            worst[s] = int(err.argmax())
            e = max(float(err[b]), MIN_SELECTOR_ERROR)
            if e >= 0.5:
                self.alpha[s] = 0.0
                self.best[s] = -1
                replace[s] = True
                last = s + 1
                break
            self.best[s] = b
            self.alpha[s] = 0.5 * math.log((1.0 - e) / e)
            lam = min(lam / (2.0 * (1.0 - e)) if hit[s, b] else lam / (2.0 * e), MAX_IMPORTANCE)
        rows = np.flatnonzero(replace[:last])
        cols = worst[rows]
        keep = cols != self.best[rows]
        if keep.any():
            self._new_weak(rows[keep], cols[keep])
        self.num_updates += 1

    # ---------------------------------------------------------------------- prediction
    @property
    def is_trained(self) -> bool:
        return bool(self.alpha.sum() > 0.0)

    def confidence(self, maps: Sequence[FeatureMaps]) -> np.ndarray:
        """Confidence in [-1, 1] that each sample is the target (0 before any training):
        the alpha-weighted vote of the selectors' best weak classifiers over sum(alpha)."""
        out = np.zeros(len(maps))
        active = np.flatnonzero(self.best >= 0)
        total = self.alpha[active].sum()
        if len(maps) == 0 or total <= 0.0:
            return out
        for m in maps:
            self._check(m.integral)
        integrals = np.stack([m.integral for m in maps])
        cols = self.best[active]
        x = _means(integrals, self.channels[active, cols], self._sub(active, cols))
        llr = self._log_likelihood_ratio(x, active, cols)
        votes = np.where(llr >= 0.0, 1.0, -1.0) @ self.alpha[active]
        return np.clip(votes / total, -1.0, 1.0)


def _means(integrals: np.ndarray, channels: np.ndarray, index: RectIndex) -> np.ndarray:
    return index.means(integrals, channels)
