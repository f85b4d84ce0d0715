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

A residual is **consistent with noise** when the run's gap is at most its
floor and no step's gap exceeds ``STEP_FACTOR`` times that step's floor, in
both families: a systematic residual smaller than the random scatter of a
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

from labctl.reconcile.observe import Observation
from labctl.reconcile.residuals import LOG_I_FLOOR, LOG_I_FLOOR_PROJECTOR, Z_FLOOR_MM, Layout
from labctl.reconcile.results import GoodnessSummary, StepAboveFloor

# The fixed thresholds (``--null-runs 0``; with null runs, labctl/reconcile/null.py, the replicas' distributions decide)
REFERENCE_NOISE_MM = 0.15  # one distance reading per stage step (the laser meter's repeatability), set on the test campaign
STEP_FACTOR = 3.0  # twice the largest step ratio of 200 null runs of the test campaign (1.50, docs/reconcile.md)
MATERIAL_FRACTION = 0.2  # an effect must remove at least this share of a family's gap (set by hand) ...
FLOOR_FRACTION = 0.5  # ... and at least this multiple of that family's noise floor (set by hand: half a floor)


@dataclass(frozen=True)
class StepFit:
    """One step's systematic residual against its noise floor, in one family."""

    step_id: str
    family: str  # "depth" (mm) or "intensity" (%)
    gap: float
    floor: float

    @property
    def ratio(self) -> float:
        return self.gap / self.floor if self.floor > 0 else math.inf


@dataclass(frozen=True)
class Goodness:
    """The residual of one model against the noise: run gaps, their floors, per-step detail, the verdict."""

    gap_mm: float
    gap_floor_mm: float
    intensity_gap_pct: float
    intensity_gap_floor_pct: float
    steps: list[StepFit]

    @property
    def worst_step(self) -> StepFit | None:
        return max(self.steps, key=lambda s: s.ratio, default=None)

    @property
    def depth_consistent(self) -> bool:
        return (not math.isfinite(self.gap_mm) or self.gap_mm <= self.gap_floor_mm) and all(
            s.ratio <= STEP_FACTOR for s in self.steps if s.family == "depth")

    @property
    def intensity_consistent(self) -> bool:
        return (not math.isfinite(self.intensity_gap_pct) or self.intensity_gap_pct <= self.intensity_gap_floor_pct) \
            and all(s.ratio <= STEP_FACTOR for s in self.steps if s.family == "intensity")

    @property
    def consistent(self) -> bool:
        return self.depth_consistent and self.intensity_consistent

    def summary(self) -> GoodnessSummary:
        """The record reconcile.json gives: gaps, floors, consistency, and the steps furthest above their floors."""
        return GoodnessSummary(
            gap=rounded(self.gap_mm), gap_floor=rounded(self.gap_floor_mm), intensity_gap=rounded(self.intensity_gap_pct),
            intensity_gap_floor=rounded(self.intensity_gap_floor_pct), consistent_with_noise=self.consistent,
            depth_consistent=self.depth_consistent, intensity_consistent=self.intensity_consistent,
            step_factor=STEP_FACTOR, steps_above_floor=steps_above_floor(self.steps))


def rounded(value: float) -> float | None:
    """``value`` to 4 decimals, None where it is not finite (a gap or floor as reconcile.json gives it)."""
    return round(float(value), 4) if math.isfinite(value) else None


def steps_above_floor(steps: list[StepFit]) -> list[StepAboveFloor]:
    """Of the five steps furthest above their floors, those above (gap over floor > 1), furthest first."""
    worst = sorted(steps, key=lambda s: -s.ratio)[:5]
    return [StepAboveFloor(step=s.step_id, family=s.family, gap=rounded(s.gap), floor=rounded(s.floor),
                           ratio=rounded(s.ratio)) for s in worst if s.ratio > 1.0]


def _systematic(v: np.ndarray, var: np.ndarray) -> float:
    return float(np.sqrt(max(0.0, float(np.mean(v * v - var))))) if len(v) else math.nan


def depth_floor_sq(lay: Layout, obs: list[Observation]) -> np.ndarray:
    """Every depth row's floor^2 (mm^2): its bin mean's variance, the simulator's floor, the reference's noise."""
    var = lay.stack_z([o.z_var for o in obs])
    stage = np.array([o.scene.reference != "robot" for o in obs], bool)[lay.z_step] if len(obs) else np.zeros(0, bool)
    return var + Z_FLOOR_MM**2 + np.where(stage, REFERENCE_NOISE_MM**2, 0.0)


def goodness(lay: Layout, obs: list[Observation], dz: list[np.ndarray], di: list[np.ndarray],
             technology: str) -> Goodness:
    """The goodness of fit of the residual maps ``dz``, ``di`` (``residuals.raw_residuals``)."""
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
            steps.append(StepFit(o.scene.step_id, "depth", _systematic(v[m], var[m]), math.sqrt(np.mean(floor_sq[m]))))
        m = lay.i_step == s
        if m.sum() >= 2:
            steps.append(StepFit(o.scene.step_id, "intensity", 100 * _systematic(w[m], log_var[m]),
                                 100 * math.sqrt(np.mean(i_floor_sq[m]))))
    nan = math.nan
    return Goodness(_systematic(v, var), math.sqrt(np.mean(floor_sq)) if len(v) else nan,
                    100 * _systematic(w, log_var), 100 * math.sqrt(np.mean(i_floor_sq)) if len(w) else nan, steps)


def material(before: Any, after: Any) -> bool:
    """The practical-significance rule. Over the steps whose own gap a change of the model moves by more than
    ``FLOOR_FRACTION`` of their floor (an effect may act on part of the run only: a drift early on, a target on
    the robot), in one residual family, the change must reduce their RMS gap in units of their own floors
    (whitened, so that a quiet step counts as much as a noisy one) by at least ``MATERIAL_FRACTION`` of it and
    by at least ``FLOOR_FRACTION`` (half a floor). The families are those of ``before.steps``: depth and
    intensity of a ``Goodness``, the corner families of a ``CornerGoodness`` (labctl/reconcile/corners.py)."""
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
