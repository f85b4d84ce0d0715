"""The compiled parallel kernels on one thread, where sharing out their work costs more than it gives."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager

import numba


@contextmanager
def serial_kernels() -> Iterator[None]:
    """The compiled parallel kernels (the renderer's ray casting and aggregation, the stack statistics) on one
    thread within the block.

    A render at the bin grid has a few thousand rays: starting and joining the kernels' thread team costs more
    than the work it shares out, the more so when other work holds the cores (a bin-grid render of the
    blaze-101 took 28 ms on 2 threads against 0.4 ms on one at a load average of 3). While a run's steps are
    observed, a background thread reads the next step's frames on the second core (labctl/reconcile/observe.py):
    a team of two threads would wait on it. Each ray and pixel is computed alone, so the result is the same on
    any number of threads."""
    threads = numba.get_num_threads()
    numba.set_num_threads(1)
    try:
        yield
    finally:
        numba.set_num_threads(threads)
