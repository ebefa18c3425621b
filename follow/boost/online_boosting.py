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

For speed (everything is a handful of whole-array numpy operations) two simplifications
are made: the Gaussians of all S x W weak classifiers learn each sample with unit weight
(the sample banks keep the classes balanced) while lambda weighs the selectors' error
counts; and lambda is carried along the chain by the weak classifier each selector had
chosen before this sample (its error updated with this sample), so the chain is a scalar
recurrence. Each selector's new best weak classifier and alpha are then chosen exactly.
The Gaussians have a bounded memory (`gaussian_memory_samples`) and the error counts a
forgetting factor (`selector_error_decay`), so that the classifier follows an appearance
that changes. Everything random comes from one seeded generator. With
`compiled_boosting` (and numba installed), the learning step and the replacement run as
the compiled loops of `kernels`, which give the same classifier.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from follow.boost import kernels
from follow.boost.kernels import MAX_IMPORTANCE, MIN_SELECTOR_ERROR
from follow.boost.sample_bank import SampleBanks
from follow.ccf.features import FeatureMaps, RectIndex
from follow.config import IdentifyConfig
from follow.types import InvalidInput

STOCK_SIZE = 512  # random weak-classifier parameters drawn at once
MIN_COUNT = float(np.finfo(np.float64).tiny)  # floor of a forgotten error count
NEG, POS = 0, 1


