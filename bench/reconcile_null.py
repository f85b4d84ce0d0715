"""Calibrate the reconcile thresholds: simulated-vs-simulated runs with nothing hidden.

``python -m bench.reconcile_null [SEEDS]`` simulates the reconcile test
campaign (tests/reconcile/forward.py) for every camera profile and SEEDS
seeds (default 10) from the built-in model, reconciles each against the same
model and prints per run the verdict, the best candidate's dBIC, the gap
against its noise floor and the largest step gap in units of its floor;
then the rate of ``none`` verdicts, the false-``unexplained`` rate, the
largest dBIC (against ``DBIC_THRESHOLD``) and the largest step ratio
(against ``goodness.STEP_FACTOR``). Then the same for checkerboard-only
runs (two distances, 60 mm tiles: ``tests/reconcile/test_corner_positions.py``)
of every camera: the verdict, the best corner candidate's dBIC and the corner
gap (mm in the board plane and px) against its floor. Not a budget benchmark.
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

from labctl.reconcile.goodness import STEP_FACTOR
from labctl.reconcile.workflow import DBIC_THRESHOLD, reconcile
from tests.reconcile.forward import BACKENDS, SIZES, simulated_run
from tests.reconcile.test_corner_positions import BOARD, SECOND


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
    board_verdicts, board_scores = [], []
    with tempfile.TemporaryDirectory() as tmp:
        for camera in sorted(SIZES):
            for seed in range(100, 100 + seeds):
                campaign = BOARD.format(frames=5, second=SECOND, seed=seed).replace('"blaze"', f'"{BACKENDS[camera]}"')
                result = reconcile(simulated_run(Path(tmp) / f"board-{camera}-{seed}", camera, {}, campaign=campaign))
                corners = result.corners
                if corners is None:
                    print(f"{camera} seed {seed} board: verdict {result.verdict}, no corners compared", flush=True)
                    board_verdicts.append(result.verdict)
                    continue
                scores = [c["score"] for r in corners.rounds for c in r.get("candidates", [])]
                board_scores.extend(scores)
                board_verdicts.append(result.verdict)
                g = corners.before
                print(f"{camera} seed {seed} board: verdict {result.verdict}, corner gap {g.gap_mm:.3f} mm "
                      f"({g.gap_px:.3f} px; floor {g.gap_floor_mm:.3f} mm, {g.gap_floor_px:.3f} px)"
                      + (f", best corner candidate dBIC {max(scores):.1f}" if scores else ", consistent: not fitted"),
                      flush=True)
    m = len(board_verdicts)
    print(f"{m} board runs: verdict none {board_verdicts.count('none')}/{m}, unexplained "
          f"{board_verdicts.count('unexplained')}/{m}, effect_found {board_verdicts.count('effect_found')}/{m}, "
          f"not_comparable {board_verdicts.count('not_comparable')}/{m}")
    n = len(verdicts)
    print(f"{n} runs: verdict none {verdicts.count('none')}/{n}, unexplained {verdicts.count('unexplained')}/{n}, "
          f"effect_found {verdicts.count('effect_found')}/{n}, ambiguous {verdicts.count('ambiguous')}/{n}; "
          f"largest dBIC {max(best_scores):.1f} (threshold {DBIC_THRESHOLD:g}); "
          f"largest step gap {max(ratios):.2f} x its floor (limit {STEP_FACTOR:g})")
    return 0


if __name__ == "__main__":
    sys.exit(main(int(sys.argv[1]) if len(sys.argv) > 1 else 10))
