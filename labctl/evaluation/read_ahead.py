"""Reading a sequence of steps' arrays one step ahead of their evaluation.

The evaluation of a stack (compiled statistics, partitions) and the reading of the next (HDF5's read and
decompression) each take about one core; h5py releases the GIL while HDF5 reads, and the compiled kernels
release it while they run, so on two cores a background thread reading step i + 1 while step i is evaluated
hides most of one behind the other (docs/benchmarks.md, evaluation). One step ahead at most: two steps' arrays
are in memory at a time, so two sets of buffers ("slots", step i in slot i % 2) can hold every step's arrays:
reading into a buffer again spares the kernel zeroing the fresh pages of a new array for every stack.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from typing import TypeVar

from labctl.run.store import StepRecord

Arrays = TypeVar("Arrays")


#: the sets of buffers a step's arrays may be read into: the step yielded and the next one
SLOTS = 2


def read_ahead(steps: Sequence[StepRecord],
               load: Callable[[StepRecord, int], Arrays]) -> Iterator[tuple[StepRecord, Arrays]]:
    """Each of ``steps`` in order with ``load(step, slot)`` (its arrays), ``load`` of the next step running in a
    background thread meanwhile. ``slot`` is the step's index modulo ``SLOTS``: ``load`` of step i starts only
    once the caller is done with step i - 2, so it may read into the buffers step i - 2 was read into, provided
    the caller keeps no reference to a step's arrays past its turn. The caller should not call h5py while it
    holds a step (a call waits for the read under way); an exception of ``load`` is raised where its step would
    have been yielded."""
    with ThreadPoolExecutor(max_workers=1, thread_name_prefix="read-ahead") as pool:
        pending: Future[Arrays] | None = pool.submit(load, steps[0], 0) if steps else None
        for i, step in enumerate(steps):
            assert pending is not None
            arrays = pending.result()
            pending = pool.submit(load, steps[i + 1], (i + 1) % SLOTS) if i + 1 < len(steps) else None
            yield step, arrays
            del arrays
