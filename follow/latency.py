"""Capture-to-command latency: from a frame's capture to the first command computed
from its result, the delay a following robot reacts with."""

from __future__ import annotations

from collections import deque

import numpy as np


class LatencyRecorder:
    """The newest `window` latencies (bounded memory on runs of any length)."""

    def __init__(self, window: int = 4096):
        self._values_s: deque[float] = deque(maxlen=window)
        self.count = 0

    def add(self, latency_s: float) -> None:
        self._values_s.append(latency_s)
        self.count += 1

    def summary_ms(self, skip: int = 0) -> dict[str, float | None]:
        """Median and 95th percentile in milliseconds (None before the first), and the
        number of latencies they come from, without the first `skip` recorded (a
        warm-up)."""
        kept = list(self._values_s)[max(0, skip - (self.count - len(self._values_s))) :]
        if not kept:
            return {"median": None, "p95": None, "samples": 0}
        values = 1e3 * np.asarray(kept)
        return {
            "median": round(float(np.median(values)), 2),
            "p95": round(float(np.percentile(values, 95)), 2),
            "samples": len(kept),
        }
