"""A frozen camera driver hands back its last image again and again, or cycles through
its ring of stale buffers (3, 4, 3, 4, ...); a sensor's noise makes no two real images
alike. Stamped as it arrives, such a repeat would pass old news for fresh, so the frame
sources (a live camera, the ROS 2 node's image topic) drop it: a freeze then delivers
nothing, and the base stops as on any stall."""

from __future__ import annotations

import hashlib
from collections import deque

import numpy as np

# The most buffers a camera's driver cycles through (OpenCV's V4L2 back-end queues 4).
MAX_DRIVER_BUFFERS = 8


class RepeatedImages:
    """Tells an image that is exactly one of the last `remembered` ones handed in.

    Images are compared by digest (SHA-1 of their bytes, about 2 ms for a 720p frame),
    so remembering several costs no more than remembering one."""

    def __init__(self, remembered: int = MAX_DRIVER_BUFFERS):
        self._digests: deque[bytes] = deque(maxlen=remembered)

    def is_repeat(self, image: np.ndarray) -> bool:
        """Whether `image` equals one of the last images that were not repeats (kept if not)."""
        digest = _digest(image)
        if digest in self._digests:
            return True
        self._digests.append(digest)
        return False


def _digest(image: np.ndarray) -> bytes:
    """A digest of the image's pixels, shape and dtype: equal only for equal images."""
    image = np.ascontiguousarray(image)
    digest = hashlib.sha1(f"{image.shape} {image.dtype.str}".encode(), usedforsecurity=False)
    digest.update(image.data)
    return digest.digest()
