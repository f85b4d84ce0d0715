"""Confounds: effects whose signatures a run cannot tell apart, and the captures that would.

A depth sweep in one direction moves the distance, the run's time and the
signal together: a range error growing with the distance, a warm-up drift
settling over the run and an error following the intensity (which falls with
the distance) can all draw the same curve over its steps. What tells them
apart are the run's *separating steps*: steps at one position (the same wall
distance, or the same robot angle) that differ in something else, the time (a
position seen again later: ``depth_sweep.return_mm``, an offset calibration
and the sweep's own step at its distance), the target's remission or the
exposure. An effect that follows the distance predicts the same value at every
step of such a group; one that follows the time or the signal predicts a
difference.

Each step's mean of the whitened residual (and of a fitted signature), minus
its group's mean, is the group's *contrast*. Before an effect is named
(``check``):

* it is *contradicted* when its fitted signature predicts contrasts the
  measurement does not show: chi^2 of the measured contrasts against the
  signature's exceeds chi^2 against no effect at all by the margin, also
  when any one other candidate's contrasts, scaled to fit, stand beside both
  (``Separation.excess``: two effects hidden together make contrasts
  together), and still when the signature is the change of the candidate's
  full re-simulation at its refined parameters rather than its linearization
  (``screen``);
* it is *not separated* from a competitor on another of the axes a sweep moves
  together (``SWEEP_AXES``; every scored candidate, those below the naming
  threshold included), when the run holds no steps that separate those axes
  (``time_separated``, ``signal_separated``) and the competitor reproduces it,
  its fitted change correlating at ``REPRODUCE_CORRELATION`` or more or its fit
  removing at least ``REPRODUCE_SHARE`` of what the winner's removes, unless
  the separating steps it has favour the winner by the margin. Two effects on
  one axis, or on axes the run separates, are told apart by their scores.

The chi^2 takes a step mean of the whitened residual (a bin's residual over its
noise) as having unit variance: a step mean averages many bins, so its noise is
smaller and the test errs towards "not separated". The margin is the evidence
the candidate scores must differ by to name one over another (``MARGIN`` of
labctl/reconcile/workflow.py): both are twice a log-likelihood ratio.

The capture that would separate two effects (``separating_capture``) is one the
run does not already hold: a return to an earlier position late in the run, the
sweep in the other direction or interleaved, plates of other remission or a
second exposure at one distance, positions beyond or between the run's own
where the two predictions part most. ``plan_confounds`` says the same of a
campaign before it runs, from its planned steps.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from scipy import stats

from labctl.reconcile.candidates import SHORTEST_TAU_SEARCHED_S
from labctl.reconcile.characterize import CONFOUNDED
from labctl.reconcile.goodness import MATERIAL_FRACTION
from labctl.reconcile.observe import Observation
from labctl.reconcile.residuals import Layout
from labctl.reconcile.score import Fit
from labctl.run.config import Campaign
from labctl.run.planning import PlannedStep
from sim.effects import EFFECTS
from sim.profiles import get_profile
from sim.scenes.targets import PLATE_MATERIALS, STAGE_TARGETS

# A competitor reproduces the winner when what the winner's form adds beyond it is not material: under
# MATERIAL_FRACTION of the winner's gain (the share an effect must remove to be added, goodness.py), or its
# signature's correlation is at least sqrt(1 - MATERIAL_FRACTION) (the part of the winner's change it leaves is then
# under MATERIAL_FRACTION of its energy).
REPRODUCE_SHARE = 1.0 - MATERIAL_FRACTION
REPRODUCE_CORRELATION = math.sqrt(1.0 - MATERIAL_FRACTION)
SAME_POSITION_MM = 20.0  # two wall steps this close are one position (sweep steps are 50 mm apart or more)
# a repeat sooner than the shortest drift time constant reconcile searches cannot show a drift
MIN_REPEAT_S = SHORTEST_TAU_SEARCHED_S

#: the axis an effect's signature follows, by its declared form (``Observed.signature``)
FORM_AXES = {"warm_up": "time", "inverse_light": "signal", "proportional_range": "distance",
             "periodic_range": "distance", "periodic_disparity": "distance", "mean_phasor": "distance",
             "plane_bounce": "distance", "plane_phasor": "distance", "disparity_offset": "distance",
             "log_light_polynomial": "signal", "log_cos_alpha": "pixel", "column_row_profile": "pixel",
             "resimulated": "pixel"}
#: the axis of a ``resimulated`` effect that only some steps show (``Observed.steps``)
STEP_AXES = {"robot_plates": "angle", "translucent": "target"}
SWEEP_TARGET = "wall"  # the depth sweep's target
#: the axes a sweep moves together; effects on two of them are the common confounds
SWEEP_AXES = ("time", "distance", "signal")


@dataclass(frozen=True)
class Capture:
    """What a step holds that can separate effects: where, when, what and how it was seen."""

    step_id: str
    procedure: str
    target: str
    distance_mm: float | None  # camera-wall distance (stage steps)
    robot_angle_deg: float | None
    time_s: float  # since the run's first frame (a plan: since its start)
    exposure_us: float | None


@dataclass(frozen=True)
class Confound:
    """Why the winner of a round is not named: contradicted by the separating steps, or not separated from a
    competitor; ``capture`` is one the run does not hold that would separate them (empty when contradicted)."""

    winner: str
    competitor: str | None  # None: contradicted by the separating steps themselves
    capture: str
    reason: str


def run_captures(observations: Sequence[Observation], t0_s: float) -> list[Capture]:
    """The captures of a measured run (its compared steps), times from the run's first frame."""
    return [Capture(o.scene.step_id, o.scene.procedure, o.scene.target, o.scene.wall_distance_mm,
                    o.scene.robot_angle_deg if o.scene.reference == "robot" else None,
                    float(np.mean(o.times_s)) - t0_s if len(o.times_s) else math.nan, o.scene.exposure_us)
            for o in observations]


