"""numba's parallel kernels on the cores other busy threads of labctl leave.

The depth sweep's evaluation runs its compiled kernels (``metrics/stack.py``, ``metrics/depth.py``) beside two
threads that each keep a core busy: the read-ahead of the next step's arrays (HDF5's decompression,
``labctl/evaluation/read_ahead.py``) and the run file's SHA-256 (``labctl/evaluation/conditions.py``). A kernel
spread over every core then waits at its end for the thread that shared a core with them: on the 2-core development
machine, beside other work (load average 3.7-5.1), the evaluation of bench/evaluation.py's sweep took 24.7 s and
26.7 s with one kernel thread against 30.5 s and 32.5 s with two (alternating), and 11.5-11.9 s of user CPU
against 14.0-15.2 s. The kernels' results do not depend on the number of threads (every thread computes pixels or
rows of its own).
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager

import numba


@contextmanager
def kernel_threads_beside(busy: int) -> Iterator[int]:
    """Inside (a ``with`` block, or a function it decorates), numba's parallel kernels launched from this thread
    use the threads of numba's pool less ``busy`` (at least one), the number yielded; the previous number is
    restored after (numba's setting is per thread)."""
    before = numba.get_num_threads()
    numba.set_num_threads(max(1, before - busy))
    try:
        yield numba.get_num_threads()
    finally:
        numba.set_num_threads(before)
