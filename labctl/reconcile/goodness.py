"""Goodness of fit: is the remaining residual consistent with the noise the stacks themselves show?

The run's gap (``gap_before``, ``gap_after`` of reconcile.json), in mm: the RMS over every usable bin of every step
of the systematic mean-depth residual (measured minus simulated bin mean, the
lab's nuisance removed), with the bin means' own noise variance (estimated
from the stacks) subtracted: sqrt(max(0, mean(r^2 - var))). The intensity
gap is the same for ln I in % (each step's gain removed; the gap that
vignetting, which leaves depth alone, closes). For every step and family
the *step gap* is the same over that step's bins. Its *floor* is the noise
level of one bin mean of that step, combined with what the comparison itself
cannot resolve:

    floor_s^2 = mean_s(var_bin) + Z_FLOOR_MM^2 + REFERENCE_NOISE_MM^2 (stage steps)

(``Z_FLOOR_MM``: the binned simulation against the full-resolution one;
``REFERENCE_NOISE_MM``: the reading noise of the reference distance of a
stage step, which no stack shows: one reading per step). The run's
``gap_floor`` is the same over all usable bins (root of the mean of the
bins' floor^2), in the gap's unit.

The noise's statistics form three more families (labctl/reconcile/residuals.py
states each residual and its sampling variance var_i, derived from sampling
statistics): ``noise`` (ln of the measured temporal std over the model's, in
%), ``validity`` (valid fraction measured minus predicted, in percentage
points) and ``correlation`` (ln of the measured correlation ratio over the
model's, in %). Their gaps and floors are built like the depth's, from
their rows:

    gap = 100 sqrt(max(0, mean(r_i^2 - var_i))),
    floor = 100 sqrt(mean(var_i) + STAT_FLOORS[family]^2)

per step and over the run. With 10 frames per step (observe.MAX_FRAMES), one
bin of 16 pixels has var = 0.0035 (6 %) in ``noise`` (psi'(72) / 4), 0.25 (50
%) in ``correlation`` (psi'(4.5) + psi'(72)) and p (1 - p) / 160 in
``validity`` (at most 4 percentage points): the per-step and run gaps average
over hundreds of bins, so a temporal noise 10 % off the model's, or a
correlation ratio 1.5 times the model's, stands far above them.

A residual is **consistent with noise** when the run's gap is at most its
floor and no step's gap exceeds ``STEP_FACTOR`` times that step's floor, in
every family: a systematic residual smaller than the random scatter of a
single bin mean cannot be told from noise by eye or by any one step, and a
step far above its own floor (a drift seen early in a run, one misplaced
target) is not hidden by averaging over many quiet steps. ``STEP_FACTOR`` is
calibrated on runs with nothing hidden (``bench/reconcile_null.py`` prints
the largest step ratio reached).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from drivers.laser.dimetix import REPEATABILITY_2SIGMA_MM
from labctl.reconcile.observe import Observation
from labctl.reconcile.predict import Prediction
from labctl.reconcile.residuals import (
    LOG_I_FLOOR,
    LOG_I_FLOOR_PROJECTOR,
    STAT_FLOORS,
    STATISTICS,
    Z_FLOOR_MM,
    Layout,
    sampling_variance,
)
from labctl.reconcile.results import FamilyGoodness, GoodnessSummary, StepAboveFloor

# The fixed thresholds (``--null-runs 0``; with null runs, labctl/reconcile/null.py, the replicas' distributions decide)
REFERENCE_NOISE_MM = REPEATABILITY_2SIGMA_MM / 2  # one distance reading per stage step (the laser meter's 1 sigma)
STEP_FACTOR = 3.0  # twice the largest step ratio of 200 null runs of the test campaign (1.50, docs/reconcile.md)
MATERIAL_FRACTION = 0.2  # an effect must remove at least this share of a family's gap (set by hand) ...
FLOOR_FRACTION = 0.5  # ... and at least this multiple of that family's noise floor (set by hand: half a floor)


UNITS = {"depth": "mm", "intensity": "%", "noise": "%", "validity": "percentage points", "correlation": "%"}


@dataclass(frozen=True)
class StepFit:
    """One step's systematic residual against its noise floor, in one family."""

    step_id: str
    family: str  # "depth" (mm), "intensity" (%), "noise", "validity", "correlation" (``UNITS``)
    gap: float
    floor: float
    excess: float | None = None  # mean(v^2 - var), the gap's square before it is clipped at 0 (None: gap^2)

    @property
    def mean_square(self) -> float:
        """The systematic residual's mean square, unclipped: an unbiased estimate that is negative when the
        residual is smaller than its noise alone would make it (the gap is its root, 0 there)."""
        return self.gap**2 if self.excess is None else self.excess

    @property
    def ratio(self) -> float:
        return self.gap / self.floor if self.floor > 0 else math.inf