def plan_captures(planned: Sequence[PlannedStep]) -> list[Capture]:
    """The captures of a campaign's planned steps that reconcile could compare, timed at the middle of their
    slots (a target at the best focus at its estimated distance)."""
    out = []
    for p in planned:
        s = p.step
        if s.target not in STAGE_TARGETS and s.target not in PLATE_MATERIALS:
            continue
        distance = s.distance_mm if s.distance_from is None else p.stage_position_mm
        if s.target in STAGE_TARGETS and distance is None:
            continue
        out.append(Capture(s.step_id, s.procedure, s.target, None if s.target in PLATE_MATERIALS else distance,
                           s.robot_angle_deg, p.start_s + p.duration_s / 2, s.exposure_us))
    return out


def effect_axis(name: str) -> str | None:
    """The axis the effect's signature follows (None: an effect reconcile does not score)."""
    effect = EFFECTS.get(name)
    if effect is None or effect.observed is None or effect.observed.signature is None:
        return None
    return STEP_AXES.get(effect.observed.steps) or FORM_AXES.get(effect.observed.signature)


def confounded(a: str, b: str, captures: Sequence[Capture]) -> bool:
    """Whether effects ``a`` and ``b`` follow two of the axes a sweep moves together (time, distance, signal)
    and the run holds no steps that separate those axes (``time_separated``, ``signal_separated``)."""
    axes = {effect_axis(a), effect_axis(b)}
    if len(axes) != 2 or not axes <= set(SWEEP_AXES):
        return False
    return (time_separated(captures) if "time" in axes else signal_separated(captures)) is None


def position_groups(captures: Sequence[Capture]) -> list[list[int]]:
    """Indices of captures at one position (the same robot angle, or wall distances within
    ``SAME_POSITION_MM``), groups of two or more."""
    groups: list[list[int]] = []
    keyed = sorted((i for i, c in enumerate(captures) if c.distance_mm is not None or c.robot_angle_deg is not None),
                   key=lambda i: (captures[i].robot_angle_deg is None, captures[i].robot_angle_deg or 0.0,
                                  captures[i].distance_mm or 0.0))
    for i in keyed:
        c = captures[i]
        if groups:
            first = captures[groups[-1][0]]
            same = (c.robot_angle_deg == first.robot_angle_deg if c.robot_angle_deg is not None
                    else first.robot_angle_deg is None and abs(c.distance_mm - first.distance_mm) <= SAME_POSITION_MM)
            if same:
                groups[-1].append(i)
                continue
        groups.append([i])
    return [g for g in groups if len(g) > 1]


