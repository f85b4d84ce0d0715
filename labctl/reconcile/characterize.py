"""What a residual that no library effect explains follows: its axes, their effect sizes, its map and curve.

The residual is the per-step, per-bin depth residual of the final model with
the lab's nuisance removed (``goodness.depth_residual_maps``). Every axis a lab
varies or a sensor has is tried:

* per bin: ``distance`` (the bin's range along its ray as simulated, mm;
  stereo: its depth), ``disparity`` (1000 / z, the simulated depth's inverse
  in 1/m: a stereo camera's disparity up to its focal length times baseline,
  so that an error constant in disparity, growing with z^2, is a straight
  line on it), pixel ``row``,
  ``column`` and ``radius`` (bin centre, 0 ... 1 of the half diagonal) and
  ``intensity`` (the measured bin mean, log-spaced groups);
* per step: ``time`` (mean frame time since the run's first frame, s),
  ``exposure`` (the step's exposure time, us, where the run records one),
  ``robot_angle`` (deg, robot steps only) and ``target`` (the target or
  material, categorical).

Each axis's values are grouped (``GROUPS`` groups of equal width between the
smallest and largest value, or one group per category) and the residual's group means form the axis's curve. The share of
the residual's variance the axis carries is the correlation ratio

    eta^2 = sum_g n_g (m_g - m)^2 / sum_i (r_i - m)^2          (Pearson 1905)

(sums weighted by each bin's inverse noise variance, so that precise steps
count for more than noisy ones) and its effect size the peak-to-peak of the
curve (mm). The carrying axis
is the one with the largest eta^2; axes whose values are strongly
correlated with it over the compared bins (|Spearman rho| >= ``CONFOUNDED``,
e.g. distance and time in a sweep run in one direction) are listed as
confounded with it, since the run cannot tell them apart (distance and
disparity are one axis on two scales, always in rank order, and are not said
to be confounded with each other). For the pixel
axes, ``same_at_every_distance`` is the correlation of the curve from the
nearer half of the steps with the curve from the farther half (1: a fixed
pattern; near 0: it changes with distance).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import stats

from labctl.reconcile.observe import Observation
from labctl.reconcile.predict import Prediction
from labctl.reconcile.residuals import Z_FLOOR_MM
from labctl.reconcile.results import (
    AxisSummary,
    Confounded,
    CurvePoint,
    DepartureAtEnds,
    DepartureFactor,
    FamilyDeparture,
    StatisticsAxis,
    StatisticsCurvePoint,
    Unexplained,
    ValidityDeparture,
)

GROUPS = 24  # set by hand: more groups than the 19 distances of a 0.4-4 m sweep in 200 mm steps, so each has its own
CONFOUNDED = 0.8  # set by hand: |rho| of two axes a run cannot tell apart (1 for distance and time in a one-way sweep)
MIN_ETA2 = 0.1  # below this share no axis is said to carry the residual
PIXEL_AXES = ("row", "column", "radius")
SAME_AXIS = {"distance", "disparity"}


@dataclass(frozen=True)
class AxisFit:
    """An axis the residual was tried against: its share of the residual (eta^2), the curve's peak to peak (mm),
    the curve, and (pixel axes) the correlation of its near and far halves' curves."""

    name: str
    unit: str
    eta2: float
    effect_mm: float
    curve: list[CurvePoint]
    same_at_every_distance: float | None = None

    def summary(self) -> AxisSummary:
        """The axis as reconcile.json lists it (rounded)."""
        return AxisSummary(axis=self.name, unit=self.unit, eta2=round(float(self.eta2), 4),
                           effect_mm=round(self.effect_mm, 4), same_at_every_distance=self.same_at_every_distance)


def _axes(observations: list[Observation], predictions: list[Prediction], maps: list[np.ndarray],
          t0_s: float) -> dict[str, tuple[str, list]]:
    """Per axis: unit and, per step, the axis value of every bin (an (h, w) array, or a scalar/str per step)."""
    h, w = maps[0].shape
    row, col = np.mgrid[0:h, 0:w].astype(float)
    radius = np.hypot(col - (w - 1) / 2, row - (h - 1) / 2) / math.hypot(w / 2, h / 2)
    out: dict[str, tuple[str, list]] = {
        "distance": ("mm", [p.range_mm for p in predictions]),
        "disparity": ("1/m", [np.where(p.z > 0, 1000.0 / np.where(p.z > 0, p.z, 1.0), np.nan) for p in predictions]),
        "row": ("bin", [row] * len(maps)), "column": ("bin", [col] * len(maps)),
        "radius": ("of the half diagonal", [radius] * len(maps)),
        "intensity": ("log10 of the bin mean", [np.log10(np.where(o.intensity > 0, o.intensity, np.nan))
                                                for o in observations]),
        "time": ("s", [float(np.mean(o.times_s)) - t0_s if len(o.times_s) else math.nan for o in observations]),
        "exposure": ("us", [o.scene.exposure_us if o.scene.exposure_us is not None else math.nan
                            for o in observations]),
        "robot_angle": ("deg", [o.scene.robot_angle_deg if o.scene.reference == "robot" else math.nan
                                for o in observations]),
        "target": ("", [o.scene.target for o in observations]),
    }
    return out


