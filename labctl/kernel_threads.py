"""How many threads numba's parallel kernels use, where sharing their work out over every core costs more than it
gives. Each ray, pixel or row is computed alone, so the results are the same on any number of threads.

* Beside labctl's own busy threads (``kernel_threads_beside``): the depth sweep's evaluation runs its compiled
  kernels (``metrics/stack.py``, ``metrics/depth.py``) beside two threads that each keep a core busy, the
  read-ahead of the next step's arrays (HDF5's decompression, ``labctl/evaluation/read_ahead.py``) and the run
  file's SHA-256 (``labctl/evaluation/conditions.py``). A kernel spread over every core then waits at its end for
  the thread that shared a core with them: on the 2-core development machine, beside other work (load average
  3.7-5.1), the evaluation of bench/evaluation.py's sweep took 24.7 s and 26.7 s with one kernel thread against
  30.5 s and 32.5 s with two (alternating), and 11.5-11.9 s of user CPU against 14.0-15.2 s.
* On every thread again (``every_kernel_thread``): the depth sweep's key steps, whose jackknives take about a
  second while the read-ahead, two steps ahead, has stopped and waits for them.
* On one thread (``serial_kernels``): a reconcile render at the bin grid has a few thousand rays, and starting
  and joining the kernels' thread team costs more than the work it shares out, the more so when other work holds
  the cores (a bin-grid render of the blaze-101 took 28 ms on 2 threads against 0.4 ms on one at a load average
  of 3). While reconcile observes a run's steps, a background thread reads the next step's frames on the second
  core (labctl/reconcile/observe.py): a team of two threads would wait on it.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager

import numba


@contextmanager
def _kernel_threads(threads: int) -> Iterator[int]:
    """numba's parallel kernels launched from this thread on ``threads`` threads (at least one) inside, the number
    yielded; the previous number restored after (numba's setting is per thread)."""
    before = numba.get_num_threads()
    numba.set_num_threads(max(1, threads))
    try:
        yield numba.get_num_threads()
    finally:
        numba.set_num_threads(before)


@contextmanager
def kernel_threads_beside(busy: int) -> Iterator[int]:
    """Inside (a ``with`` block, or a function it decorates), numba's parallel kernels launched from this thread
    use the threads of numba's pool less ``busy`` (at least one), the number yielded; the previous number is
    restored after."""
    with _kernel_threads(numba.get_num_threads() - busy) as threads:
        yield threads


@contextmanager
def serial_kernels() -> Iterator[int]:
    """Inside (a ``with`` block), numba's parallel kernels launched from this thread (the renderer's ray casting
    and aggregation, the stack statistics) run on one thread; the previous number is restored after."""
    with _kernel_threads(1) as threads:
        yield threads


@contextmanager
def every_kernel_thread() -> Iterator[int]:
    """Inside (a ``with`` block), numba's parallel kernels launched from this thread use every thread of numba's
    pool, whatever an enclosing ``kernel_threads_beside`` left them: for a step whose figures take far longer than
    the reading beside them, which runs ahead until it waits (the depth sweep's key steps)."""
    with _kernel_threads(numba.config.NUMBA_NUM_THREADS) as threads:
        yield threads
