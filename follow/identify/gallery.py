"""A fixed-size store of the target's looks that stays diverse as it fills."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np


def add_keeping_diverse(
    entries: np.ndarray,
    count: int,
    entry: np.ndarray,
    likeness: Callable[[np.ndarray, np.ndarray], np.ndarray],
) -> int:
    """Put `entry` into `entries` (a fixed-size array whose first `count` rows are in
    use) and return the new count. A full store drops one of its two most alike entries
    (`likeness(a, b)`: pairwise, higher is more alike), the one kept longer, rather than
    the oldest: views from long ago and from other sides stay when the target has been
    seen one way for a while."""
    if count < len(entries):
        entries[count] = entry
        return count + 1
    candidates = np.concatenate([entries, entry[None]])
    alike = np.asarray(likeness(candidates, candidates), dtype=np.float64)
    np.fill_diagonal(alike, -np.inf)
    i, j = np.unravel_index(int(np.argmax(alike)), alike.shape)
    drop = min(i, j)
    if drop < len(entries):
        entries[drop:-1] = entries[drop + 1 :]
        entries[-1] = entry
    return count
