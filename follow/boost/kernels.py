"""The online boosting learning step as one compiled loop (numba), on request.

The numpy implementation in `online_boosting` spends most of an update in Python's
per-call overhead (~40 whole-array operations on 225 values); this does the same
arithmetic in one pass, in the same order, so both give the same results. It is used
only with `[identify] compiled_boosting = true` and numba installed (the `numba` extra):
numba's compiler stays resident once loaded, about 105 MB of the process for about 1 ms
a frame (docs/identification.md, *How it works*, 3). numba is imported by `load()`, never at
import time, so a process that does not ask for the loops does not carry it.
"""

from __future__ import annotations

import math

MIN_SELECTOR_ERROR = 0.01  # keeps alpha finite (<= 2.3) for a flawless weak classifier
MAX_IMPORTANCE = 1e3  # cap of lambda along the selector chain


def _learn_step(
    integral, flat, inv_area, cls, mean, var, count, memory, min_var,
    correct, wrong, gain, num_selectors, per_selector, lowest, best, alpha, reached, hit,
):  # fmt: skip
    """One sample through all weak classifiers and the selector chain, in place.

    integral: the sample's integral image, flattened (float32); flat (4, S*W) corner
    offsets; mean/var/count (2, S*W) class Gaussians; correct/wrong (S*W) error counts
    stored times `gain`; lowest/best/alpha/reached (S) selector state; hit (S*W) scratch.
    Returns whether every weak classifier has seen both classes."""
    n = num_selectors * per_selector
    all_known = True
    for j in range(n):
        corners = (
            integral[flat[0, j]] - integral[flat[1, j]] - integral[flat[2, j]]
            + integral[flat[3, j]]
        )  # fmt: skip
        x = corners * inv_area[j]
        c = count[cls, j] + 1.0
        if c > memory:
            c = memory
        rate = 1.0 / c
        delta = x - mean[cls, j]
        mean[cls, j] += rate * delta
        var[cls, j] = (1.0 - rate) * (var[cls, j] + rate * delta * delta)
        count[cls, j] = c
        vn = max(var[0, j], min_var)
        vp = max(var[1, j], min_var)
        dn = x - mean[0, j]
        dp = x - mean[1, j]
        target = dn * dn / vn + math.log(vn) >= dp * dp / vp + math.log(vp)
        known_n = count[0, j] > 0.0
        known_p = count[1, j] > 0.0
        if not (known_n and known_p):
            target = known_p and not known_n
            all_known = False
        hit[j] = target if cls == 1 else not target

    lam = 1.0
    for s in range(num_selectors):
        entering = lam
        if lam > 0.0:
            j = s * per_selector + lowest[s]
            cj = correct[j] / gain
            wj = wrong[j] / gain
            if hit[j]:
                cj += lam
            else:
                wj += lam
            e = max(wj / (cj + wj), MIN_SELECTOR_ERROR)
            if e >= 0.5:
                lam = 0.0
            elif hit[j]:
                lam = min(lam / (2.0 * (1.0 - e)), MAX_IMPORTANCE)
            else:
                lam = min(lam / (2.0 * e), MAX_IMPORTANCE)
            reached[s] = True
        weight = entering * gain
        b, lowest_error = 0, 2.0
        for w in range(per_selector):
            j = s * per_selector + w
            added = weight if hit[j] else 0.0
            correct[j] += added
            wrong[j] += weight - added
            err = wrong[j] / (correct[j] + wrong[j])
            if err < lowest_error:
                lowest_error, b = err, w
        lowest[s] = b
        e = max(lowest_error, MIN_SELECTOR_ERROR)
        if e < 0.5:
            best[s] = b
            alpha[s] = 0.5 * math.log((1.0 - e) / min(e, 0.5))
        else:
            best[s] = -1
            alpha[s] = 0.0
    return all_known


def _replace_step(
    correct, wrong, gain, num_selectors, per_selector, rand, replace_probability, best,
    lowest, reached, stock_flat, stock_inv, stock_next, bank, sizes, flat, inv_area,
    mean, var, count, memory, replaced,
):  # fmt: skip
    """Selectors reached since the last call swap their worst weak classifier (each with
    probability `replace_probability` given uniform draws `rand`, always when no better
    than chance) for the next stocked one, with Gaussians fitted to the banks
    (bank (2, N, D) flattened integrals, `sizes` filled). Writes the replaced flat
    indices to `replaced` and returns how many."""
    n = 0
    for s in range(num_selectors):
        if not reached[s]:
            continue
        reached[s] = False
        if not (rand[s] < replace_probability or best[s] < 0):
            continue
        worst, highest = 0, -1.0
        for w in range(per_selector):
            j = s * per_selector + w
            err = wrong[j] / (correct[j] + wrong[j])
            if err > highest:
                highest, worst = err, w
        if worst == lowest[s]:
            continue
        j = s * per_selector + worst
        k = stock_next + n
        for c in range(4):
            flat[c, j] = stock_flat[c, k]
        inv_area[j] = stock_inv[k]
        correct[j] = gain
        wrong[j] = gain
        for cls in range(2):
            total, total_sq = 0.0, 0.0
            for i in range(sizes[cls]):
                v = (
                    bank[cls, i, stock_flat[0, k]] - bank[cls, i, stock_flat[1, k]]
                    - bank[cls, i, stock_flat[2, k]] + bank[cls, i, stock_flat[3, k]]
                ) * stock_inv[k]  # fmt: skip
                total += v
                total_sq += v * v
            size = max(sizes[cls], 1)
            m = total / size
            mean[cls, j] = m
            var[cls, j] = max(total_sq / size - m * m, 0.0)
            count[cls, j] = min(float(sizes[cls]), memory)
        replaced[n] = j
        n += 1
    return n


learn_step = replace_step = None  # the compiled loops, once `load()` has made them
python_learn_step = _learn_step  # the same loops uncompiled, for tests without numba
python_replace_step = _replace_step

_warmed_up = False


def load() -> bool:
    """Compile both loops with numba (or load them from its cache) and warm them up;
    False where numba is not installed."""
    global learn_step, replace_step
    if learn_step is None:
        try:
            import numba
        except ImportError:
            return False
        learn_step = numba.njit(cache=True, nogil=True)(_learn_step)
        replace_step = numba.njit(cache=True, nogil=True)(_replace_step)
    _warm_up()
    return True


def _warm_up() -> None:
    """Run both loops now, on a tiny problem with the real argument types, so that the
    first training frame does not stall on their compilation."""
    global _warmed_up
    if _warmed_up:
        return
    import numpy as np

    s, w, size = 1, 2, 4
    integral = np.zeros(size, dtype=np.float32)
    flat = np.zeros((4, s * w), dtype=np.intp)
    stats = [np.zeros((2, s * w)) for _ in range(3)]
    counts = [np.ones(s * w) for _ in range(2)]
    selectors = [np.zeros(s, dtype=np.intp) for _ in range(2)]
    reached = np.zeros(s, dtype=bool)
    learn_step(
        integral, flat, np.ones(s * w), 1, *stats, 30.0, 1e-4, *counts, 1.0, s, w,
        *selectors, np.zeros(s), reached, np.zeros(s * w, dtype=bool),
    )  # fmt: skip
    replace_step(
        *counts, 1.0, s, w, np.ones(s), 0.5, *selectors, reached, flat, np.ones(s * w), 0,
        np.zeros((2, 1, size), dtype=np.float32), np.zeros(2, dtype=np.intp), flat.copy(),
        np.ones(s * w), *stats, 30.0, np.zeros(s, dtype=np.intp),
    )  # fmt: skip
    _warmed_up = True
