"""Verdicts calibrated on the campaign's own null runs (docs/reconcile.md, *Null calibration*).

Before deciding, reconcile simulates K *null replicas* of the measured
campaign from the model it is about to judge: the same campaign file (the run
file stores it), the same sensor size, other seeds, nothing added. Each
replica is observed and compared to that model exactly like the measured run
(the first round of labctl/reconcile/workflow.py), which gives what the
decisions are judged by, as they come out when nothing is missing:

* the residual statistics of the goodness of fit: per residual family the
  signed root of the steps' unclipped mean square beyond the noise
  (``gap:<family>``, in the family's unit: the RMS of the step gaps where no
  step is below its noise; every family the ``Goodness`` holds), and the
  largest step gap in units of its floor (``worst_step_ratio``);
* every candidate's dBIC (labctl/reconcile/score.py).

Each decision gets an empirical p-value, p = (1 + #{null >= observed}) / (K + 1)
(a Monte Carlo test, Davison & Hinkley 1997, ch. 4): the share of the K + 1 runs (replicas and
measured run, exchangeable when nothing is missing) that reach the observed value.

* **Consistent with the noise** (``consistency``): the statistics are combined
  into one, the largest of them standardized by the mean and standard deviation
  over the K + 1 runs (a max-type statistic, Westfall & Young 1993: it tests all
  families at once at level ``ALPHA``), each family's as its mean square, not
  its root (``combined_statistics``), and in the first round the best
  candidate's dBIC beside them (``BEST``: a departure along a library effect's
  signature shows in its dBIC before it moves a whole family). Consistent when
  p > ``ALPHA``.
* **A candidate is significant**: the round's best dBIC against the null
  replicas' best dBIC among the same candidates (the winner is a maximum, so it
  is judged against the null distribution of the maximum). Significant when
  p <= ``ALPHA``.
* **Material** (practical significance): the effect must remove at least
  ``MATERIAL_FRACTION`` of the excess of one statistic over its null median.

The replicas are simulated once, from the model of the first round. A later
round (after an effect was added and fitted) is judged against the same first-
round distributions: the dBIC of the candidates still in play, and the residual
statistics alone. Fitting an effect absorbs a little noise, so a later round's
residual is slightly smaller than a null replica's would be: that judgement is
slightly lenient towards "consistent".
"""

from __future__ import annotations

import functools
import math
import shutil
import statistics as stats
import tempfile
import time
import tomllib
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import tomli_w

from labctl.reconcile import replica_cache
from labctl.reconcile.false_positives import ALPHA
from labctl.reconcile.goodness import FLOOR_FRACTION, MATERIAL_FRACTION, Goodness, StepFit, material
from labctl.reconcile.observe import MAX_FRAMES
from labctl.reconcile.results import CalibrationSection, NullJudgement, ValueRange
from labctl.reconcile.score import Fit
from sim.model import SimModel
from sim.shared_renders import forget as forget_renders
from sim.shared_renders import shared_renders

#: replica seeds: NULL_SEED_BASE, NULL_SEED_BASE + 1, ... (the measured campaign's own seed skipped); a prime far
#: above the seeds the project's campaigns and tests use, so that no replica repeats a simulated measurement
NULL_SEED_BASE = 1_000_003
WORST = "worst_step_ratio"
#: the statistic of the first round's best candidate: its dBIC, judged against the replicas' best
BEST = "best_delta_bic"
#: the noise-free step maps a process running null replicas keeps for the next replica (sim/shared_renders.py):
#: the complete campaign's 205 steps at 640 x 480 take about 0.5 GB (time-of-flight: range and amplitude in
#: float32) to 0.8 GB (stereo: disparity, its spread, validity, infrared), so all of them fit
REPLICA_RENDER_BYTES = 1 << 30


@dataclass(frozen=True)
class Replica:
    """One null replica's first-round comparison: its goodness-of-fit steps, every candidate's dBIC, the whitened
    residual sum of squares per (step, family) cell, the seconds it took, and per family its residual maps by step
    id (``goodness.residual_maps``; the minimum detectable effect crosses them with a signature)."""

    seed: int
    steps: list[StepFit]
    delta_bic: dict[str, float]
    cell_rss: np.ndarray
    seconds: float
    maps: dict[str, dict[str, np.ndarray]] = field(default_factory=dict)