def time_repeats(captures: Sequence[Capture]) -> list[tuple[Capture, Capture]]:
    """Pairs (first, later) of captures of one target at one position and exposure, at least ``MIN_REPEAT_S``
    apart."""
    pairs = []
    for group in position_groups(captures):
        for a in group:
            for b in group:
                ca, cb = captures[a], captures[b]
                if (ca.target == cb.target and ca.exposure_us == cb.exposure_us
                        and cb.time_s - ca.time_s >= MIN_REPEAT_S):
                    pairs.append((ca, cb))
    return pairs


def signal_groups(captures: Sequence[Capture]) -> list[list[Capture]]:
    """Groups of captures at one position that differ in target or exposure (the signal changes, the distance
    does not)."""
    out = []
    for group in position_groups(captures):
        kinds = {(captures[i].target, captures[i].exposure_us) for i in group}
        if len(kinds) > 1:
            out.append([captures[i] for i in group])
    return out


def _walls(captures: Sequence[Capture]) -> list[Capture]:
    """The captures of the run's sweep, in time order: its wall steps, or without any, those of its most
    frequent stage target."""
    stage = [c for c in captures if c.distance_mm is not None and math.isfinite(c.time_s)]
    if not stage:
        return []
    targets = [c.target for c in stage]
    main = SWEEP_TARGET if SWEEP_TARGET in targets else max(dict.fromkeys(targets), key=targets.count)
    return sorted((c for c in stage if c.target == main), key=lambda c: c.time_s)


def _follows_time(walls: Sequence[Capture]) -> float | None:
    """Spearman's rho of the sweep's distances against its times (None: fewer than three positions); the
    sweep's own procedure only, so that one step before it (an offset calibration) does not break the tie."""
    procedures = [c.procedure for c in walls]
    sweep = [c for c in walls if c.procedure == max(dict.fromkeys(procedures), key=procedures.count)]
    if len({round(c.distance_mm) for c in sweep}) < 3:
        return None
    return float(stats.spearmanr([c.time_s for c in sweep], [c.distance_mm for c in sweep]).statistic)


def _late_repeat(walls: Sequence[Capture], after_s: float) -> tuple[Capture, Capture] | None:
    """The longest-separated pair of the sweep's captures at one position, if at least ``after_s`` apart."""
    pairs = [(a, b) for a, b in time_repeats(walls) if b.time_s - a.time_s >= after_s]
    return max(pairs, key=lambda p: p[1].time_s - p[0].time_s) if pairs else None


def time_separated(captures: Sequence[Capture]) -> str | None:
    """How the run tells the time from the distance (None: it cannot): a sweep position seen again at least
    half the sweep's time span later, or sweep distances that do not follow the time (|Spearman rho| below
    ``CONFOUNDED``, as the characterization's confounded axes). The sweep is one target's captures (``_walls``):
    another target changes the signal as well."""
    walls = _walls(captures)
    if not walls:
        return None
    repeat = _late_repeat(walls, max(MIN_REPEAT_S, (walls[-1].time_s - walls[0].time_s) / 2))
    if repeat is not None:
        a, b = repeat
        return f"the {a.distance_mm:.0f} mm position is seen again {b.time_s - a.time_s:.0f} s later ({b.step_id})"
    rho = _follows_time(walls)
    if rho is not None and abs(rho) < CONFOUNDED:
        return f"the {walls[0].target} distances do not follow the time (Spearman rho {rho:.2f})"
    return None


def signal_separated(captures: Sequence[Capture]) -> str | None:
    """How the run tells the signal from the distance (None: it cannot): other targets or exposures at one
    position."""
    groups = signal_groups(captures)
    if not groups:
        return None
    g = groups[0]
    where = f"{g[0].distance_mm:.0f} mm" if g[0].distance_mm is not None else f"{g[0].robot_angle_deg:g} deg"
    what = sorted({c.target for c in g})
    exposures = sorted({c.exposure_us for c in g if c.exposure_us is not None})
    return (f"{', '.join(what)} at {where}" + (f", exposures {', '.join(f'{e:g}' for e in exposures)} us"
                                              if len(exposures) > 1 else ""))


