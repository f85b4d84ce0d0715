"""labctl's numerical work runs with one BLAS thread, and gives the machine's setting back afterwards."""

from __future__ import annotations

import numpy as np
from threadpoolctl import threadpool_info, threadpool_limits

from labctl.blas import one_blas_thread


def blas_threads() -> list[int]:
    np.ones((2, 2)) @ np.ones((2, 2))  # numpy's BLAS loaded
    return [pool["num_threads"] for pool in threadpool_info() if pool["user_api"] == "blas"]


def test_one_blas_thread_inside_the_setting_restored_after() -> None:
    with threadpool_limits(limits=2, user_api="blas"):
        before = blas_threads()
        assert before and all(n <= 2 for n in before)
        assert one_blas_thread(blas_threads)() == [1] * len(before)
        assert blas_threads() == before