class OnlineBoostingClassifier:
    """Target (+1) versus others (-1) on `FeatureMaps`; confidence in [-1, 1]."""

    def __init__(
        self,
        num_channels: int,
        config: IdentifyConfig,
        seed: int | None = None,
        compiled: bool | None = None,
    ):
        """`compiled`: learn with numba's compiled loops (None: as the configuration's
        `compiled_boosting` says)."""
        if num_channels < 1:
            raise ValueError(f"online boosting needs at least one channel, got {num_channels}")
        if config.num_selectors < 1 or config.weak_classifiers_per_selector < 2:
            raise ValueError("online boosting needs >= 1 selector of >= 2 weak classifiers")
        if not 0.0 < config.rect_min_fraction <= config.rect_max_fraction <= 1.0:
            raise ValueError(
                "rect_min_fraction and rect_max_fraction must satisfy 0 < min <= max <= 1, got "
                f"{config.rect_min_fraction}, {config.rect_max_fraction}"
            )
        if config.gaussian_memory_samples < 1.0 or not 0.0 < config.selector_error_decay <= 1.0:
            raise ValueError("gaussian_memory_samples must be >= 1, selector_error_decay in (0, 1]")
        self.config = config
        self.num_channels = int(num_channels)
        self.rng = np.random.default_rng(config.seed if seed is None else seed)
        s, w = config.num_selectors, config.weak_classifiers_per_selector
        self.channels = np.zeros((s, w), dtype=np.intp)
        self.rects = np.zeros((s, w, 4))  # x0, y0, x1, y1 normalised
        self.mean = np.zeros((2, s, w))  # [others, target] Gaussians
        self.var = np.zeros((2, s, w))
        self.count = np.zeros((2, s, w))
        # lambda-weighted counts of right and wrong votes, stored multiplied by
        # `_decay_gain` (1 / the forgetting applied so far): forgetting costs nothing
        self._correct = np.ones((s, w))
        self._wrong = np.ones((s, w))
        self._decay_gain = 1.0
        self.alpha = np.zeros(s)
        self.best = np.full(s, -1, dtype=np.intp)  # -1: selector no better than chance
        self._lowest_error = np.zeros(s, dtype=np.intp)  # per selector, even if >= 0.5
        self._all_known = False  # every weak classifier has seen both classes
        self.num_updates = 0
        self.banks = SampleBanks(config.sample_bank_size)
        self._map_size: tuple[int, int] | None = None
        self._flat = np.zeros((4, s, w), dtype=np.intp)  # corner offsets into an integral
        self._inv_area = np.zeros((s, w))
        self._min_var = config.min_feature_std**2
        self._row_offsets = np.arange(s) * w
        use_kernel = config.compiled_boosting if compiled is None else compiled
        if use_kernel and not kernels.load():
            raise ValueError(
                "compiled online boosting (compiled_boosting = true) needs the `numba` "
                "package: install follow's `numba` extra, or set [identify] "
                "compiled_boosting = false"
            )
        self._kernel = kernels.learn_step if use_kernel else None
        self._hit = np.zeros(s * w, dtype=bool)
        self._replaced = np.zeros(s, dtype=np.intp)
        self._reached = np.zeros(s, dtype=bool)  # selectors reached since the last replacement
        self._pending = False  # samples learnt since the last replacement
        self._draw(STOCK_SIZE)
        self._new_weak(np.arange(s * w))

    @property
    def correct(self) -> np.ndarray:
        """Lambda-weighted count of right votes per weak classifier (S, W)."""
        return self._correct / self._decay_gain

    @property
    def wrong(self) -> np.ndarray:
        """Lambda-weighted count of wrong votes per weak classifier (S, W)."""
        return self._wrong / self._decay_gain

    # ----------------------------------------------------------------- weak classifiers
    def _draw(self, n: int) -> None:
        """Stock up n random weak-classifier parameters (rectangle, channel and, once the
        map size is known, corner offsets), drawn in bulk because drawing is per call."""
        lo, hi = self.config.rect_min_fraction, self.config.rect_max_fraction
        u = self.rng.random((n, 5))
        size = lo + (hi - lo) * u[:, :2]
        corner = u[:, 2:4] * (1.0 - size)
        rects = np.concatenate([corner, corner + size], axis=1)
        channels = np.minimum((u[:, 4] * self.num_channels).astype(np.intp), self.num_channels - 1)
        flat, inv_area = self._offsets(rects, channels)
        self._stock = [rects, channels, flat, inv_area]
        self._stock_next = 0

    def _offsets(self, rects: np.ndarray, channels: np.ndarray):
        """Corner offsets (4, n) into an integral image and 1 / area (n,) of rectangles."""
        if self._map_size is None:
            return np.zeros((4, len(rects)), dtype=np.intp), np.zeros(len(rects))
        h, w = self._map_size
        c = self.num_channels
        idx = RectIndex.build(rects, (h, w))
        rows = np.stack([idx.r1, idx.r0, idx.r1, idx.r0]) * ((w + 1) * c)
        cols = np.stack([idx.c1, idx.c1, idx.c0, idx.c0]) * c
        return rows + cols + channels, idx.inv_area

    def _new_weak(self, k: np.ndarray) -> None:
        """Fresh random weak classifiers at flat indices k, trained on the sample banks."""
        n = len(k)
        if self._stock_next + n > len(self._stock[0]):
            self._draw(max(STOCK_SIZE, n))
        take = slice(self._stock_next, self._stock_next + n)
        self._stock_next += n
        flat, inv = self._stock[2][:, take], self._stock[3][take]
        self.rects.reshape(-1, 4)[k] = self._stock[0][take]
        self.channels.reshape(-1)[k] = self._stock[1][take]
        self._flat.reshape(4, -1)[:, k] = flat
        self._inv_area.reshape(-1)[k] = inv
        self._correct.reshape(-1)[k] = self._decay_gain
        self._wrong.reshape(-1)[k] = self._decay_gain
        mean, var, count = (a.reshape(2, -1) for a in (self.mean, self.var, self.count))
        sizes = self.banks.sizes
        if self._map_size is None or sizes.max() == 0:
            mean[:, k] = var[:, k] = count[:, k] = 0.0
            self._all_known = False
            return
        # both banks at once: unused slots are zero, sums are divided by the fill levels
        data = self.banks.data
        corners = data.reshape(2, data.shape[1], -1)[:, :, flat]  # 2, N, 4, k
        f = np.einsum("j,cnjk->cnk", _CORNER_SIGNS, corners) * inv
        inv_n = (1.0 / np.maximum(sizes, 1))[:, None]
        m = f.sum(axis=1) * inv_n
        mean[:, k] = m
        var[:, k] = np.maximum(np.einsum("cnk,cnk->ck", f, f) * inv_n - m * m, 0.0)
        count[:, k] = np.minimum(sizes, self.config.gaussian_memory_samples)[:, None]
        if sizes.min() == 0:
            self._all_known = False

    def _features(self, integrals: np.ndarray, rows=None, cols=None) -> np.ndarray:
        """Rectangle means (B, ...) of stacked integrals (B, H+1, W+1, C) for all weak
        classifiers (S, W) or those at (rows, cols)."""
        flat = self._flat if rows is None else self._flat[:, rows, cols]
        inv = self._inv_area if rows is None else self._inv_area[rows, cols]
        return _rect_means(integrals, flat, inv)

    def _check(self, integral: np.ndarray) -> None:
        if integral.ndim != 3 or integral.shape[2] != self.num_channels:
            raise InvalidInput(
                f"feature maps have shape {integral.shape}, expected {self.num_channels} channels"
            )
        size = (integral.shape[0] - 1, integral.shape[1] - 1)
        if self._map_size is None:
            self._map_size = size
            flat, inv = self._offsets(self.rects.reshape(-1, 4), self.channels.reshape(-1))
            self._flat[:] = flat.reshape(self._flat.shape)
            self._inv_area[:] = inv.reshape(self._inv_area.shape)
            self._draw(STOCK_SIZE)
        elif size != self._map_size:
            raise InvalidInput(
                f"feature maps of size {size} given to a classifier trained on {self._map_size}"
            )

    def _votes(self, x: np.ndarray, mean, var, count, all_known: bool) -> np.ndarray:
        """True (target) / False per feature value by naive Bayes between the two class
        Gaussians (equal priors); a class not seen yet loses, neither seen gives False."""
        v = np.maximum(var, self._min_var)
        d = x - mean
        q = d * d / v + np.log(v)  # -2 log N(x) + const, per class
        target = q[NEG] >= q[POS]
        if not all_known:
            known_n, known_p = count[NEG] > 0, count[POS] > 0
            target = np.where(known_n & known_p, target, known_p & ~known_n)
        return target

    # ------------------------------------------------------------------------ training
    def update(self, maps: FeatureMaps, label: int) -> None:
        """Learn one sample: label +1 = target, -1 = someone else; stored in its bank.
        The selectors it reached then replace their worst weak classifier (each with
        probability `replace_probability`, always when no better than chance)."""
        self._learn_one(maps, label)
        self._replace_worst()

    def train(self, positives: Sequence[FeatureMaps], negatives: Sequence[FeatureMaps]) -> None:
        """Learn one frame's samples, then replay banked samples of the rarer class until
        both classes have had as many updates (once both banks hold samples). The worst
        weak classifiers are replaced once, after the frame, as `update` does per sample."""
        order = [(m, 1) for m in positives] + [(m, -1) for m in negatives]
        if not order:
            return
        for i in self.rng.permutation(len(order)):
            self._learn_one(*order[i])
        deficit = len(negatives) - len(positives)
        cls = POS if deficit > 0 else NEG
        if self.banks.size(cls) > 0 and self.banks.size(1 - cls) > 0:
            for _ in range(abs(deficit)):
                self._learn(self.banks.sample(cls, self.rng), cls)
        self._replace_worst()

    def _learn_one(self, maps: FeatureMaps, label: int) -> None:
        if label not in (1, -1):
            raise ValueError(f"label must be +1 or -1, got {label}")
        self._check(maps.integral)
        cls = POS if label > 0 else NEG
        self.banks.push(cls, maps.integral)
        self._learn(maps.integral, cls)

    def _learn(self, integral: np.ndarray, cls: int) -> None:
        if self._kernel is not None:
            self._learn_compiled(integral, cls)
            return
        cfg = self.config
        x = self._features(integral[None])[0]
        # the class Gaussians: running mean and variance with a bounded memory
        count = self.count[cls]
        n = np.minimum(count + 1.0, cfg.gaussian_memory_samples)
        rate = 1.0 / n
        delta = x - self.mean[cls]
        self.mean[cls] += rate * delta
        self.var[cls] = (1.0 - rate) * (self.var[cls] + rate * delta * delta)
        count[...] = n
        if not self._all_known:
            self._all_known = bool(self.count.min() > 0)
        hit = self._votes(x, self.mean, self.var, self.count, self._all_known)
        if cls == NEG:
            hit = ~hit

        # importance weight lambda along the selector chain (counts in decayed units)
        gain = self._advance_decay()
        chosen = self._row_offsets + self._lowest_error
        lams = _importance_chain(
            (self._correct.reshape(-1)[chosen] / gain).tolist(),
            (self._wrong.reshape(-1)[chosen] / gain).tolist(),
            hit.reshape(-1)[chosen].tolist(),
        )
        lam = np.asarray(lams)
        self._reached |= lam > 0.0
        added = (lam * gain)[:, None] * hit
        self._correct += added
        self._wrong += lam[:, None] * gain - added

        # each selector's best weak classifier and its voting weight
        err = self._wrong / (self._correct + self._wrong)
        best = err.argmin(axis=1)
        self._lowest_error = best
        e = np.maximum(err.reshape(-1)[self._row_offsets + best], MIN_SELECTOR_ERROR)
        good = e < 0.5
        self.best = np.where(good, best, -1)
        self.alpha = np.where(good, 0.5 * np.log((1.0 - e) / np.minimum(e, 0.5)), 0.0)
        self._pending = True
        self.num_updates += 1

    def _advance_decay(self) -> float:
        """One step of forgetting for the error counts; returns the current gain."""
        self._decay_gain /= self.config.selector_error_decay
        if self._decay_gain > 1e150:
            # counts of a selector lambda has not reached for long are forgotten down to
            # the smallest normal double, not to 0: their error would be 0 / 0
            for counts in (self._correct, self._wrong):
                np.maximum(counts / self._decay_gain, MIN_COUNT, out=counts)
            self._decay_gain = 1.0
        return self._decay_gain

    def _learn_compiled(self, integral: np.ndarray, cls: int) -> None:
        """`_learn` as one compiled loop (same arithmetic, same order)."""
        gain = self._advance_decay()
        cfg = self.config
        s, w = self.channels.shape
        self._all_known = self._kernel(
            integral.reshape(-1), self._flat.reshape(4, -1), self._inv_area.reshape(-1), cls,
            self.mean.reshape(2, -1), self.var.reshape(2, -1), self.count.reshape(2, -1),
            float(cfg.gaussian_memory_samples), self._min_var,
            self._correct.reshape(-1), self._wrong.reshape(-1), gain, s, w,
            self._lowest_error, self.best, self.alpha, self._reached, self._hit,
        )  # fmt: skip
        self._pending = True
        self.num_updates += 1

    def _replace_worst_compiled(self) -> None:
        """`_replace_worst` as one compiled loop (bank statistics summed sequentially)."""
        s, w = self.channels.shape
        if self._stock_next + s > len(self._stock[0]):
            self._draw(STOCK_SIZE)
        rand = self.rng.random(s)
        bank = self.banks.data
        replaced = self._replaced
        n = kernels.replace_step(
            self._correct.reshape(-1), self._wrong.reshape(-1), self._decay_gain, s, w, rand,
            self.config.replace_probability, self.best, self._lowest_error, self._reached,
            self._stock[2], self._stock[3], self._stock_next,
            bank.reshape(2, bank.shape[1], -1), self.banks.sizes, self._flat.reshape(4, -1),
            self._inv_area.reshape(-1), self.mean.reshape(2, -1), self.var.reshape(2, -1),
            self.count.reshape(2, -1), float(self.config.gaussian_memory_samples), replaced,
        )  # fmt: skip
        if n:
            take = slice(self._stock_next, self._stock_next + n)
            self.rects.reshape(-1, 4)[replaced[:n]] = self._stock[0][take]
            self.channels.reshape(-1)[replaced[:n]] = self._stock[1][take]
            self._stock_next += n
            if self.banks.sizes.min() == 0:
                self._all_known = False
        self._pending = False

    def _replace_worst(self) -> None:
        """Selectors reached by the last samples swap their worst weak classifier for a
        fresh one: each with probability `replace_probability`, always when no better
        than chance."""
        if not self._pending:
            return
        if self._kernel is not None and self._map_size is not None and len(self.banks):
            self._replace_worst_compiled()
            return
        if self._stock_next + len(self.best) > len(self._stock[0]):
            self._draw(STOCK_SIZE)  # as the compiled loop does, to draw the same numbers
        err = self._wrong / (self._correct + self._wrong)
        worst = err.argmax(axis=1)
        replace = (self.rng.random(len(worst)) < self.config.replace_probability) | (self.best < 0)
        replace &= self._reached & (worst != self._lowest_error)
        sel = np.flatnonzero(replace)
        if len(sel):
            self._new_weak(self._row_offsets[sel] + worst[sel])
        self._reached[:] = False
        self._pending = False

    # ---------------------------------------------------------------------- prediction
    @property
    def is_trained(self) -> bool:
        """Some selector has a weight and both classes were seen: learnt from positives
        alone, every weak classifier votes for the target (the other class, never seen,
        loses), and anyone, an all-black crop too, would score +1."""
        return bool(self.alpha.sum() > 0.0) and min(self.banks.size(0), self.banks.size(1)) > 0

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
        cols = self.best[active]
        x = self._features(np.stack([m.integral for m in maps]), active, cols)
        sub = [a[:, None, active, cols] for a in (self.mean, self.var, self.count)]
        votes = np.where(self._votes(x, *sub, all_known=False), 1.0, -1.0)
        return np.clip(votes @ self.alpha[active] / total, -1.0, 1.0)