def _time_capture(captures: Sequence[Capture], after_s: float | None = None) -> str:
    """A capture that tells the time from the distance and that the run does not hold."""
    walls = _walls(captures)
    ref = walls[0].distance_mm if walls else 2000.0
    span = walls[-1].time_s - walls[0].time_s if walls else 0.0
    wait = max(after_s or 0.0, span / 2, MIN_REPEAT_S)
    if _late_repeat(walls, wait) is None:
        return (f"the {ref:.0f} mm position again at least {wait:.0f} s after it was first seen (a depth_sweep's "
                f"return_mm = {ref:.0f}: the same distance and signal, another time)")
    rho = _follows_time(walls)
    if rho is not None and abs(rho) >= CONFOUNDED:
        return ('the depth sweep interleaved (order = "interleaved": every other position on the way out, '
                "the rest on the way back), so that near and far positions are each seen early and late")
    return (f"a second run started with the camera already warm (after running for {max(wait, span):.0f} s): "
            "the same positions, another state of the warm-up")


def _signal_capture(captures: Sequence[Capture]) -> str:
    """A capture that tells the signal from the distance and that the run does not hold."""
    groups = signal_groups(captures)
    walls = _walls(captures)
    ref = walls[0].distance_mm if walls else 2000.0
    if not any(len({c.target for c in g}) > 1 for g in groups):
        return ("plates of different remission at one distance (remission_angle with ptfe and molleton: the "
                "same distance, another signal)")
    if not any(len({c.exposure_us for c in g}) > 1 for g in groups):
        return f"the {ref:.0f} mm wall at a second exposure (exposure_us half the first): another signal, one distance"
    return f"the {ref:.0f} mm wall at more exposures, spanning a decade of signal"


def _form_capture(steps_apart: np.ndarray, captures: Sequence[Capture]) -> str:
    """Positions the run does not hold, where two effects on one axis part most (``steps_apart``: how much
    their predictions differ at each capture)."""
    s = int(np.argmax(steps_apart))
    c = captures[s]
    if c.distance_mm is None:
        where = f"{c.robot_angle_deg:g} deg" if c.robot_angle_deg is not None else c.step_id
        return f"more {c.procedure} captures around {where} ({c.target}), where their predictions part most"
    distances = sorted({round(w.distance_mm) for w in _walls(captures)})
    d = round(c.distance_mm)
    if d <= distances[0]:
        return f"wall positions nearer than {d} mm (the run's nearest), where their predictions part most"
    if d >= distances[-1]:
        return f"wall positions beyond {d} mm (the run's farthest), where their predictions part most"
    i = distances.index(min(distances, key=lambda v: abs(v - d)))
    lo, hi = distances[max(i - 1, 0)], distances[min(i + 1, len(distances) - 1)]
    return (f"wall positions between {lo} and {hi} mm at half the run's spacing (new positions: "
            f"{(lo + d) / 2:.0f}, {(d + hi) / 2:.0f} mm), where their predictions part most")


def separating_capture(a: str, b: str, captures: Sequence[Capture], steps_apart: np.ndarray | None = None) -> str:
    """A capture the run does not hold that would tell effect ``a`` from ``b`` (by the axes they follow)."""
    axes = {effect_axis(a), effect_axis(b)}
    if "time" in axes and len(axes) > 1:
        return _time_capture(captures)
    if axes == {"signal", "distance"}:
        return _signal_capture(captures)
    if steps_apart is not None and len(steps_apart) == len(captures) and len(captures):
        return _form_capture(steps_apart, captures)
    return "more steps of the procedures where the two effects' predictions part most"