def _stack(values: list, maps: list[np.ndarray]) -> np.ndarray:
    """An axis's value of every compared bin, in the order of ``np.concatenate([m[ok] for m in maps])``."""
    parts = []
    for v, m in zip(values, maps, strict=True):
        ok = np.isfinite(m)
        parts.append(np.asarray(v)[ok] if np.ndim(v) == 2 else np.full(int(ok.sum()), v, dtype=object))
    return np.concatenate(parts) if parts else np.zeros(0)


def _groups(x: np.ndarray) -> tuple[np.ndarray, list[str] | list[float]]:
    """Group index per value (quantile groups for numbers, one per category) and each group's label."""
    if x.dtype == object and len(x) and isinstance(x[0], str):
        labels = sorted(set(x.tolist()))
        return np.array([labels.index(v) for v in x]), labels
    x = x.astype(float)
    edges = np.linspace(float(x.min()), float(x.max()), GROUPS + 1)
    idx = np.clip(np.searchsorted(edges, x, side="right") - 1, 0, GROUPS - 1)
    centres = [float(np.mean(x[idx == g])) if np.any(idx == g) else math.nan for g in range(GROUPS)]
    return idx, centres


def _curve(v: np.ndarray, x: np.ndarray, wt: np.ndarray) -> tuple[float, float, list[CurvePoint], np.ndarray]:
    idx, labels = _groups(x)
    n = np.bincount(idx, minlength=len(labels)).astype(float)
    wsum = np.bincount(idx, wt, len(labels))
    means = np.bincount(idx, wt * v, len(labels)) / np.maximum(wsum, 1e-300)
    mean = float(np.sum(wt * v) / np.sum(wt))
    total = float(np.sum(wt * (v - mean) ** 2))
    eta2 = float(np.sum(wsum * (means - mean) ** 2) / total) if total > 0 else 0.0
    used = n > 0
    curve = [CurvePoint(x=lab if isinstance(lab, str) else round(lab, 4), mean_mm=round(float(m), 4), n=int(k))
             for lab, m, k, u in zip(labels, means, n, used, strict=True) if u]
    return eta2, float(np.ptp(means[used])) if used.any() else 0.0, curve, means[idx]