@dataclass(frozen=True)
class FamilyGap:
    """The run's gap and floor in one statistics family (``STATISTICS``), in its unit (``UNITS``)."""

    family: str
    gap: float
    floor: float


@dataclass(frozen=True)
class Goodness:
    """The residual of one model against the noise: run gaps, their floors, per-step detail, the verdict.

    Every family (``families``) has a run gap and floor (``family_gap``) and its steps in ``steps``."""

    gap_mm: float
    gap_floor_mm: float
    intensity_gap_pct: float
    intensity_gap_floor_pct: float
    steps: list[StepFit]
    statistics: tuple[FamilyGap, ...] = ()  # the noise, validity and correlation families
    #: the first round's candidates' dBIC, which the null calibration judges beside the residual statistics
    #: (labctl/reconcile/null.py); None in a later round, whose candidates the null replicas do not score
    candidate_scores: dict[str, float] | None = None

    @property
    def worst_step(self) -> StepFit | None:
        return max(self.steps, key=lambda s: s.ratio, default=None)

    @property
    def families(self) -> tuple[str, ...]:
        """The families compared: depth, intensity and the statistics families present."""
        return ("depth", "intensity", *(f.family for f in self.statistics))

    def family_gap(self, family: str) -> tuple[float, float]:
        """(gap, floor) of the run in ``family``, in its unit (``UNITS``)."""
        if family == "depth":
            return self.gap_mm, self.gap_floor_mm
        if family == "intensity":
            return self.intensity_gap_pct, self.intensity_gap_floor_pct
        found = next((f for f in self.statistics if f.family == family), None)
        return (found.gap, found.floor) if found else (math.nan, math.nan)

    def family_consistent(self, family: str) -> bool:
        """The run's gap in ``family`` is at most its floor and no step exceeds ``STEP_FACTOR`` floors."""
        gap, floor = self.family_gap(family)
        return (not math.isfinite(gap) or gap <= floor) and all(
            s.ratio <= STEP_FACTOR for s in self.steps if s.family == family)

    @property
    def depth_consistent(self) -> bool:
        return self.family_consistent("depth")

    @property
    def intensity_consistent(self) -> bool:
        return self.family_consistent("intensity")

    @property
    def means_consistent(self) -> bool:
        """Depth and intensity bin means consistent with the noise."""
        return self.depth_consistent and self.intensity_consistent

    @property
    def inconsistent_statistics(self) -> list[str]:
        """The statistics families whose residual stands above its floor."""
        return [f.family for f in self.statistics if not self.family_consistent(f.family)]

    @property
    def consistent(self) -> bool:
        return self.means_consistent and not self.inconsistent_statistics

    def family_summary(self) -> dict[str, FamilyGoodness]:
        """Per family: run gap, floor, unit, consistency and how many steps it compared."""
        out = {}
        for family in self.families:
            gap, floor = self.family_gap(family)
            out[family] = FamilyGoodness(gap=rounded(gap), floor=rounded(floor), unit=UNITS[family],
                                         consistent=self.family_consistent(family),
                                         steps=sum(s.family == family for s in self.steps))
        return out

    def summary(self) -> GoodnessSummary:
        """The record reconcile.json gives: gaps, floors, consistency, the families, and the steps furthest above their floors."""
        return GoodnessSummary(
            gap=rounded(self.gap_mm), gap_floor=rounded(self.gap_floor_mm), intensity_gap=rounded(self.intensity_gap_pct),
            intensity_gap_floor=rounded(self.intensity_gap_floor_pct), consistent_with_noise=self.consistent,
            depth_consistent=self.depth_consistent, intensity_consistent=self.intensity_consistent,
            step_factor=STEP_FACTOR, families=self.family_summary(),
            steps_above_floor=steps_above_floor(self.steps))


