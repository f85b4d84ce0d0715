"""The Dask client of a batch: a local cluster sized to the machine, or an existing cluster's scheduler.

Workers are processes with one thread each: HDF5 (h5py) serializes every call
within a process behind one lock, and the evaluation's compiled kernels
(numba) and numpy already use the core they run on, so a core is a worker
(Dask's distributed scheduler, https://distributed.dask.org/en/stable/
worker.html: ``nthreads`` and ``processes``).
"""

from __future__ import annotations

import logging
import os
import signal
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from typing import TYPE_CHECKING

from labctl.errors import InputError, RunAborted

if TYPE_CHECKING:
    from distributed import Client

#: a worker's compiled kernels run on its one core (numba would start a thread per core in every worker); set in
#: this process's environment while the local cluster spawns its workers (``_worker_environment``)
WORKER_ENVIRONMENT = {"NUMBA_NUM_THREADS": "1"}
#: Dask's nannies set these in every worker's environment, unless set to None (``distributed.nanny.pre-spawn-environ``).
#: Its MALLOC_TRIM_THRESHOLD_ = 64 KiB (to give freed memory back to the system at once) also switches off glibc's
#: dynamic mmap threshold (mallopt(3), M_TRIM_THRESHOLD), so every large numpy temporary is mapped afresh and
#: page-faulted in: an evaluation of a small sweep took 2.2-2.5 s instead of 1.4 s in a process with it set
#: (docs/benchmarks.md, batch). The local cluster's workers keep glibc's defaults.
NANNY_ENVIRONMENT = {"distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_": None}
#: the local cluster's own log lines shown: none below CRITICAL. Its scheduler, nannies and workers log their
#: errors with tracebacks (a worker's heartbeat that meets the scheduler already closing after a Ctrl-C is
#: one, a race inside Dask's shutdown); the batch reports every run's outcome itself, a task lost on the
#: cluster included, so those lines would only bury its own.
CLUSTER_LOG_LEVEL = logging.CRITICAL
#: seconds to wait for a remote scheduler before giving up
CONNECT_TIMEOUT_S = 20.0


def machine_workers() -> int:
    """The cores this process may run on (its CPU affinity, which a container or ``taskset`` narrows)."""
    try:
        return max(len(os.sched_getaffinity(0)), 1)
    except AttributeError:  # not on Linux
        return max(os.cpu_count() or 1, 1)


@dataclass(frozen=True)
class Cluster:
    """Where the tasks run: ``scheduler``, an existing cluster's address (``tcp://host:8786``; its workers
    must read the run files and write the outputs at the same paths), else a local cluster of ``workers``
    single-threaded worker processes (default: one per core)."""

    scheduler: str | None = None
    workers: int | None = None

    def __post_init__(self) -> None:
        if self.scheduler is not None and self.workers is not None:
            raise InputError("--workers sizes a local cluster; with --scheduler the cluster keeps its own workers")
        if self.workers is not None and self.workers < 1:
            raise InputError(f"--workers must be at least 1, not {self.workers}")


@contextmanager
def block_ctrl_c() -> Iterator[None]:
    """Threads and processes started inside never receive SIGINT: Ctrl-C at a terminal signals the whole
    foreground process group, and the local cluster's workers would each die with a traceback.

    SIGINT is blocked in this thread while the cluster starts. The cluster's event-loop thread starts here and
    inherits the mask (``pthread_sigmask``: a new thread inherits its creator's signal mask), and so does
    every thread it starts, among them those that start (and restart) the worker processes; a process keeps
    its mask across fork and exec, so a worker holds Ctrl-C pending and never acts on it. multiprocessing's
    resource tracker is started first: its start unblocks SIGINT in the thread that starts it. A Ctrl-C
    during the start stays pending in this process and reaches its handler when this thread unblocks it."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    from multiprocessing import resource_tracker

    resource_tracker.ensure_running()
    signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})


@contextmanager
def _worker_environment() -> Iterator[None]:
    """``WORKER_ENVIRONMENT`` in this process's environment while the workers are spawned, restored afterwards.

    A worker process reads NUMBA_NUM_THREADS when it first imports numba, which it does while it imports the
    parent's main module, before a Nanny's ``env`` would be applied; a value set after that makes numba refuse to
    compile anything once its threads run ("Cannot set NUMBA_NUM_THREADS to a different value once the threads
    have been launched"). Inherited at the spawn, the value is there from the start. This process's own numba
    keeps the value it started with. A worker the Nanny restarts later starts with this process's environment."""
    saved = {key: os.environ.get(key) for key in WORKER_ENVIRONMENT}
    os.environ.update(WORKER_ENVIRONMENT)
    try:
        yield
    finally:
        for key, value in saved.items():
            if value is None:
                os.environ.pop(key, None)
            else:
                os.environ[key] = value


@contextmanager
def open_client(cluster: Cluster) -> Iterator[Client]:
    """A connected Dask client of ``cluster``; a local cluster is closed on the way out. The local scheduler's
    HTTP server (its dashboard when the ``bokeh`` package is installed) listens on a free port. Used inside
    :func:`labctl.batch.interrupt.deferred_ctrl_c`, Ctrl-C interrupts none of the client's calls."""
    import dask
    from distributed import Client, LocalCluster

    scheduler = cluster.scheduler
    if scheduler is not None:
        try:
            client = Client(scheduler, timeout=CONNECT_TIMEOUT_S)
        except (OSError, TimeoutError, ValueError) as exc:
            raise RunAborted(f"cannot reach the Dask scheduler at {scheduler}: {exc}") from None
        try:
            yield client
        finally:
            client.close()
        return
    with block_ctrl_c(), _worker_environment(), dask.config.set(NANNY_ENVIRONMENT):
        local = LocalCluster(n_workers=cluster.workers or machine_workers(), threads_per_worker=1, processes=True,
                             dashboard_address=":0", silence_logs=CLUSTER_LOG_LEVEL)
    try:
        with Client(local) as client:
            yield client
    finally:
        local.close()
