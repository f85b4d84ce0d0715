"""The reconcile thresholds' error rates on null runs (simulated with nothing the model lacks).

On a null run every named effect is a false positive and an ``unexplained``
verdict is a false alarm of the goodness of fit. The rates come with their
one-sided 95 % Clopper-Pearson upper bounds (metrics/proportion.py), and the
largest best-candidate dBIC and step gap (in units of the step's noise floor)
show the margin to the thresholds ``DBIC_THRESHOLD`` and ``STEP_FACTOR``
(docs/reconcile.md).
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Sequence

from labctl.batch.index import ErrorRates, NullCalibration
from labctl.batch.tasks import Summary
from labctl.reconcile.goodness import STEP_FACTOR
from labctl.reconcile.workflow import DBIC_THRESHOLD
from metrics.proportion import upper_bound


def _rates(runs: Sequence[Summary]) -> ErrorRates:
    n = len(runs)
    reconciled = [r["reconcile"] for r in runs]
    positives = sum(bool(r["named"]) for r in reconciled)
    unexplained = sum(r["verdict"] == "unexplained" for r in reconciled)
    scores = [r["best_candidate_dbic"] for r in reconciled if r["best_candidate_dbic"] is not None]
    ratios = [r["worst_step_ratio"] for r in reconciled if r["worst_step_ratio"] is not None]
    return ErrorRates(runs=n, verdicts=dict(Counter(r["verdict"] for r in reconciled)),
                      false_positive=positives, false_positive_rate=positives / n,
                      false_positive_upper_95=upper_bound(positives, n),
                      false_unexplained=unexplained, false_unexplained_rate=unexplained / n,
                      false_unexplained_upper_95=upper_bound(unexplained, n),
                      named=dict(Counter(name for r in reconciled for name in r["named"])),
                      largest_candidate_dbic=max(scores, default=None), largest_step_ratio=max(ratios, default=None))


def null_calibration(summaries: Sequence[Summary]) -> NullCalibration | None:
    """The rates over the reconciled null runs of a sweep (all of them and per camera); None without any."""
    runs = [s for s in summaries if s.get("null") and "verdict" in s.get("reconcile", {})]
    if not runs:
        return None
    cameras = sorted({str(s["parameters"].get("camera", "")) for s in runs} - {""})
    return NullCalibration(dbic_threshold=DBIC_THRESHOLD, step_factor=STEP_FACTOR, overall=_rates(runs),
                           by_camera={c: _rates([s for s in runs if s["parameters"].get("camera") == c])
                                      for c in cameras})
