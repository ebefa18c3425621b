"""A long run's memory kept flat: large arrays mapped on their own, returned when freed.

glibc serves a block of at least its mmap threshold (128 KiB at start) with a mapping of
its own, returned to the system when freed, but raises the threshold to the size of each
such block freed (up to 32 MiB). After the identifier has dropped one classifier's sample
banks (4 MiB), the next ones come from the heap, and as classifiers, snapshots and frames
come and go the heap fragments: a synthetic run of `follow run`'s per-frame path grew 4-7
MiB over 800-3000 frames, 0.4-0.5 MiB with the threshold fixed at 128 KiB-1 MiB (`follow
bench memory`, docs/system.md). Fixed at 1 MiB, a 640x480 frame (0.9 MiB) is still
served from the heap.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import logging
import sys

log = logging.getLogger(__name__)

M_MMAP_THRESHOLD = -3  # glibc's mallopt parameter
MMAP_THRESHOLD_BYTES = 1 << 20


def fix_mmap_threshold(threshold_bytes: int = MMAP_THRESHOLD_BYTES) -> bool:
    """Fix glibc's mmap threshold (which also stops it from rising); whether it was set.
    Elsewhere (macOS, musl) nothing is done: their allocators behave otherwise."""
    if not sys.platform.startswith("linux"):
        return False
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        mallopt = libc.mallopt
    except (OSError, AttributeError):
        log.debug("no glibc mallopt: the mmap threshold stays the allocator's own")
        return False
    mallopt.argtypes = [ctypes.c_int, ctypes.c_int]
    mallopt.restype = ctypes.c_int
    return bool(mallopt(M_MMAP_THRESHOLD, int(threshold_bytes)))
