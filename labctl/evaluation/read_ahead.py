"""Reading a sequence of steps' arrays ahead of their evaluation.

The evaluation of a stack (compiled statistics, partitions) and the reading of the next (HDF5's read and
decompression) each take about one core; h5py releases the GIL while HDF5 reads, and the compiled kernels
release it while they run, so on two cores a background thread reading step i + 1 while step i is evaluated
hides most of one behind the other (docs/benchmarks.md, evaluation). Up to two steps ahead: the steps do not all
cost the same on both sides (a key step's figures take longer than its reading, a step of x and y alone reads
for longer than it is evaluated), and a reader allowed only one step ahead waits whenever the evaluation is slower
and holds the evaluation up whenever it is. So three steps' arrays are in memory at a time, in three sets of
buffers ("slots", step i in slot i % 3): reading into a buffer again spares the kernel zeroing the fresh pages of
a new array for every stack.

The two steps ahead are read by two threads, at the same time where both are due. That matters at the start: the
first steps are read into fresh buffers, whose pages the kernel provides as they are first touched, while the
evaluation has nothing to do but wait. On the 2-core development machine (a virtual machine) first touching a
123 MB stack took 0.33 s once the process had freed and written much memory, as the benchmark's sweep does
before its evaluation, and on two threads six stacks took 0.66-0.93 s against 1.18-1.47 s on one.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from typing import TypeVar

from labctl.run.store import StepRecord

Arrays = TypeVar("Arrays")


#: the sets of buffers a step's arrays may be read into: the step yielded and the two after it
SLOTS = 3


def read_ahead(steps: Sequence[StepRecord],
               load: Callable[[StepRecord, int], Arrays]) -> Iterator[tuple[StepRecord, Arrays]]:
    """Each of ``steps`` in order with ``load(step, slot)`` (its arrays), ``load`` of the next ``SLOTS - 1`` steps
    running in ``SLOTS - 1`` background threads meanwhile. ``slot`` is the step's index modulo ``SLOTS``:
    ``load`` of step i starts only once the caller is done with step i - ``SLOTS``, so it may read into the
    buffers that step was read into, provided the caller keeps no reference to a step's arrays past its turn. The
    caller should not call h5py while it holds a step (a call waits for the read under way); an exception of
    ``load`` is raised where its step would have been yielded."""
    with ThreadPoolExecutor(max_workers=SLOTS - 1, thread_name_prefix="read-ahead") as pool:
        pending: deque[Future[Arrays]] = deque(pool.submit(load, steps[k], k % SLOTS)
                                               for k in range(min(SLOTS - 1, len(steps))))
        for i, step in enumerate(steps):
            arrays = pending.popleft().result()
            ahead = i + SLOTS - 1  # its slot is that of step i - 1, which the caller is done with
            if ahead < len(steps):
                pending.append(pool.submit(load, steps[ahead], ahead % SLOTS))
            yield step, arrays
            del arrays