def p_value(observed: float, null: Sequence[float]) -> float:
    """Empirical p-value of ``observed`` against the null values: (1 + #{null >= observed}) / (K + 1)."""
    return (1 + sum(1 for v in null if v >= observed)) / (len(null) + 1)


def p_values(rows: np.ndarray) -> np.ndarray:
    """``p_value`` of each row's first value against the rest of its row, for an (n, K + 1) array at once.

    >>> rows = np.array([[3.0, 1.0, 2.0, 4.0], [0.5, 1.0, 2.0, 4.0]])
    >>> p_values(rows).tolist(), [p_value(r[0], r[1:]) for r in rows]
    ([0.5, 1.0], [0.5, 1.0])
    """
    return (1 + np.sum(rows[:, 1:] >= rows[:, :1], axis=1)) / rows.shape[1]


def critical_value(null: Sequence[float], alpha: float = ALPHA) -> float:
    """The value a statistic must exceed for p <= ``alpha``: the (K - j)-th smallest null value, j the number of
    null values allowed at or above it (inf when even exceeding them all does not reach ``alpha``)."""
    ordered = sorted(null)
    j = math.floor(alpha * (len(ordered) + 1) + 1e-9) - 1
    if j < 0:
        return math.inf
    return ordered[len(ordered) - 1 - j] if j < len(ordered) else -math.inf


def signed_root(mean_square: float) -> float:
    """sqrt of a mean square that may be negative, with its sign: a gap-like value (the gap's unit) that goes on
    below 0 instead of piling up there."""
    return math.copysign(math.sqrt(abs(mean_square)), mean_square)


def combined_statistics(steps: Sequence[StepFit]) -> dict[str, float]:
    """The residual statistics of a goodness of fit as the standardized maximum combines them: per family the mean
    of its steps' unclipped mean squares beyond the noise (``StepFit.mean_square``), and the largest step gap in
    units of its floor. Unclipped, a family whose gaps are 0 in most null runs (the residual within its noise)
    still has a continuous null distribution. A mean over many steps' sums of squares is close to normal when
    nothing is missing, which a standardized maximum needs: its signed root (``step_statistics``) is not where it
    sits near 0, the root's slope there stretching one side. (The test campaign's validity: mean squares -0.035 to
    0.0002 over 19 replicas, spread evenly; their roots -0.187 to 0.014, the largest 3 standard deviations above
    the others' mean, which a replica with a depth effect then had to exceed as well.)"""
    out: dict[str, float] = {}
    for family in sorted({s.family for s in steps}):
        squares = [s.mean_square for s in steps if s.family == family and math.isfinite(s.gap)]
        if squares:
            out[f"gap:{family}"] = float(np.mean(squares))
    ratios = [s.ratio for s in steps if math.isfinite(s.ratio)]
    if ratios:
        out[WORST] = max(ratios)
    return out


def step_statistics(steps: Sequence[StepFit]) -> dict[str, float]:
    """The residual statistics of a goodness of fit as reconcile.json reports them: ``combined_statistics`` with
    each family's mean square as its signed root (the RMS of the step gaps, in the family's unit, where no step is
    below its noise)."""
    return {key: value if key == WORST else signed_root(value) for key, value in combined_statistics(steps).items()}


def standardized_max(pool: list[dict[str, float]]) -> list[float]:
    """For every member of ``pool`` (the measured run first, then the replicas) the largest of its statistics
    standardized by their mean and standard deviation over the pool; statistics some member lacks, or that do
    not vary, are left out."""
    if not pool:
        return []
    keys = sorted(set.intersection(*(set(p) for p in pool)))
    values = np.array([[p[key] for key in keys] for p in pool], float).reshape(len(pool), len(keys))
    return [float(v) for v in standardized_max_rows(values)]


def standardized_max_rows(values: np.ndarray) -> np.ndarray:
    """``standardized_max`` of arrays: ``values`` (..., members, statistics) gives (..., members); a statistic
    that does not vary over the members, or is NaN in one, is left out (-inf where none is left)."""
    by_statistic = np.ascontiguousarray(np.moveaxis(values, -1, -2))  # members last: reduced as one row each
    with np.errstate(invalid="ignore", divide="ignore"):
        spread = by_statistic.std(axis=-1, keepdims=True)
        z = (by_statistic - by_statistic.mean(axis=-1, keepdims=True)) / spread
    z = np.where(spread > 0, z, -np.inf)
    return z.max(axis=-2) if values.shape[-1] else np.full(values.shape[:-1], -np.inf)


