"""numpy's and scipy's BLAS on one thread, for a process that also runs torch on every core.

Why: numpy and scipy each ship OpenBLAS, which runs a large enough matrix product or an SVD on
every core and then keeps its worker threads spinning, waiting for more work, for a while after
it returns. On the robot's two cores those spinning threads took a core from the next torch pass:
after the table-plane fit (an SVD and a 2000 x 200 product), the grasp network's pass over a
testbed frame took 138-147 ms instead of 79 (ad-hoc measurement on the 2-core development host,
2026-12-04; with OpenBLAS on one thread, 80 ms after the plane fit as after nothing). The robot's
own matrices are small (3 x 3 up to 20000 x 3), so one BLAS thread costs them nothing measurable
and the networks keep both cores. For these shapes (inner dimension 3, SVDs of n x 3 points) the
answers are the same bits on one thread as on two: the plane, heights, raised points and extents
of 35 dev frames (ad hoc), ``tests/test_blas.py``, and the sim-dev results reproducing byte for
byte (BENCHMARKS.md, "Eighth pass"). Not in general: OpenBLAS's threaded product of two
300 x 200 matrices differs from its one-thread product in the last bits.

The limit is process-wide (threadpoolctl sets it in the loaded libraries) and set once; a library
loaded afterwards keeps its own default, so scipy's linear algebra, which loads scipy's OpenBLAS,
is imported first.
"""

from __future__ import annotations

_limited = False


def single_threaded_blas() -> None:
    """Limit every BLAS library loaded in this process to one thread (idempotent, cheap after
    the first call). Torch's own thread pool (OpenMP, oneDNN) is not touched."""
    global _limited
    if _limited:
        return
    import numpy  # noqa: F401  (loads numpy's OpenBLAS)
    import scipy.linalg  # noqa: F401  (loads scipy's OpenBLAS)
    from threadpoolctl import threadpool_limits

    threadpool_limits(limits=1, user_api="blas")
    _limited = True
