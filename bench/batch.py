"""Batch speed-up: N runs evaluated one after the other, as ``labctl evaluate`` does, and as Dask tasks on a
local cluster of one worker process per core (``labctl batch runs``).

The runs are synthetic wall sweeps (bench/evaluation.py's generator: 8
positions, 320 x 240, 20 frames, x/y/z written), each evaluated into its own
directory by the batch's task function. Both sides are warmed first (the
serial side by one evaluation, every worker by one task), so that what is
compared is the steady state; the cluster's start-up is reported apart.

* speed-up (the budget): serial time / cluster time for the N runs;
* overhead per task: the cluster's time for N empty tasks, divided by N
  (submission, scheduling, the result's way back), and the cost the cluster
  adds per run: (cluster time x workers - serial time) / N.

The budget, 1.6 on a 2-core machine, leaves room for the machine's other
load and the cluster's cost per run; a perfect split would be 2.
"""

from __future__ import annotations

import time
from pathlib import Path

from bench.common import Result, scratch_dir
from bench.evaluation import make_run
from labctl.batch.cluster import Cluster, machine_workers, open_client
from labctl.batch.tasks import process_run

RUNS = 8
WIDTH, HEIGHT, FRAMES = 320, 240, 20
DISTANCES = [500 + 500 * i for i in range(8)]
BUDGET = 1.6


def _noop(index: int) -> int:
    return index


def _on_cluster(runs: list[Path], outdir: Path, workers: int) -> tuple[float, float, float]:
    """(start-up, N runs, N empty tasks) seconds on a local cluster of ``workers``."""
    start = time.perf_counter()
    with open_client(Cluster(workers=workers)) as client:
        started = time.perf_counter() - start
        warm = [client.submit(process_run, runs[k % len(runs)], outdir / f"warm{k}", True, False, pure=False)
                for k in range(workers)]
        client.gather(warm)
        start = time.perf_counter()
        client.gather([client.submit(process_run, run, outdir / run.stem, True, False, pure=False) for run in runs])
        batch_s = time.perf_counter() - start
        start = time.perf_counter()
        client.gather([client.submit(_noop, k, pure=False) for k in range(len(runs) * 10)])
        empty_s = (time.perf_counter() - start) / 10
    return started, batch_s, empty_s


def run() -> Result:
    workers = machine_workers()
    with scratch_dir() as tmp:
        directory = Path(tmp)
        runs = []
        for k in range(RUNS):
            runs.append(directory / f"unit{k}.h5")
            make_run(runs[-1], WIDTH, HEIGHT, FRAMES, DISTANCES, seed=k)
        process_run(runs[0], directory / "serial-warm", True, False)
        start = time.perf_counter()
        for run_file in runs:
            process_run(run_file, directory / "serial" / run_file.stem, True, False)
        serial_s = time.perf_counter() - start
        started, batch_s, empty_s = _on_cluster(runs, directory / "batch", workers)
    speedup = serial_s / batch_s
    added = (batch_s * workers - serial_s) / RUNS
    return Result(
        name=f"batch evaluation ({RUNS} runs of {len(DISTANCES)} x {WIDTH}x{HEIGHT} x {FRAMES} frames, "
             f"{workers} workers)",
        measured=f"cluster {batch_s:.1f} s (start-up {started:.1f} s apart) = speed-up {speedup:.2f}; "
                 f"overhead per empty task {empty_s / RUNS * 1e3:.1f} ms, added per run {added:.2f} s of "
                 f"{serial_s / RUNS:.2f} s",
        floor=f"serial {serial_s:.1f} s",
        ratio=speedup,
        budget=f">= {BUDGET} with {workers} workers",
        ok=speedup >= BUDGET,
    )
