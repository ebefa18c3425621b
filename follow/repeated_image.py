"""A frozen camera driver hands back its last image again and again; a sensor's noise
makes no two real images alike. Stamped as it arrives, such a repeat would pass old
news for fresh, so the frame sources (a live camera, the ROS 2 node's image topic) drop
it: a freeze then delivers nothing, and the base stops as on any stall."""

from __future__ import annotations

import numpy as np


class RepeatedImages:
    """Tells an image that is exactly the last one handed in."""

    def __init__(self):
        self._last: np.ndarray | None = None

    def is_repeat(self, image: np.ndarray) -> bool:
        """Whether `image` equals the last image that was not a repeat (kept if not)."""
        if self._last is not None and np.array_equal(image, self._last):
            return True
        self._last = image
        return False