@dataclass(frozen=True)
class Holdings:
    """What a run's ``captures`` already hold, as an effect's capture hint asks it (``sim.effects.RunHoldings``)."""

    captures: Sequence[Capture]

    @property
    def first_position(self) -> str:
        walls = _walls(self.captures)
        return f"{walls[0].distance_mm:.0f} mm" if walls else "first"

    def repeated_after(self, seconds: float) -> bool:
        return any(b.time_s - a.time_s >= seconds for a, b in time_repeats(self.captures))

    def early_stacks(self, within_s: float) -> int:
        walls = _walls(self.captures)
        if not walls:
            return 0
        first = walls[0]
        return sum(c.time_s <= first.time_s + within_s and abs(c.distance_mm - first.distance_mm) <= SAME_POSITION_MM
                   for c in walls)

    def time_capture(self, after_s: float) -> str:
        return _time_capture(self.captures, after_s)


# --------------------------------------------------------------------------- the check before naming
def _contrasts(x: np.ndarray, cells: np.ndarray, n_cells: int, groups: list[list[int]], n_steps: int) -> np.ndarray:
    """Per group and family, each step's mean of ``x`` minus the group's mean of those step means."""
    count = np.bincount(cells, minlength=n_cells)
    with np.errstate(invalid="ignore", divide="ignore"):
        means = np.bincount(cells, x, n_cells) / count
    out = []
    for family in (0, 1):
        for group in groups:
            cell = [s + family * n_steps for s in group if count[s + family * n_steps] > 0]
            if len(cell) > 1:
                m = means[cell]
                out.append(m - m.mean())
    return np.concatenate(out) if out else np.zeros(0)


class Separation:
    """The run's separating steps and the contrasts of the whitened residual over them."""

    def __init__(self, lay: Layout, captures: Sequence[Capture], r: np.ndarray) -> None:
        self.captures = list(captures)
        self.lay = lay
        self.groups = position_groups(captures)
        steps = lay.row_steps()
        n_z = len(lay.z_step)
        self.cells = steps + np.where(np.arange(len(steps)) >= n_z, lay.n_steps, 0)  # (step, family)
        self.measured = self.contrast(r)

    def contrast(self, x: np.ndarray) -> np.ndarray:
        return _contrasts(x, self.cells, 2 * self.lay.n_steps, self.groups, self.lay.n_steps)

    def chi2(self, fit: Fit) -> float:
        """chi^2 of the measured contrasts against those ``fit`` predicts (unit variance per step mean)."""
        d = self.measured - self.contrast(fit.signature)
        return float(d @ d)

    def excess(self, best: Fit, others: Sequence[Fit]) -> float:
        """How much worse the measured contrasts fit with ``best``'s than with no effect (chi^2), where any one of
        ``others`` may act beside it: its contrasts, at the non-negative scale that fits them best, taken out with
        and without ``best``'s. Effects hidden together make contrasts together (a material bias and a multipath at
        the plates of one robot angle), and one of them alone can fit them worse than nothing although it is
        there; ``best`` is contradicted only when no other effect of the library makes up the difference."""
        m = self.measured
        rest = m - self.contrast(best.signature)
        excess = float(rest @ rest - m @ m)
        for other in others:
            if other.name == best.name:
                continue
            c = self.contrast(other.signature)
            norm = float(c @ c)
            if norm <= 0:
                continue
            with_best = rest - max(float(rest @ c) / norm, 0.0) * c
            without = m - max(float(m @ c) / norm, 0.0) * c
            excess = min(excess, float(with_best @ with_best - without @ without))
        return excess

    def steps_apart(self, a: Fit, b: Fit) -> np.ndarray:
        """How much two fitted changes differ at each step (sum of squares over its rows)."""
        return np.bincount(self.lay.row_steps(), (a.signature - b.signature) ** 2, self.lay.n_steps)


def reproduces(best: Fit, other: Fit) -> bool:
    """Whether ``other`` can stand for ``best`` on this run: its fitted change correlates with the winner's at
    ``REPRODUCE_CORRELATION`` or it removes ``REPRODUCE_SHARE`` of what the winner removes."""
    norm = float(np.linalg.norm(best.signature) * np.linalg.norm(other.signature))
    correlation = abs(float(best.signature @ other.signature)) / norm if norm > 0 else 0.0
    gain_best, gain_other = best.rss0 - best.rss1, other.rss0 - other.rss1
    return correlation >= REPRODUCE_CORRELATION or (gain_best > 0 and gain_other >= REPRODUCE_SHARE * gain_best)