def rounded(value: float) -> float | None:
    """``value`` to 4 decimals, None where it is not finite (a gap or floor as reconcile.json gives it)."""
    return round(float(value), 4) if math.isfinite(value) else None


def steps_above_floor(steps: list[StepFit]) -> list[StepAboveFloor]:
    """Of the five steps furthest above their floors, those above (gap over floor > 1), furthest first."""
    worst = sorted(steps, key=lambda s: -s.ratio)[:5]
    return [StepAboveFloor(step=s.step_id, family=s.family, gap=rounded(s.gap), floor=rounded(s.floor),
                           ratio=rounded(s.ratio)) for s in worst if s.ratio > 1.0]


def _excess(v: np.ndarray, var: np.ndarray) -> float:
    """The residual's mean square beyond its noise's variance (unbiased, may be negative)."""
    return float(np.mean(v * v - var)) if len(v) else math.nan


def _systematic(v: np.ndarray, var: np.ndarray) -> float:
    return math.sqrt(max(0.0, _excess(v, var))) if len(v) else math.nan


def depth_floor_sq(lay: Layout, obs: list[Observation]) -> np.ndarray:
    """Every depth row's floor^2 (mm^2): its bin mean's variance, the simulator's floor, the reference's noise."""
    var = lay.stack_z([o.z_var for o in obs])
    stage = np.array([o.scene.reference != "robot" for o in obs], bool)[lay.z_step] if len(obs) else np.zeros(0, bool)
    return var + Z_FLOOR_MM**2 + np.where(stage, REFERENCE_NOISE_MM**2, 0.0)


def statistics_goodness(lay: Layout, obs: list[Observation], preds: list[Prediction],
                        stats: dict[str, list[np.ndarray]]) -> tuple[list[StepFit], tuple[FamilyGap, ...]]:
    """Per-step fits and run gaps of the statistics families (``residuals.raw_statistics`` maps ``stats``), in
    % (noise, correlation: 100 x the log ratio) and percentage points (validity)."""
    variances = [sampling_variance(o, p) for o, p in zip(obs, preds, strict=True)]
    steps: list[StepFit] = []
    runs = []
    for family in STATISTICS:
        v = lay.stack_family(family, stats[family])
        var = lay.stack_family(family, [x[family] for x in variances])
        # the rows were chosen on the first model; a model fitted since may predict nothing in some of them (a
        # stereo bin whose light slope now hides its texture): those rows are not compared
        compared = np.isfinite(v) & np.isfinite(var)
        v, var = v[compared], var[compared]
        floor_sq = var + STAT_FLOORS[family] ** 2
        rows = lay.s_step.get(family, np.zeros(0, int))[compared]
        for s, o in enumerate(obs):
            m = rows == s
            if m.sum() >= 2:
                steps.append(StepFit(o.scene.step_id, family, 100 * _systematic(v[m], var[m]),
                                     100 * math.sqrt(np.mean(floor_sq[m])), 100**2 * _excess(v[m], var[m])))
        if len(v):
            runs.append(FamilyGap(family, 100 * _systematic(v, var), 100 * math.sqrt(np.mean(floor_sq))))
    return steps, tuple(runs)


def depth_residual_maps(lay: Layout, dz: list[np.ndarray]) -> list[np.ndarray]:
    """Per-step depth residual maps (mm) with the lab's nuisance removed (NaN outside the compared bins)."""
    return lay.unstack(lay.profile_z(np.nan_to_num(lay.stack_z(dz))), lay.z_masks)


def residual_maps(lay: Layout, dz: list[np.ndarray], di: list[np.ndarray],
                  stats: dict[str, list[np.ndarray]]) -> dict[str, list[np.ndarray]]:
    """Per family, the per-step maps of the residual whose mean square beyond the noise is a step's
    ``StepFit.mean_square``, in the unit of its gaps (``UNITS``: depth profiled in mm, intensity profiled in %, the
    statistics families in % or percentage points); NaN outside the compared bins. What the minimum detectable
    effect crosses a signature with (labctl/reconcile/power.py)."""
    out = {"depth": depth_residual_maps(lay, dz),
           "intensity": lay.unstack(100 * lay.profile_i(np.nan_to_num(lay.stack_i(di))), lay.i_masks)}
    for family in STATISTICS:
        masks = lay.family_masks(family)
        if masks:
            out[family] = lay.unstack(100 * lay.stack_family(family, stats[family]), masks)
    return out