@dataclass(frozen=True)
class FixedThresholds:
    """The decisions without null runs: consistent with the noise below the hand-set floors and step factor
    (labctl/reconcile/goodness.py), a candidate significant above ``dbic_threshold``, material by the floors."""

    dbic_threshold: float
    name: str = "fixed thresholds"
    null_runs: int = 0

    def consistent(self, good: Goodness) -> bool:
        return good.consistent

    def judge(self, good: Goodness) -> NullJudgement | None:
        """Nothing beyond the goodness of fit's own fixed-threshold check."""
        return None

    def significance(self, best: Fit, in_play: set[str]) -> tuple[bool, float | None]:
        return best.score >= self.dbic_threshold, None

    def threshold(self, in_play: set[str]) -> float:
        """The dBIC a candidate must reach."""
        return self.dbic_threshold

    def material(self, before: Goodness, after: Goodness) -> bool:
        return material(before, after)

    def summary(self) -> CalibrationSection:
        """The ``null_calibration`` section of reconcile.json."""
        return CalibrationSection(method=self.name, null_runs=0, dbic_threshold=self.dbic_threshold,
                                  material_fraction=MATERIAL_FRACTION, floor_fraction=FLOOR_FRACTION)


@dataclass
class NullCalibration:
    """The decisions judged against ``replicas``, the null replicas' first-round comparisons."""

    replicas: list[Replica]
    alpha: float = ALPHA
    seconds: float = 0.0
    workers: int = 1
    cached: int = 0  # replicas taken from the cache (labctl/reconcile/replica_cache.py), not simulated
    name: str = "null runs"

    @property
    def null_runs(self) -> int:
        return len(self.replicas)

    def null_statistics(self) -> list[dict[str, float]]:
        return [step_statistics(r.steps) for r in self.replicas]

    def judge(self, good: Goodness) -> NullJudgement:
        """How far ``good`` lies inside the null distribution: the combined p-value and each statistic's own
        p-value (consistent with the noise while p > alpha). The statistics are the residual's
        (``combined_statistics``) and, in the first round, the best candidate's dBIC (``BEST``, against each
        replica's best among the same candidates): a departure along a library effect's signature stands out in
        its dBIC long before it moves a family's mean square beyond the replicas' (a 0.22 mm wiggling at a 150 mm
        period on the test campaign: dBIC 12-14 against the replicas' best of at most 2.7, while its depth mean
        square stayed inside theirs in 5 of 20 runs). One combined statistic keeps the decision at alpha."""
        run = combined_statistics(good.steps)
        pool = [combined_statistics(r.steps) for r in self.replicas]
        observed = step_statistics(good.steps)
        null = self.null_statistics()
        if good.candidate_scores:
            run[BEST] = observed[BEST] = max(good.candidate_scores.values())
            for row, reported, best in zip(pool, null, self.null_best(set(good.candidate_scores)), strict=True):
                row[BEST] = reported[BEST] = best
        t = standardized_max([run, *pool])
        p = p_value(t[0], t[1:])
        marginal = {k: round(p_value(v, [n[k] for n in null if k in n]), 4) for k, v in observed.items()}
        return NullJudgement(p_value=round(p, 4), null_runs=self.null_runs,
                             statistics={k: round(v, 4) for k, v in observed.items()}, statistic_p_values=marginal)

    def consistent(self, good: Goodness) -> bool:
        return self.judge(good).p_value > self.alpha

    def null_best(self, in_play: set[str]) -> list[float]:
        """Every replica's best dBIC among the candidates ``in_play``."""
        return [max((v for k, v in r.delta_bic.items() if k in in_play), default=-math.inf) for r in self.replicas]

    def threshold(self, in_play: set[str]) -> float:
        """The dBIC the best of ``in_play`` must exceed for p <= alpha."""
        return critical_value(self.null_best(in_play), self.alpha)

    def significance(self, best: Fit, in_play: set[str]) -> tuple[bool, float | None]:
        """Whether the round's best candidate ``best`` beats the null replicas' best among ``in_play``, and p."""
        p = p_value(best.score, self.null_best(in_play))
        return p <= self.alpha, round(p, 4)

    def material(self, before: Goodness, after: Goodness) -> bool:
        """The change removes at least ``MATERIAL_FRACTION`` of one statistic's excess over its null median."""
        b, a = step_statistics(before.steps), step_statistics(after.steps)
        null = self.null_statistics()
        for key, value in b.items():
            median = stats.median(n[key] for n in null if key in n) if any(key in n for n in null) else math.nan
            excess = value - median
            if key in a and excess > 0 and value - a[key] >= MATERIAL_FRACTION * excess:
                return True
        return False

    def summary(self) -> CalibrationSection:
        """The ``null_calibration`` section of reconcile.json."""
        null = self.null_statistics()
        keys = sorted(set().union(*null)) if null else []
        dbic = sorted(set().union(*(r.delta_bic for r in self.replicas)))
        return CalibrationSection(
            method=self.name, null_runs=self.null_runs, alpha=self.alpha,
            p_value="empirical: (1 + #{null >= observed}) / (null_runs + 1)",
            seeds=[r.seed for r in self.replicas], seconds=round(self.seconds, 1), workers=self.workers,
            cached=self.cached,
            null_statistics={k: _range([n[k] for n in null if k in n]) for k in keys},
            null_best_delta_bic=_range(self.null_best(set(dbic))),
            null_delta_bic={k: _range([r.delta_bic[k] for r in self.replicas if k in r.delta_bic]) for k in dbic},
            later_rounds="judged against the first round's null distributions (the replicas are simulated once, "
                         "from the model the first round compares): the dBIC of the candidates still in play, and "
                         "the residual statistics",
            material_fraction=MATERIAL_FRACTION)


