"""Tasks made in this process and on a local Dask cluster at once, from one queue.

A local cluster takes seconds to start (its worker processes import labctl,
numpy, scipy and numba), and each worker's first task is slower than the next
(a replica's noise-free step maps, ``sim/shared_renders.py``, are made once per
process). This process has all of that already. So with ``workers`` cores, this
process works through the queue from the first moment while a cluster of
``workers - 1`` processes starts in a background thread and then takes tasks
from the same queue: no core waits for the cluster.

The background thread is started with SIGINT blocked (``block_ctrl_c``), so it
and the worker processes it starts never see Ctrl-C; Ctrl-C reaches this
process's main thread, which stops taking tasks, tells the background thread to
stop, and waits for it to cancel its tasks and close the cluster. A task the
cluster cannot make (its worker lost, the cluster failing to start) goes back to
the queue and is made here.
"""

from __future__ import annotations

import threading
from collections import deque
from collections.abc import Callable, Hashable, Sequence
from queue import Empty, SimpleQueue
from typing import Any, TypeVar

from labctl.batch.cluster import Cluster, block_ctrl_c, open_client
from labctl.batch.interrupt import POLL_S
from labctl.kernel_threads import kernel_threads_beside

Item = TypeVar("Item", bound=Hashable)


class _Queue:
    """The items still to make, shared by this process and the cluster's thread."""

    def __init__(self, items: Sequence[Any]) -> None:
        self._items = deque(items)
        self._lock = threading.Lock()
        self.stop = threading.Event()

    def take(self) -> Any | None:
        with self._lock:
            return self._items.popleft() if self._items and not self.stop.is_set() else None

    def give_back(self, items: Sequence[Any]) -> None:
        with self._lock:
            self._items.extendleft(reversed(list(items)))


def make_here_and_on_cluster(make: Callable[[Any], Any], items: Sequence[Item], workers: int,
                             keep: Callable[[Item, Any], None],
                             here: Callable[[Item], None] | None = None) -> list[str]:
    """``keep(item, make(item))`` for every item, made in this process and on a local cluster of ``workers - 1``
    processes started beside it (module docstring). ``make`` must be picklable (a module-level function or a
    ``functools.partial`` of one); ``keep`` is called under a lock, from this thread or the cluster's. ``here(item)``
    is told of each item before this process makes it (progress). A task that fails on the cluster is made again
    here, where its error is raised. Returns what went wrong with the cluster itself (it failing to start, a lost
    worker), its items made here instead."""
    queue = _Queue(items)
    lock = threading.Lock()
    failures: list[str] = []

    def keep_one(item: Item, result: Any) -> None:
        with lock:
            keep(item, result)

    def cluster_side() -> None:
        running: dict[Any, Item] = {}
        finished: SimpleQueue[Any] = SimpleQueue()  # the futures done, put there by the client's thread
        try:
            with open_client(Cluster(workers=workers - 1)) as client:
                while not queue.stop.is_set():
                    while len(running) < workers - 1 and (item := queue.take()) is not None:
                        future = client.submit(make, item, pure=False)
                        future.add_done_callback(finished.put)
                        running[future] = item
                    if not running:
                        return
                    try:
                        future = finished.get(timeout=POLL_S)
                    except Empty:  # none finished yet: look at the stop flag again
                        continue
                    result = future.result()  # a task's error: its item is given back, and raises here
                    keep_one(running.pop(future), result)
                client.cancel(list(running))
        except Exception as exc:  # noqa: BLE001 - what the cluster could not make is made in this process
            failures.append(f"{type(exc).__name__}: {exc}")
        finally:
            queue.give_back(list(running.values()))

    def work_through() -> None:
        while (item := queue.take()) is not None:
            if here is not None:
                here(item)
            keep_one(item, make(item))

    with block_ctrl_c():  # the thread, and the processes it starts, inherit SIGINT blocked
        thread = threading.Thread(target=cluster_side, name="labctl-cluster", daemon=True)
        thread.start()
    try:
        with kernel_threads_beside(workers - 1):  # the cluster's processes hold the other cores
            work_through()
        while thread.is_alive():  # in short waits: Ctrl-C ends them
            thread.join(POLL_S)
        work_through()  # what the cluster gave back
    finally:
        queue.stop.set()
        thread.join()
    return failures
