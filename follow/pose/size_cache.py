"""A bounded cache for what the detector keeps per input size.

The detector keeps, per network input shape, an input buffer (follow/pose/preprocess.py)
and, with OpenVINO, a compiled model (25-30 MiB each, follow/pose/runtime.py). One camera
needs a few shapes, one per input height; a library caller whose frame sizes vary would
add shapes without end. Only the most recently used ones are kept.
"""

from __future__ import annotations

from collections import OrderedDict

from follow.pose.people_sized_input import MAX_SMALLER_HEIGHTS

# Frame sizes whose shapes are kept: the camera's and one more (the warm-up's default,
# or two cameras taking turns), so that one camera's heights never evict each other.
FRAME_SIZES_KEPT = 2
# Shapes kept: every input height the people-sized input runs, for each of those sizes.
SHAPES_KEPT = FRAME_SIZES_KEPT * (1 + MAX_SMALLER_HEIGHTS)


class RecentlyUsed(OrderedDict):
    """A dict that keeps its `capacity` most recently used entries: setting one more
    drops the one used longest ago. Reading (`[]`, `get`) counts as a use."""

    def __init__(self, capacity: int = SHAPES_KEPT):
        if capacity < 1:
            raise ValueError(f"cache capacity must be >= 1, got {capacity}")
        super().__init__()
        self.capacity = capacity

    def __getitem__(self, key):
        value = super().__getitem__(key)
        self.move_to_end(key)
        return value

    def get(self, key, default=None):
        return self[key] if key in self else default

    def __setitem__(self, key, value) -> None:
        super().__setitem__(key, value)
        self.move_to_end(key)
        while len(self) > self.capacity:
            self.popitem(last=False)