def _range(values: list[float]) -> ValueRange:
    finite = [v for v in values if math.isfinite(v)]
    if not finite:
        return ValueRange(min=None, median=None, max=None)
    return ValueRange(min=round(min(finite), 4), median=round(stats.median(finite), 4), max=round(max(finite), 4))


def replica_campaign(campaign_toml: str, seed: int, best_focus_mm: float | None = None) -> str:
    """The measured campaign as a null replica runs it: seed ``seed``, no injected faults, at most ``MAX_FRAMES``
    frames per stack (the comparison reads no more), and its ``distance_mm = "best_focus"`` steps where the
    measured run placed them (``best_focus_mm``, ``observe.measured_best_focus``), not where the replica's own
    slanted edge would: that sharpest distance moves with the noise (one replica of the complete campaign put
    the checkerboard at 806 mm, the next at 706 mm)."""
    data = tomllib.loads(campaign_toml)
    data["sim"] = {"seed": seed}
    for procedure in data.get("procedure", []):
        if isinstance(procedure.get("frames"), int):
            procedure["frames"] = min(procedure["frames"], MAX_FRAMES)
        if best_focus_mm is not None and procedure.get("distance_mm") == "best_focus":
            procedure["distance_mm"] = best_focus_mm
    return tomli_w.dumps(data)


def replica_model(model: SimModel, info: dict[str, Any]) -> str:
    """``model``'s text at the measured run's sensor size."""
    data = model.model_dump(mode="json")
    profile = model.profile()
    overrides = dict(data.get("camera_overrides") or {})
    if (profile.width, profile.height) != (info["width"], info["height"]):
        overrides.update(width=info["width"], height=info["height"])
    data["camera_overrides"] = overrides
    return tomli_w.dumps(data)


def seeds_for(campaign_toml: str, k: int) -> list[int]:
    """K replica seeds from ``NULL_SEED_BASE``, skipping the campaign's own ``[sim] seed``."""
    own = tomllib.loads(campaign_toml).get("sim", {}).get("seed")
    seeds: list[int] = []
    seed = NULL_SEED_BASE
    while len(seeds) < k:
        if seed != own:
            seeds.append(seed)
        seed += 1
    return seeds


#: the measured run's first-round comparison (``workflow.first_round``), which a replica goes through as well
Compare = Callable[[list[Any], dict[str, Any], SimModel],
                   tuple[Goodness, list[Fit], np.ndarray, dict[str, dict[str, np.ndarray]]]]