def characterize(observations: list[Observation], predictions: list[Prediction], maps: list[np.ndarray],
                 t0_s: float) -> Unexplained:
    """The axes the residual maps follow (sorted by eta^2), the carrying axis, its curve, and the mean map."""
    if not maps or not any(np.isfinite(m).any() for m in maps):
        return Unexplained(axes=[], carrying_axis=None, spatial_map_mm=[], description="no compared bins")
    v = np.concatenate([m[np.isfinite(m)] for m in maps])
    weight = 1.0 / _stack([o.z_var + Z_FLOOR_MM**2 for o in observations], maps).astype(float)
    distance = np.array([o.scene.wall_distance_mm if o.scene.wall_distance_mm is not None
                         else float(np.nanmedian(o.z)) for o in observations])
    near = distance <= np.nanmedian(distance)
    fits: list[AxisFit] = []
    values: dict[str, np.ndarray] = {}
    for name, (unit, per_step) in _axes(observations, predictions, maps, t0_s).items():
        x = _stack(per_step, maps)
        ok = np.array([isinstance(a, str) for a in x]) if name == "target" else np.isfinite(x.astype(float))
        if ok.sum() < 2 or len(set(x[ok].tolist() if name == "target" else np.round(x[ok].astype(float), 6))) < 2:
            continue
        eta2, size, curve, _ = _curve(v[ok], x[ok], weight[ok])
        eta2 *= float(weight[ok].sum() / weight.sum())  # an axis defined on part of the bins carries at most that part
        steady = None
        if name in PIXEL_AXES:
            parts = []
            for half in (True, False):
                sel = [i for i, s in enumerate(near) if s == half]
                sub = [maps[i] for i in sel]
                parts.append((np.concatenate([m[np.isfinite(m)] for m in sub] or [np.zeros(0)]),
                              _stack([per_step[i] for i in sel], sub).astype(float),
                              _stack([observations[i].z_var + Z_FLOOR_MM**2 for i in sel], sub).astype(float)))
            if all(len(h) > GROUPS for h, _, _ in parts):
                a = [_curve(h, xx, 1.0 / var)[2] for h, xx, var in parts]
                ca, cb = ([c.mean_mm for c in k] for k in a)
                if len(ca) == len(cb) and len(ca) > 2 and np.std(ca) > 0 and np.std(cb) > 0:
                    steady = round(float(np.corrcoef(ca, cb)[0, 1]), 3)
        fits.append(AxisFit(name, unit, eta2, size, curve, steady))
        values[name] = x
    fits.sort(key=lambda f: -f.eta2)
    carrying = fits[0] if fits and fits[0].eta2 >= MIN_ETA2 else None
    confounded: list[Confounded] = []
    if carrying is not None and carrying.name != "target":
        xc = values[carrying.name].astype(float)
        for f in fits[1:]:
            if f.name == "target" or {f.name, carrying.name} == SAME_AXIS:
                continue
            x = values[f.name].astype(float)
            ok = np.isfinite(xc) & np.isfinite(x)
            if ok.sum() > 2 and np.std(x[ok]) > 0 and np.std(xc[ok]) > 0:
                rho = stats.spearmanr(xc[ok], x[ok]).statistic
                if abs(rho) >= CONFOUNDED:
                    confounded.append(Confounded(axis=f.name, spearman_rho=round(float(rho), 3)))
    stack = np.stack(maps)
    count = np.isfinite(stack).sum(axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean_map = np.where(count > 0, np.nansum(stack, axis=0) / count, np.nan)
    return Unexplained(
        axes=[f.summary() for f in fits],
        carrying_axis=carrying.name if carrying else None,
        confounded_with=confounded,
        curve=carrying.curve if carrying else [],
        spatial_map_mm=[[None if not math.isfinite(x) else round(float(x), 3) for x in r] for r in mean_map],
        description=describe(carrying, confounded),
    )


def describe(carrying: AxisFit | None, confounded: list[Confounded]) -> str:
    """One sentence a user reads: what the residual follows and how large it is."""
    if carrying is None:
        return f"no single axis carries the residual (every axis's eta^2 < {MIN_ETA2})"
    what = {"distance": "a curve over the camera-target distance", "time": "a change over the run's time",
            "disparity": "a curve over the inverse depth (disparity)", "exposure": "a function of the exposure time",
            "row": "a pattern over the pixel rows", "column": "a pattern over the pixel columns",
            "radius": "a pattern over the distance from the image centre", "intensity": "a function of the intensity",
            "robot_angle": "a function of the robot angle", "target": "a difference between targets"}[carrying.name]
    text = f"{what}, {carrying.effect_mm:.2f} mm peak to peak, carrying {100 * carrying.eta2:.0f} % of the residual"
    if carrying.same_at_every_distance is not None:
        text += ("; the same at every distance" if carrying.same_at_every_distance >= 0.8
                 else "; it changes with distance")
    if confounded:
        text += "; this run cannot tell it from " + ", ".join(c.axis for c in confounded)
    return text


#: what each statistics family compares, for the sentence a user reads
FAMILY_WORDS = {"noise": "temporal noise", "validity": "valid pixels", "correlation": "noise correlation between "
                "neighbouring pixels (variance of a bin mean over the per-pixel variance / n)"}


def _region(curve: list[CurvePoint], unit: str, values: np.ndarray) -> str:
    """Where along a numeric axis the curve departs most: its groups beyond half the largest departure."""
    means = np.array([c.mean_mm for c in curve])
    xs = [c.x for c in curve]
    big = np.abs(means) >= 0.5 * np.max(np.abs(means))
    lo, hi = min(x for x, b in zip(xs, big) if b), max(x for x, b in zip(xs, big) if b)
    scale, shown = (1000.0, "m") if unit == "mm" else (1.0, unit)
    if hi >= xs[-1] and lo > xs[0]:
        return f"beyond {lo / scale:.1f} {shown}"
    if lo <= xs[0] and hi < xs[-1]:
        return f"below {hi / scale:.1f} {shown}"
    if lo <= xs[0] and hi >= xs[-1]:
        return "at every distance" if unit == "mm" else "everywhere"
    return f"between {lo / scale:.1f} and {hi / scale:.1f} {shown}"


def _changes_sign(curve: list[CurvePoint]) -> bool:
    """Whether a curve departs to both sides by at least a quarter of its largest departure."""
    means = np.array([c.mean_mm for c in curve])
    big = 0.25 * np.max(np.abs(means))
    return bool(np.any(means > big) and np.any(means < -big))


def _size(family: str, value: float) -> str:
    """A departure as the user reads it: a factor on the model's (log ratios) or percentage points (validity)."""
    if family == "validity":
        return f"{100 * abs(value):.0f} percentage points {'below' if value < 0 else 'above'} the model's"
    return f"{math.exp(value):.2f}x the model's"


def describe_statistics(family: str, observations: list[Observation], predictions: list[Prediction],
                        maps: list[np.ndarray], weights: list[np.ndarray], t0_s: float) -> FamilyDeparture:
    """What a statistics family's residual (per-step maps, NaN outside the compared bins; ``weights`` their
    inverse variances) follows: the carrying axis and the region of it where the residual departs most, the
    departure as a factor (noise, correlation: the log ratio's weighted mean, exponentiated) or relative
    change (validity: measured over predicted valid pixels there), and a sentence."""
    v = np.concatenate([m[np.isfinite(m)] for m in maps]) if maps else np.zeros(0)
    if not len(v):
        return FamilyDeparture(family=family, carrying_axis=None, description=f"{FAMILY_WORDS[family]}: no compared bins")
    weight = _stack(weights, maps).astype(float)
    fits: list[AxisFit] = []
    values: dict[str, np.ndarray] = {}
    for name, (unit, per_step) in _axes(observations, predictions, maps, t0_s).items():
        if name in ("target", "intensity"):
            continue
        x = _stack(per_step, maps).astype(float)
        ok = np.isfinite(x)
        if ok.sum() < 2 or len(np.unique(np.round(x[ok], 6))) < 2:
            continue
        eta2, size, curve, _ = _curve(v[ok], x[ok], weight[ok])
        fits.append(AxisFit(name, unit, eta2 * float(weight[ok].sum() / weight.sum()), size, curve))
        values[name] = x
    fits.sort(key=lambda f: -f.eta2)
    carrying = fits[0] if fits and fits[0].eta2 >= MIN_ETA2 else None
    where = "at every distance" if carrying is None else (
        _region(carrying.curve, carrying.unit, values[carrying.name]) + f", following the {carrying.name}"
        if carrying.name != "distance" else _region(carrying.curve, carrying.unit, values[carrying.name]))
    if carrying is not None:
        x = values[carrying.name]
        curve_means = np.array([c.mean_mm for c in carrying.curve])
        half = 0.5 * np.max(np.abs(curve_means))
        xs = np.array([c.x for c in carrying.curve], float)
        lo, hi = xs[np.abs(curve_means) >= half].min(), xs[np.abs(curve_means) >= half].max()
        edges = np.linspace(float(np.nanmin(x)), float(np.nanmax(x)), GROUPS + 1)
        step = edges[1] - edges[0]
        region = np.isfinite(x) & (x >= lo - step) & (x <= hi + step)
    else:
        region = np.ones(len(v), bool)
    mean = float(np.sum(weight[region] * v[region]) / np.sum(weight[region]))
    departure: DepartureAtEnds | ValidityDeparture | DepartureFactor
    if carrying is not None and _changes_sign(carrying.curve):
        first, last = carrying.curve[0], carrying.curve[-1]
        scale, shown = (1000.0, "m") if carrying.unit == "mm" else (1.0, carrying.unit)
        ends = [_size(family, c.mean_mm) + f" at {c.x / scale:.1f} {shown}" for c in (first, last)]
        size, where = f"from {ends[0]} to {ends[1]}", f"following the {carrying.name}"
        departure = DepartureAtEnds(at_ends=[round(first.mean_mm, 4), round(last.mean_mm, 4)])
    elif family == "validity":
        measured = _stack([o.valid_rate for o in observations], maps).astype(float)[region]
        predicted = _stack([p.valid_rate for p in predictions], maps).astype(float)[region]
        change = float(measured.sum() / predicted.sum() - 1.0) if predicted.sum() > 0 else mean
        size = f"{100 * abs(change):.0f} % {'below' if change < 0 else 'above'} the model's"
        departure = ValidityDeparture(relative_change=round(change, 4), difference=round(mean, 4))
    else:
        size = _size(family, mean)
        departure = DepartureFactor(factor=round(math.exp(mean), 4))
    return FamilyDeparture(
        family=family, carrying_axis=carrying.name if carrying else None, where=where, departure=departure,
        axes=[StatisticsAxis(axis=f.name, unit=f.unit, eta2=round(float(f.eta2), 4)) for f in fits],
        curve=[StatisticsCurvePoint(x=c.x, mean=c.mean_mm, n=c.n) for c in carrying.curve] if carrying else [],
        description=f"{FAMILY_WORDS[family]} {size} {where}")
