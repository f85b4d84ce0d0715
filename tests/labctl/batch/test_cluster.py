"""The batch's local Dask cluster: its own log lines stay off the batch's stderr."""

from __future__ import annotations

import logging
import os
import subprocess
import sys
from pathlib import Path

import pytest

from labctl.batch.cluster import Cluster, machine_workers, open_client
from tests.conftest import REALTIME_GROUP

PROBE = "a log line of the cluster's own"


@pytest.mark.parametrize("logger", ["distributed.worker", "distributed.scheduler", "distributed.nanny"])
def test_the_cluster_s_error_logs_stay_off_stderr(capfd: pytest.CaptureFixture[str], logger: str) -> None:
    """Dask's scheduler, nannies and workers log their own errors, e.g. a worker's heartbeat that meets the
    scheduler already closing after a Ctrl-C, with a traceback. The batch reports every run's outcome
    itself (a task lost on the cluster included), so none of these lines reaches its stderr: one logged at
    ERROR in a worker process and in the batch's own process (where the scheduler runs) shows nowhere."""
    with open_client(Cluster(workers=1)) as client:
        client.run(logging.getLogger(logger).error, PROBE)  # in the worker process, whose stderr is ours
        logging.getLogger(logger).error(PROBE)
    out, err = capfd.readouterr()
    assert PROBE not in out + err


# A program using the cluster as labctl does: numba imported by its main module (which a spawned worker imports
# first); in the worker, a parallel kernel of an importable module loaded from the cache the program warmed, then
# a kernel compiled there
KERNELS = '''
import numba
import numpy as np


@numba.njit(parallel=True, cache=True)
def total(a):
    s = 0.0
    for i in numba.prange(a.size):
        s += a[i]
    return s


def in_a_worker():
    total(np.ones(8))  # loaded from the cache: no compile, its threads start
    late = numba.njit(lambda x: x + 1)  # compiled after the threads started
    return late(1), numba.config.NUMBA_NUM_THREADS
'''
PROGRAM = '''
import numba
import numpy as np

from labctl.batch.cluster import Cluster, open_client
from probe_kernels import in_a_worker, total

if __name__ == "__main__":
    total(np.ones(8))  # compiled and cached here
    with open_client(Cluster(workers=1)) as client:
        print(client.submit(in_a_worker, pure=False).result())
    print(numba.config.NUMBA_NUM_THREADS)
'''


@pytest.mark.xdist_group(REALTIME_GROUP)
def test_a_worker_compiles_after_its_threads_started_and_runs_on_one_thread(tmp_path: Path) -> None:
    """A worker's numba starts with NUMBA_NUM_THREADS = 1 (inherited at the spawn, not set after its imports:
    then its first compile after a cached parallel kernel ran refused with "Cannot set NUMBA_NUM_THREADS to a
    different value once the threads have been launched"), and the program's own numba keeps its value."""
    (tmp_path / "probe_kernels.py").write_text(KERNELS)
    (tmp_path / "program.py").write_text(PROGRAM)
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_NUM_THREADS"}
    env.update(NUMBA_CACHE_DIR=str(tmp_path / "cache"),
               PYTHONPATH=os.pathsep.join([str(tmp_path), str(Path(__file__).parents[3])]))
    done = subprocess.run([sys.executable, str(tmp_path / "program.py")], env=env, capture_output=True, text=True,
                          timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    worker, own = done.stdout.split("\n")[:2]
    assert worker == "(2, 1)"
    assert int(own) == machine_workers()  # numba's default: the cores this process may use


def worker_environment() -> dict[str, str | None]:
    return {name: os.environ.get(name) for name in ("MALLOC_TRIM_THRESHOLD_", "OMP_NUM_THREADS")}


@pytest.mark.xdist_group(REALTIME_GROUP)
def test_workers_keep_glibcs_malloc_thresholds_and_dasks_one_thread_numpy(monkeypatch: pytest.MonkeyPatch) -> None:
    """Dask's nannies would set MALLOC_TRIM_THRESHOLD_, which switches off glibc's dynamic mmap threshold (every
    large numpy temporary mapped and faulted in afresh); the local cluster's workers go without it, and keep
    Dask's one-thread numpy."""
    monkeypatch.delenv("MALLOC_TRIM_THRESHOLD_", raising=False)
    monkeypatch.delenv("OMP_NUM_THREADS", raising=False)
    with open_client(Cluster(workers=1)) as client:
        assert client.submit(worker_environment, pure=False).result() == {
            "MALLOC_TRIM_THRESHOLD_": None, "OMP_NUM_THREADS": "1"}