def goodness(lay: Layout, obs: list[Observation], dz: list[np.ndarray], di: list[np.ndarray],
             technology: str, preds: list[Prediction] | None = None,
             stats: dict[str, list[np.ndarray]] | None = None) -> Goodness:
    """The goodness of fit of the residual maps ``dz``, ``di`` (``residuals.raw_residuals``) and, with the
    predictions ``preds`` and the statistics maps ``stats`` (``residuals.raw_statistics``), of the noise,
    validity and correlation families."""
    v = lay.profile_z(np.nan_to_num(lay.stack_z(dz)))
    var = lay.stack_z([o.z_var for o in obs])
    floor_sq = depth_floor_sq(lay, obs)
    with np.errstate(invalid="ignore", divide="ignore"):
        log_var = lay.stack_i([o.intensity_var / o.intensity**2 for o in obs])
    w = lay.profile_i(np.nan_to_num(lay.stack_i(di)))
    projector = np.array([technology == "stereo" and o.scene.projector for o in obs], bool)
    i_floor_sq = log_var + np.where(projector[lay.i_step], LOG_I_FLOOR_PROJECTOR**2, LOG_I_FLOOR**2) \
        if len(obs) else np.zeros(0)
    steps: list[StepFit] = []
    for s, o in enumerate(obs):
        m = lay.z_step == s
        if m.sum() >= 2:
            steps.append(StepFit(o.scene.step_id, "depth", _systematic(v[m], var[m]), math.sqrt(np.mean(floor_sq[m])),
                                 _excess(v[m], var[m])))
        m = lay.i_step == s
        if m.sum() >= 2:
            steps.append(StepFit(o.scene.step_id, "intensity", 100 * _systematic(w[m], log_var[m]),
                                 100 * math.sqrt(np.mean(i_floor_sq[m])), 100**2 * _excess(w[m], log_var[m])))
    statistics: tuple[FamilyGap, ...] = ()
    if preds is not None and stats is not None:
        stat_steps, statistics = statistics_goodness(lay, obs, preds, stats)
        steps += stat_steps
    nan = math.nan
    return Goodness(_systematic(v, var), math.sqrt(np.mean(floor_sq)) if len(v) else nan,
                    100 * _systematic(w, log_var), 100 * math.sqrt(np.mean(i_floor_sq)) if len(w) else nan, steps,
                    statistics)


def material(before: Any, after: Any) -> bool:
    """The practical-significance rule. Over the steps whose own gap a change of the model moves by more than
    ``FLOOR_FRACTION`` of their floor (an effect may act on part of the run only: a drift early on, a target on
    the robot), in one residual family, the change must reduce their RMS gap in units of their own floors
    (whitened, so that a quiet step counts as much as a noisy one) by at least ``MATERIAL_FRACTION`` of it and
    by at least ``FLOOR_FRACTION`` (half a floor). The families are those of ``before.steps``: every family
    of a ``Goodness`` (depth, intensity, noise, validity, correlation), the corner families of a
    ``CornerGoodness`` (labctl/reconcile/corners.py)."""
    after_steps = {(s.step_id, s.family): s for s in after.steps}
    for family in sorted({s.family for s in before.steps}):
        pairs = [(b, after_steps[(b.step_id, family)]) for b in before.steps
                 if b.family == family and (b.step_id, family) in after_steps]
        moved = [(b, a) for b, a in pairs if abs(b.gap - a.gap) > FLOOR_FRACTION * b.floor]
        if not moved:
            continue
        ratio_b = math.sqrt(np.mean([b.ratio**2 for b, _ in moved]))
        ratio_a = math.sqrt(np.mean([(a.gap / b.floor) ** 2 for b, a in moved]))
        if ratio_b - ratio_a >= max(MATERIAL_FRACTION * ratio_b, FLOOR_FRACTION):
            return True
    return False
