"""Calibrate the reconcile thresholds: simulated-vs-simulated runs with nothing hidden.

``python -m bench.reconcile_null [SEEDS]`` simulates the reconcile test
campaign (tests/reconcile/forward.py) for every camera profile and SEEDS
seeds (default 10) from the built-in model, reconciles each against the same
model and prints per run the verdict, the best candidate's dBIC, the gap
against its noise floor and the largest step gap in units of its floor;
then the rate of ``none`` verdicts, the false-``unexplained`` rate, the
largest dBIC (against ``DBIC_THRESHOLD``) and the largest step ratio
(against ``goodness.STEP_FACTOR``). Not a budget benchmark.
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

from labctl.reconcile.goodness import STEP_FACTOR
from labctl.reconcile.workflow import DBIC_THRESHOLD, reconcile
from tests.reconcile.forward import SIZES, simulated_run


def main(seeds: int) -> int:
    best_scores, ratios, verdicts = [], [], []
    with tempfile.TemporaryDirectory() as tmp:
        for camera in sorted(SIZES):
            for seed in range(100, 100 + seeds):
                result = reconcile(simulated_run(Path(tmp) / f"{camera}-{seed}", camera, {}, seed=seed))
                best = max((c["score"] for c in result.candidates), default=float("-inf"))
                good = result.goodness_before
                worst = good.worst_step
                best_scores.append(best)
                ratios.append(worst.ratio if worst else 0.0)
                verdicts.append(result.verdict)
                print(f"{camera} seed {seed}: verdict {result.verdict}, best candidate dBIC {best:.1f}, gap "
                      f"{good.gap_mm:.3f} mm (floor {good.gap_floor_mm:.3f}), worst step {ratios[-1]:.2f} x its floor",
                      flush=True)
    n = len(verdicts)
    print(f"{n} runs: verdict none {verdicts.count('none')}/{n}, unexplained {verdicts.count('unexplained')}/{n}, "
          f"effect_found {verdicts.count('effect_found')}/{n}, ambiguous {verdicts.count('ambiguous')}/{n}; "
          f"largest dBIC {max(best_scores):.1f} (threshold {DBIC_THRESHOLD:g}); "
          f"largest step gap {max(ratios):.2f} x its floor (limit {STEP_FACTOR:g})")
    return 0


if __name__ == "__main__":
    sys.exit(main(int(sys.argv[1]) if len(sys.argv) > 1 else 10))
