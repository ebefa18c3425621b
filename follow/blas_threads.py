"""One BLAS thread for the whole process.

The stack's matrices are small (a tracker's 5x5 covariances, a few hundred embedding
numbers), yet numpy's and scipy's OpenBLAS split them over every core, and their worker
threads then busy-wait for more work, on the cores the pose network needs. On two
cores that made the network 1.8x slower as soon as the identifier was learning
(`follow bench --scene robot --people 1`: 28-29 ms a frame against 16 ms; docs/pose.md,
*The input height from the people in view*). One thread loses nothing measurable on
these sizes.
"""

from __future__ import annotations

import logging

log = logging.getLogger(__name__)


def limit_blas_threads(threads: int = 1) -> None:
    """Limit every BLAS library numpy and scipy load to `threads` threads from now on."""
    import numpy  # noqa: F401  (loads numpy's BLAS)
    import scipy.linalg  # noqa: F401  (loads scipy's own BLAS)
    from threadpoolctl import threadpool_limits

    threadpool_limits(limits=threads, user_api="blas")
    log.debug("BLAS limited to %d thread(s)", threads)
