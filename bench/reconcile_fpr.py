"""The false-positive rate of reconcile's null-calibrated decisions, over hundreds of null runs.

``python -m bench.reconcile_fpr [RUNS] [--null-runs K] [--check N] [--scheduler ADDRESS] [--workers N]``
simulates RUNS (default 200) null runs of the reconcile test campaign
(tests/reconcile/runs.py ``CAMPAIGN``: offset calibration, 0.4-4 m sweep in
200 mm steps, PTFE and silicone plates on the robot circle, 10 frames;
blaze-101 at 160 x 120, nothing hidden) and compares each with the model
exactly as reconcile compares a measured run and its null replicas
(``labctl.reconcile.null.null_replica`` with ``workflow.first_round``), one
Dask task per run. Each run is then judged against K (default 19) of the
others, its K successors in the pool taken cyclically, as reconcile judges a
measured run against its K null replicas: the two decisions a null run can get
wrong are

* **outside the null distribution** (``NullCalibration.judge``: the largest
  standardized statistic, the residual's and the first round's best dBIC,
  p <= alpha; the row ``residual``); without it reconcile stops with ``none``;
* **best candidate significant** (``NullCalibration.significance``: the best
  dBIC against the replicas' best, p <= alpha), counted whether or not the
  residual decision let reconcile get that far.

Prints per decision the rate with its 95 % Clopper-Pearson interval, the rate
of both together (what naming an effect needs at least) and each statistic's
marginal rate. With --check N, N of the runs (those with the residual outside
the null distribution first) are simulated again as run files and reconciled
in full against their K successors' replicas: their verdict and first-round
statistics must be those the pool gave them, which shows that the pool's
decisions are the reconcile's. Every member is a run of the campaign with its
own seed, so the runs and replicas are exchangeable and a decision at alpha =
0.05 with K = 19 is wrong 1 time in 20 at most; this measures whether the
implementation keeps that promise.
Not a budget benchmark.
"""

from __future__ import annotations

import argparse
import math
import shutil
import sys
import tempfile
import time
from pathlib import Path

from scipy import stats

from labctl.batch.cluster import Cluster, open_client
from labctl.reconcile.false_positives import ALPHA, DEFAULT_NULL_RUNS
from labctl.reconcile.goodness import Goodness
from labctl.reconcile.null import (
    NullCalibration,
    Replica,
    null_replica,
    p_value,
    replica_model,
    step_statistics,
)
from labctl.reconcile.observe import observe_run
from labctl.reconcile.workflow import base_model, first_round, reconcile
from tests.reconcile.runs import simulated_run

#: pool seeds from here: apart from the project's test seeds and from the replica seeds (null.NULL_SEED_BASE)
FIRST_SEED = 500_000
CAMERA = "blaze101"


def successors(pool: list[Replica], i: int, k: int) -> list[Replica]:
    """The K members after ``i`` in the pool, cyclically: the null replicas member ``i`` is judged against."""
    return [pool[(i + j) % len(pool)] for j in range(1, k + 1)]


def decisions(member: Replica, others: list[Replica]) -> dict[str, float]:
    """Member's p-values against ``others``: the combined residual, each statistic, the best candidate's dBIC."""
    rule = NullCalibration(others)
    judged = rule.judge(Goodness(math.nan, math.nan, math.nan, math.nan, member.steps,
                                 candidate_scores=dict(member.delta_bic)))
    in_play = set(member.delta_bic)
    best = max(member.delta_bic.values(), default=-math.inf)
    return {"residual": judged.p_value, "candidate": p_value(best, rule.null_best(in_play)),
            **{f"statistic {k}": v for k, v in judged.statistic_p_values.items()}}


def interval(hits: int, n: int) -> tuple[float, float]:
    """The exact (Clopper-Pearson 1934) 95 % interval of a rate ``hits / n``."""
    ci = stats.binomtest(hits, n).proportion_ci(0.95, method="exact")
    return float(ci.low), float(ci.high)


def rates(judged: list[dict[str, float]], alpha: float) -> list[str]:
    """One line per decision: the share of null runs with p <= alpha, its interval."""
    keys = ["residual", "candidate", *sorted({k for d in judged for k in d} - {"residual", "candidate"})]
    lines = []
    for key in keys:
        values = [d[key] for d in judged if key in d]
        hits = sum(v <= alpha for v in values)
        lo, hi = interval(hits, len(values))
        lines.append(f"| {key} | {hits}/{len(values)} ({hits / len(values):.1%}) | {lo:.1%}-{hi:.1%} |")
    both = sum(d["residual"] <= alpha and d["candidate"] <= alpha for d in judged)
    lo, hi = interval(both, len(judged))
    lines.append(f"| residual and candidate | {both}/{len(judged)} ({both / len(judged):.1%}) | {lo:.1%}-{hi:.1%} |")
    return ["| decision | p <= alpha | 95 % interval |", "|---|---|---|", *lines]


