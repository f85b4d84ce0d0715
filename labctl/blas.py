"""One BLAS thread for labctl's numerical work.

numpy's OpenBLAS starts a thread per core for a matrix product, and its threads spin while they wait for
work. labctl's products are small (a plane fit of 50 000 points, reconcile's 130 000 x 5 Jacobians) and its
compiled kernels already use the cores, so a second BLAS thread costs more than it gives: on the 2-core
development machine reconcile's complete campaign took 31.6 s with two and 26.5 s with one (51 s against
34 s of CPU time), and under load a 130 000 x 5 product took 16 ms on two threads against 0.8 ms on one
(docs/benchmarks.md). One thread also makes the results independent of the machine's core count: a sum
split over threads is added in another order (the plane fits' RMS differed in the 16th digit).
The Dask workers of labctl/batch/cluster.py start with one BLAS thread already (OPENBLAS_NUM_THREADS=1).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import ParamSpec, TypeVar

from threadpoolctl import threadpool_limits

P = ParamSpec("P")
R = TypeVar("R")


def one_blas_thread(function: Callable[P, R]) -> Callable[P, R]:
    """``function`` run with numpy's BLAS limited to one thread (threadpoolctl), the limit lifted after it."""
    return threadpool_limits.wrap(limits=1, user_api="blas")(function)
