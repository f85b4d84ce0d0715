"""The complete campaign reconciled with the default 19 null replicas, on local Dask clusters of given sizes.

``python -m bench.reconcile_workers [WORKERS ...]`` (default: 2 8) simulates the
``reconcile`` benchmark's measured run (bench/reconcile.py: the blaze-101's
complete campaign, 205 steps at 640 x 480, 10 frames a stack, hidden
wiggling) and reconciles it with the default null replicas on a local cluster
of each number of worker processes (one thread each, labctl/batch/cluster.py),
none taken from the replica cache. Prints per size the whole reconcile's time,
the replicas' share, the verdict and the named effects. On a machine of fewer
cores than workers the workers share the cores: what this measures there is
that K replicas run on such a cluster at all (each replica writes no frames:
labctl/reconcile/null.py), not the speed of a real one. Not a budget benchmark.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

from bench.common import scratch_dir
from bench.reconcile import _make_run
from labctl.reconcile.false_positives import DEFAULT_NULL_RUNS
from labctl.reconcile.workflow import reconcile


def main(sizes: list[int]) -> int:
    with scratch_dir() as tmp:
        measured = _make_run(Path(tmp))
        for workers in sizes:
            start = time.monotonic()
            result = reconcile(measured, null_runs=DEFAULT_NULL_RUNS, workers=workers)
            seconds = time.monotonic() - start
            named = ", ".join(e.name for e in result.named) or "nothing"
            print(f"{workers} workers: {seconds:.1f} s with {DEFAULT_NULL_RUNS} null replicas "
                  f"({result.rule.seconds:.1f} s the replicas); verdict {result.verdict}, named {named}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main([int(a) for a in sys.argv[1:]] or [2, 8]))