_CORNER_SIGNS = np.array([1.0, -1.0, -1.0, 1.0])


def _rect_means(integrals: np.ndarray, flat: np.ndarray, inv_area: np.ndarray) -> np.ndarray:
    """Means (B, ...) of rectangles given by corner offsets flat (4, ...) into stacked
    integral images (B, H+1, W+1, C)."""
    corners = integrals.reshape(len(integrals), -1)[:, flat]
    return (corners[:, 0] - corners[:, 1] - corners[:, 2] + corners[:, 3]) * inv_area


def _importance_chain(correct: list, wrong: list, hit: list) -> list[float]:
    """lambda entering each selector: 1 at the first; divided by 2(1 - e) after a selector
    whose chosen weak classifier was right, by 2e after a wrong one (e = its error with
    this sample counted). A selector no better than chance ends the chain (lambda 0)."""
    lams, lam = [], 1.0
    for c, w, h in zip(correct, wrong, hit, strict=True):
        lams.append(lam)
        if lam == 0.0:
            continue
        c, w = (c + lam, w) if h else (c, w + lam)
        e = max(w / (c + w), MIN_SELECTOR_ERROR)
        if e >= 0.5:
            lam = 0.0
        else:
            lam = min(lam / (2.0 * (1.0 - e)) if h else lam / (2.0 * e), MAX_IMPORTANCE)
    return lams
