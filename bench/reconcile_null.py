"""Calibrate the reconcile threshold: simulated-vs-simulated runs with nothing hidden.

``python -m bench.reconcile_null [SEEDS]`` simulates the reconcile test
campaign (tests/labctl/test_reconcile.py) for every camera profile and SEEDS
seeds (default 10) from the built-in model, reconciles each against the same
model and prints the best candidate's dBIC per run, the largest over all runs
and the false-positive rate at ``DBIC_THRESHOLD``. Not a budget benchmark.
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

from labctl.reconcile.workflow import DBIC_THRESHOLD, reconcile
from tests.labctl.test_reconcile import SIZES, measured_run


def main(seeds: int) -> int:
    best_scores, positives = [], 0
    with tempfile.TemporaryDirectory() as tmp:
        for camera in sorted(SIZES):
            for seed in range(100, 100 + seeds):
                result = reconcile(measured_run(Path(tmp) / f"{camera}-{seed}", camera, {}, seed=seed))
                best = max((c["score"] for c in result.candidates), default=float("-inf"))
                best_scores.append(best)
                positives += result.verdict != "none"
                print(f"{camera} seed {seed}: verdict {result.verdict}, best candidate dBIC {best:.1f}", flush=True)
    print(f"{len(best_scores)} runs: largest dBIC {max(best_scores):.1f}; threshold {DBIC_THRESHOLD:g}; "
          f"false positives {positives}/{len(best_scores)}")
    return 0


if __name__ == "__main__":
    sys.exit(main(int(sys.argv[1]) if len(sys.argv) > 1 else 10))
