"""Fixed-size rings of recent training samples (integral images), one per class.

The banks initialise freshly drawn weak classifiers and are replayed to balance the
number of target and non-target updates. Both classes live in one zero-initialised
array, so that statistics over both banks are a few whole-array operations.
"""

from __future__ import annotations

import numpy as np


class SampleBanks:
    """The `capacity` most recent samples (H+1, W+1, C) of each of `num_classes` classes."""

    def __init__(self, capacity: int, num_classes: int = 2):
        if capacity < 1:
            raise ValueError(f"sample bank capacity must be >= 1, got {capacity}")
        self.capacity = int(capacity)
        self.data: np.ndarray | None = None  # (classes, capacity, H+1, W+1, C), unused = 0
        self.sizes = np.zeros(num_classes, dtype=np.intp)
        self._next = [0] * num_classes

    def __len__(self) -> int:
        return int(self.sizes.sum())

    def size(self, cls: int) -> int:
        return int(self.sizes[cls])

    def push(self, cls: int, integral: np.ndarray) -> None:
        if self.data is None:
            self.data = np.zeros(
                (len(self.sizes), self.capacity, *integral.shape), dtype=integral.dtype
            )
        elif integral.shape != self.data.shape[2:]:
            raise ValueError(
                f"sample of shape {integral.shape} pushed into a bank of {self.data.shape[2:]}"
            )
        self.data[cls, self._next[cls]] = integral
        self._next[cls] = (self._next[cls] + 1) % self.capacity
        self.sizes[cls] = min(self.sizes[cls] + 1, self.capacity)

    def sample(self, cls: int, rng: np.random.Generator) -> np.ndarray:
        """One stored sample of a class, drawn uniformly."""
        if self.sizes[cls] == 0:
            raise ValueError(f"sample bank of class {cls} is empty")
        return self.data[cls, int(rng.integers(self.sizes[cls]))]