def check(best: Fit, others: Sequence[Fit], separation: Separation, margin: float) -> Confound | None:
    """Why ``best`` must not be named on this run (None: its signature is told apart from every other
    candidate's by the run's steps); ``margin``: the evidence one candidate must lead another by."""
    captures = separation.captures
    if separation.measured.size:
        excess = separation.excess(best, others)
        if excess >= margin:
            return Confound(best.name, None, "",
                            f"{best.name} predicts differences between steps at one position that the measurement "
                            f"does not show (chi^2 {excess:.1f} above no effect at all, any one other effect "
                            f"allowed beside either, over {len(separation.groups)} position(s) seen more than once)")
    unresolved = []
    for other in others:
        if other.name == best.name or not confounded(best.name, other.name, captures) or not reproduces(best, other):
            continue
        evidence = separation.chi2(other) - separation.chi2(best) if separation.measured.size else 0.0
        if evidence < margin:
            unresolved.append((other.rss0 - other.rss1, other, evidence))
    if not unresolved:
        return None
    _, other, evidence = max(unresolved, key=lambda u: u[0])
    capture = separating_capture(best.name, other.name, captures, separation.steps_apart(best, other))
    return Confound(best.name, other.name, capture,
                    f"{other.name} reproduces {best.name}'s change on this run and its steps at a repeated position "
                    f"do not tell them apart (evidence {evidence:.1f}, needed {margin:g})")


def screen(fits: Sequence[Fit], separation: Separation, threshold: float, margin: float,
           resimulated: Callable[[Fit], Fit | None] | None = None) -> tuple[list[Confound], Confound | None]:
    """The candidates best first: those the separating steps contradict (not to be named), and why the first
    one above ``threshold`` that they do not contradict must not be named either (None: it may be).

    A candidate's signature is its linear change, taken at a small strength; where that is contradicted, the
    contradiction is judged again on the change its full re-simulation makes (``resimulated``: the fit with that
    signature, None where there is none), since an effect that is not linear in its strength (a multipath on
    weak returns) can predict contrasts at one strength that it does not make at its fitted one."""
    contradicted = []
    for fit in fits:
        if fit.score < threshold or fit.loso_gain <= 0:
            break
        others = [f for f in fits if f.name not in {c.winner for c in contradicted}]
        confound = check(fit, others, separation, margin)
        if confound is not None and confound.competitor is None and resimulated is not None:
            full = resimulated(fit)
            if full is not None:
                confound = check(full, others, separation, margin)
        if confound is None or confound.competitor is not None:
            return contradicted, confound
        contradicted.append(confound)
    return contradicted, None


# --------------------------------------------------------------------------- a campaign, before it runs
@dataclass(frozen=True)
class PairReport:
    """Two axes' effects, and whether the campaign tells them apart (how, or the capture that would)."""

    axes: tuple[str, str]
    effects: tuple[list[str], list[str]]
    separated: bool
    how: str  # how the campaign separates them, or the capture that would


def campaign_confounds(campaign: Campaign, planned: Sequence[PlannedStep]) -> list[PairReport]:
    """``plan_confounds`` of a campaign's planned steps, for the effects of its camera's technology."""
    return plan_confounds(plan_captures(planned), get_profile(campaign.devices.camera.sim_profile).technology)


def plan_confounds(captures: Sequence[Capture], technology: str) -> list[PairReport]:
    """For each pair of the axes a sweep moves together (time, distance, signal), with the camera's effects on
    each: whether the planned captures tell them apart."""
    by_axis: dict[str, list[str]] = {}
    for name, effect in EFFECTS.items():
        axis = effect_axis(name)
        if axis in SWEEP_AXES and technology in effect.technologies:
            by_axis.setdefault(axis, []).append(name)
    reports = []
    for i, a in enumerate(SWEEP_AXES):
        for b in SWEEP_AXES[i + 1:]:
            if a not in by_axis or b not in by_axis:
                continue
            if "time" in (a, b):
                how = time_separated(captures)
                need = _time_capture(captures)
            else:
                how = signal_separated(captures)
                need = _signal_capture(captures)
            reports.append(PairReport((a, b), (sorted(by_axis[a]), sorted(by_axis[b])), how is not None,
                                      how or need))
    return reports
