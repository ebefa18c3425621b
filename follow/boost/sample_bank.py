"""A fixed-size ring of recent training samples (integral images) of one class.

The banks initialise freshly drawn weak classifiers and are replayed to balance the
number of target and non-target updates.
"""

from __future__ import annotations

import numpy as np


class SampleBank:
    """The `capacity` most recent integral images (H+1, W+1, C), stored contiguously."""

    def __init__(self, capacity: int):
        if capacity < 1:
            raise ValueError(f"sample bank capacity must be >= 1, got {capacity}")
        self.capacity = int(capacity)
        self._data: np.ndarray | None = None
        self._size = 0
        self._next = 0

    def __len__(self) -> int:
        return self._size

    def push(self, integral: np.ndarray) -> None:
        if self._data is None:
            self._data = np.empty((self.capacity, *integral.shape), dtype=integral.dtype)
        elif integral.shape != self._data.shape[1:]:
            raise ValueError(
                f"sample of shape {integral.shape} pushed into a bank of {self._data.shape[1:]}"
            )
        self._data[self._next] = integral
        self._next = (self._next + 1) % self.capacity
        self._size = min(self._size + 1, self.capacity)

    def integrals(self) -> np.ndarray:
        """All stored samples (N, H+1, W+1, C), a view."""
        if self._data is None:
            raise ValueError("sample bank is empty")
        return self._data[: self._size]

    def sample(self, rng: np.random.Generator) -> np.ndarray:
        """One stored sample drawn uniformly."""
        return self.integrals()[int(rng.integers(self._size))]