def null_replica(campaign_toml: str, model_text: str, seed: int, step_ids: list[str], info: dict[str, Any],
                 directory: str, compare: Compare) -> Replica:
    """Simulate one null replica, observe its steps ``step_ids`` as each is made, compare them to the model with
    ``compare`` (the very code the measured run goes through). Its run file in ``directory`` keeps the steps'
    metadata only (their frames go to the observer: ``RunWriter.frame_sink``) and is deleted after. A Dask task
    (labctl/batch/cluster.py) or a serial call."""
    from labctl.reconcile.observe import StepObserver
    from labctl.run.campaign import run_campaign
    from labctl.run.config import parse_campaign
    from labctl.run.lab import simulated_lab
    from labctl.run.progress import Reporter
    from sim.model import parse_model

    start = time.monotonic()
    text = replica_campaign(campaign_toml, seed, info.get("best_focus_mm"))
    campaign = parse_campaign(text, "null replica campaign")
    run = Path(directory) / f"null-{seed}.h5"
    observer = StepObserver(info["bin_px"], step_ids)
    try:
        with shared_renders(REPLICA_RENDER_BYTES):  # the same steps of the same model in every replica
            run_campaign(campaign, text, simulated_lab(campaign, model_text, seed=seed, source="null replica model"),
                         run, reporter=Reporter(quiet=True), frame_sink=observer)
    finally:
        run.unlink(missing_ok=True)
    good, fits, cell_rss, maps = compare(observer.observations(), info, parse_model(model_text, "null replica model"))
    return Replica(seed, good.steps, {f.name: f.score for f in fits}, cell_rss, time.monotonic() - start, maps)


def _replica_of_seed(campaign_toml: str, model_text: str, step_ids: list[str], info: dict[str, Any], directory: str,
                     compare: Compare, seed: int) -> Replica:
    """``null_replica`` with the seed last, for a ``functools.partial`` that a cluster's worker can unpickle."""
    return null_replica(campaign_toml, model_text, seed, step_ids, info, directory, compare)


def simulate_null_runs(campaign_toml: str, model: SimModel, info: dict[str, Any], step_ids: list[str], k: int,
                       workers: int, say: Callable[[str], None], compare: Compare) -> NullCalibration:
    """K null replicas of the measured campaign from ``model``, made by this process and a local Dask cluster of
    ``workers - 1`` processes started beside it (labctl/batch/here_and_cluster.py), or one after the other for a
    single worker. Replicas kept from an earlier reconcile
    of the same campaign against the same model are taken from the cache (labctl/reconcile/replica_cache.py),
    and those made here are kept there, each as soon as it is made."""
    model_text = replica_model(model, info)
    seeds = seeds_for(campaign_toml, k)
    start = time.monotonic()
    cache = replica_cache.cache_directory()
    keys: dict[int, str] = {}
    done: dict[int, Replica] = {}
    if cache is not None:  # the keys fingerprint labctl's source: only where a cache is kept
        keys = {seed: replica_cache.replica_key(model_text, replica_campaign(campaign_toml, seed, info.get("best_focus_mm")),
                                               step_ids, info)
                for seed in seeds}
        done = {seed: replica for seed, key in keys.items()
                if isinstance(replica := replica_cache.load(cache, key), Replica)}
    missing = [seed for seed in seeds if seed not in done]
    if done:
        say(f"{len(done)} of {k} null replicas from the cache ({cache})")
    workers = max(1, min(workers, len(missing) or 1))

    def keep(replica: Replica) -> None:
        """A replica made is kept at once: a reconcile stopped later (Ctrl-C, a lost worker) loses none of those
        made before."""
        done[replica.seed] = replica
        if cache is not None:
            replica_cache.store(cache, keys[replica.seed], replica)

    taken = len(done)
    directory = tempfile.mkdtemp(prefix="labctl-null-")
    make = functools.partial(_replica_of_seed, campaign_toml, model_text, step_ids, info, directory, compare)
    try:
        if workers == 1:
            for i, seed in enumerate(missing):
                say(f"null replica {i + 1} of {len(missing)} (seed {seed})")
                keep(make(seed))
        else:
            from labctl.batch.here_and_cluster import make_here_and_on_cluster

            say(f"{len(missing)} null replicas here and on {workers - 1} more worker(s)")
            problems = make_here_and_on_cluster(
                make, missing, workers, lambda _, replica: keep(replica),
                here=lambda seed: say(f"null replicas: {len(done) - taken} of {len(missing)} made; seed {seed} here"))
            for problem in problems:
                say(f"the cluster's replicas were made here instead: {problem}")
    finally:
        forget_renders()  # the replicas' maps, in this process
        shutil.rmtree(directory, ignore_errors=True)
    return NullCalibration([done[seed] for seed in seeds], seconds=time.monotonic() - start, workers=workers,
                           cached=k - len(missing))