def check(pool: list[Replica], i: int, k: int, directory: Path, alpha: float) -> str:
    """Reconcile member ``i`` in full, from a run file of its seed, against its successors; compare with the pool."""
    member = pool[i]
    run = simulated_run(directory / f"check-{member.seed}", CAMERA, seed=member.seed)
    result = reconcile(run, null=NullCalibration(successors(pool, i, k)))
    expected = step_statistics(member.steps)
    got = step_statistics(result.goodness_before.steps)
    same = expected.keys() == got.keys() and all(math.isclose(expected[key], got[key], rel_tol=1e-9, abs_tol=1e-12)
                                                 for key in expected)
    p = decisions(member, successors(pool, i, k))["residual"]
    agrees = (result.verdict == "none") == (p > alpha)
    shutil.rmtree(directory / f"check-{member.seed}", ignore_errors=True)
    return (f"seed {member.seed}: reconcile verdict {result.verdict}, pool residual p {p:.3f}: "
            f"{'agrees' if agrees else 'DISAGREES'}; first-round statistics {'identical' if same else 'DIFFER'}")


def main(runs: int, k: int, checks: int, cluster: Cluster) -> int:
    if runs < k + 1:
        print(f"RUNS must exceed K ({k}): each run is judged against K others", file=sys.stderr)
        return 2
    start = time.monotonic()
    with tempfile.TemporaryDirectory(prefix="labctl-fpr-") as tmp:
        first = simulated_run(Path(tmp) / "first", CAMERA, seed=FIRST_SEED)
        observations, info, _ = observe_run(first)
        model_text = replica_model(base_model(info), info)
        step_ids = [o.scene.step_id for o in observations]
        seeds = list(range(FIRST_SEED, FIRST_SEED + runs))
        pool: list[Replica] = []
        with open_client(cluster) as client:
            workers = len(client.scheduler_info()["workers"])
            futures = client.map(null_replica, [info["campaign_toml"]] * runs, [model_text] * runs, seeds,
                                 [step_ids] * runs, [info] * runs, [tmp] * runs, [first_round] * runs, pure=False)
            for n, future in enumerate(futures, 1):
                pool.append(future.result())
                if n % 10 == 0 or n == runs:
                    elapsed = time.monotonic() - start
                    print(f"{n}/{runs} null runs simulated and compared, {elapsed:.0f} s, about "
                          f"{elapsed / n * (runs - n):.0f} s left", flush=True)
        judged = [decisions(member, successors(pool, i, k)) for i, member in enumerate(pool)]
        print(f"{runs} null runs of the test campaign ({CAMERA} 160 x 120), each judged against K = {k} others, "
              f"alpha = {ALPHA}; simulated on {workers} workers in {time.monotonic() - start:.0f} s "
              f"({sum(r.seconds for r in pool) / runs:.1f} s per run in a worker)")
        print("\n".join(rates(judged, ALPHA)))
        flagged = [i for i, d in enumerate(judged) if d["residual"] <= ALPHA]
        print(f"residual outside the null distribution: seeds {[pool[i].seed for i in flagged] or 'none'}")
        for i in (flagged + [i for i in range(runs) if i not in flagged])[:checks]:  # both outcomes checked
            print(check(pool, i, k, Path(tmp), ALPHA), flush=True)
    print(f"done in {time.monotonic() - start:.0f} s")
    return 0


if __name__ == "__main__":
    parser = argparse.ArgumentParser(prog="python -m bench.reconcile_fpr", description=__doc__.split("\n\n")[0])
    parser.add_argument("runs", nargs="?", type=int, default=200, help="null runs (default 200)")
    parser.add_argument("--null-runs", type=int, default=DEFAULT_NULL_RUNS, help="K replicas per judged run")
    parser.add_argument("--check", type=int, default=4, help="runs reconciled in full to check the pool (default 4)")
    parser.add_argument("--scheduler", default=None, help="a running Dask scheduler (default: a local cluster)")
    parser.add_argument("--workers", type=int, default=None, help="local workers (default: one per core)")
    args = parser.parse_args()
    sys.exit(main(args.runs, args.null_runs, args.check, Cluster(scheduler=args.scheduler, workers=args.workers)))
