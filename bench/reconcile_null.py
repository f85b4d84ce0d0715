"""Calibrate the reconcile thresholds: simulated-vs-simulated runs with nothing hidden, as a sweep on Dask.

``python -m bench.reconcile_null [SEEDS] [--scheduler ADDRESS] [--workers N] [--output DIR]``
simulates the reconcile test campaign (tests/reconcile/forward.py: offset
calibration, 0.4-4 m sweep, PTFE and silicone plates on the robot circle, 10
frames, the cameras at their test sizes) for every camera profile and SEEDS
seeds (default 50: 200 runs) from the built-in model, with the sweep step and
the robot angles coarsened (``SWEEP_STEP_MM``, ``ANGLES_DEG``) so that
hundreds of runs fit in an hour on two cores. It runs as a ``labctl batch
sweep`` (one Dask task per run, the run file deleted after its reconcile),
prints per run the verdict, the best candidate's dBIC and the largest step
gap in units of its floor, then per camera and over all runs: the verdicts,
the false-positive rate (an effect named on a null run) and the
false-``unexplained`` rate with their 95 % upper bounds, the largest dBIC
(against ``DBIC_THRESHOLD``) and the largest step ratio (against
``goodness.STEP_FACTOR``). With --output the sweep's index.json, index.csv and
batch.html are kept there. With --boards N, also N seeds of checkerboard-only
runs (two distances, 60 mm tiles: ``tests/reconcile/test_corner_positions.py``)
of every camera, serially: the verdict, the best corner candidate's dBIC and
the corner gap (mm in the board plane and px) against its floor. Not a budget
benchmark.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import tomli_w

from labctl.batch.cluster import Cluster
from labctl.batch.index import ErrorRates
from labctl.batch.orchestrate import batch_sweep
from labctl.batch.sweep import load_sweep
from labctl.reconcile.workflow import reconcile
from tests.reconcile.runs import BACKENDS, CAMPAIGN, ROBOT, SIZES, simulated_run
from tests.reconcile.test_corner_positions import BOARD, SECOND

SWEEP_STEP_MM = 600
ANGLES_DEG = "[-60, 60, 60]"


def write_sweep(directory: Path, seeds: int) -> Path:
    """The null sweep: every camera at its test size x ``seeds`` seeds (from 100), reconciled, runs deleted."""
    robot = ROBOT.replace("[-60, 60, 20]", ANGLES_DEG)
    (directory / "campaign.toml").write_text(CAMPAIGN.format(backend="blaze", seed=100, sweep_step_mm=SWEEP_STEP_MM,
                                                             robot=robot))
    cameras = [[camera, *SIZES[camera]] for camera in sorted(BACKENDS)]
    sweep = {"sweep": {"name": "reconcile null runs", "campaign": "campaign.toml", "evaluate": False,
                       "reconcile": True, "keep_runs": False},
             "grid": {"seed": {"start": 100, "count": seeds},  # seeds outermost: the cameras take turns
                      "camera,model.camera_overrides.width,model.camera_overrides.height": cameras}}
    path = directory / "sweep.toml"
    path.write_text(tomli_w.dumps(sweep))
    return path


def _rates(label: str, c: ErrorRates) -> str:
    verdicts = ", ".join(f"{k} {v}" for k, v in sorted(c.verdicts.items()))
    return (f"{label}: {c.runs} runs ({verdicts}); false positive {c.false_positive}/{c.runs} "
            f"(95 % upper bound {c.false_positive_upper_95:.1%}), false unexplained "
            f"{c.false_unexplained}/{c.runs} (upper bound {c.false_unexplained_upper_95:.1%}); "
            f"largest dBIC {c.largest_candidate_dbic}, largest step gap {c.largest_step_ratio} x its floor")


def main(seeds: int, cluster: Cluster, output: Path | None) -> int:
    with tempfile.TemporaryDirectory(prefix="labctl-null-") as tmp:
        outdir = output or Path(tmp) / "out"
        outdir.mkdir(parents=True, exist_ok=True)
        sweep = load_sweep(write_sweep(Path(tmp), seeds))
        start = time.monotonic()
        outcome = batch_sweep(sweep, outdir, cluster)
        seconds = time.monotonic() - start
    for s in outcome.summaries:
        r = s.get("reconcile", {})
        print(f"{s['parameters']['camera']} seed {s['parameters']['seed']}: "
              + (f"verdict {r['verdict']}, named {r['named'] or 'nothing'}, best candidate dBIC "
                 f"{r['best_candidate_dbic']}, gap {r['gap_before']} mm (floor {r['gap_floor']}), worst step "
                 f"{r['worst_step_ratio']} x its floor" if "verdict" in r else f"FAILED {s['error']}"))
    calibration = outcome.calibration
    if calibration is None:
        print("no run was reconciled")
        return 1
    for camera, rates in calibration.by_camera.items():
        print(_rates(camera, rates))
    print(_rates("all", calibration.overall) + f" (thresholds: dBIC {calibration.dbic_threshold:g}, step "
          f"{calibration.step_factor:g}); {outcome.failed} failed; {seconds:.0f} s on the cluster "
          f"({seconds / max(len(outcome.summaries), 1):.1f} s per run)")
    return 0


def board_runs(seeds: int) -> None:
    """Checkerboard-only null runs (two distances, 60 mm tiles: tests/reconcile/test_corner_positions.py) of every
    camera, serially: the verdict, the best corner candidate's dBIC and the corner gap against its floor."""
    board_verdicts = []
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


if __name__ == "__main__":
    parser = argparse.ArgumentParser(prog="python -m bench.reconcile_null", description=__doc__.split("\n\n")[0])
    parser.add_argument("seeds", nargs="?", type=int, default=50, help="seeds per camera (default 50: 200 runs)")
    parser.add_argument("--scheduler", help="address of an existing Dask scheduler (default: a local cluster)")
    parser.add_argument("--workers", type=int, help="worker processes of the local cluster (default: one per core)")
    parser.add_argument("--output", type=Path, help="keep the sweep's index and report in this directory")
    parser.add_argument("--boards", type=int, default=0, help="seeds of checkerboard-only null runs per camera (serial)")
    args = parser.parse_args()
    status = main(args.seeds, Cluster(args.scheduler, args.workers), args.output) if args.seeds > 0 else 0
    if args.boards > 0:
        board_runs(args.boards)
    sys.exit(status)
