"""Evaluation of the VDI/VDE 2634-2 procedures (``sphere_bar``, ``flatness``) with ``metrics.vdi2634``.

A measurement is the mean of the step's ``frames_per_measurement`` consecutive
frames (all of them when the run does not say): per frame the artefact's points
are those nearer than the wall minus half the artefact's gap (the wall: the
step's reference distance, else the stage's nominal distance), and per pixel
the measurement is the mean of the frames in which the pixel saw the artefact
(frames left over after the last whole measurement are not evaluated). A ball bar's points are
split between its two spheres along the bar's nominal direction in space (its
orientation and its tilt towards the wall, so that a bar along the range axis
splits by depth): projected on that direction, the points fall into two groups
a spacing apart, separated where the two groups' means are equidistant (two
means, iterated from the centroid), and each sphere is fitted with the rim rule of
``metrics.vdi2634`` (``max_incidence_deg``, ``rim_margin_px`` of the step,
the margin turned into an angle with the camera's focal length). Per quantity the key figure is the measurement of
largest magnitude over all measurements and positions (what the guideline compares
with the maximum permissible error): P_F and F their maximum, P_S and SD
signed. With a maximum permissible error in the campaign, the verdict is
``metrics.uncertainty.conformity`` of that magnitude with the figure's expanded
uncertainty: pass or fail outside a guard band of U around the MPE, marginal
inside it. The budget is the artefact's calibration where the campaign states
it (the certificate's uncertainty of the spheres' form deviation for P_F, of the
diameter for P_S, of the centre distance for SD and of the plate's flatness
deviation for F, each with sensitivity 1); it has no Type A component: the
figure is the extreme of the test's measurements, which the guideline compares
with the MPE as it is, not a mean of repeated measurements with a standard
error. Where the campaign states none, the verdict is on the value alone.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from drivers.protocols import CameraInfo
from labctl.evaluation.depth_quality import focal_length_px
from labctl.evaluation.keyfigures import FigureValue, standard_uncertainty
from labctl.evaluation.sections import AcceptancePositionRow, AcceptanceVerdict
from labctl.run.store import StepRecord
from metrics.uncertainty import Component, conformity, expanded_uncertainty, from_multiple
from metrics.vdi2634 import (
    MAX_EXCLUDED_SHARE,
    fit_flat,
    fit_sphere_cap,
    flatness_error,
    probing_error_form,
    probing_error_size,
    sphere_spacing_error,
)

#: fewer artefact points than this in a measurement (or on a sphere inside its rim): the frame is not evaluated
MIN_POINTS = 10
#: rim rule of the sphere fit when the step does not give one (metrics.vdi2634)
MAX_INCIDENCE_DEG, RIM_MARGIN_PX = 60.0, 1.0
#: key figure -> (maximum permissible error parameter, how the measurements reduce)
QUANTITIES = {
    "probing_error_form_mm": ("mpe_form_mm", "max"),
    "probing_error_size_mm": ("mpe_size_mm", "signed"),
    "sphere_spacing_error_mm": ("mpe_spacing_mm", "signed"),
    "flatness_error_mm": ("mpe_flatness_mm", "max"),
}
#: figure -> (the artefact's calibrated value its budget takes, the step parameter with its stated uncertainty,
#: the campaign field that states it)
CALIBRATED = {
    "probing_error_form_mm": ("ball bar: calibrated sphere form", "form_uncertainty_mm", "sphere_form_uncertainty_mm"),
    "probing_error_size_mm": ("ball bar: calibrated sphere diameter", "diameter_uncertainty_mm",
                              "sphere_diameter_uncertainty_mm"),
    "sphere_spacing_error_mm": ("ball bar: calibrated centre distance", "spacing_uncertainty_mm",
                                "sphere_spacing_uncertainty_mm"),
    "flatness_error_mm": ("flat plate: calibrated flatness", "flatness_uncertainty_mm", "flatness_uncertainty_mm"),
}
#: why no acceptance figure has a Type A component
NO_TYPE_A = ("no Type A component: the figure is the extreme of the test's measurements, compared with the MPE as "
             "it is, not a mean of repeated measurements with a standard error")


@dataclass(frozen=True)
class Measurement:
    step_id: str
    frames: range  # the step's frames averaged into this measurement
    distance_mm: float
    pose_deg: float  # the bar's orientation or the plate's tilt
    values: dict[str, float]  # figure name -> value of this measurement
    points_used: tuple[float, ...] = ()  # per sphere: share of its points the fit used (rim and 0.3 % rules)
    offset_mm: tuple[float, float] = (0.0, 0.0)  # the artefact's middle right of, above the camera axis
    tilt_deg: float = 0.0  # the bar out of the image plane towards the wall, or the plate about the vertical


@dataclass
class AcceptanceResult:
    measurements: list[Measurement] = field(default_factory=list)
    mpe_mm: dict[str, float | None] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)
    #: step -> figure -> the artefact's calibration component (standard uncertainty, mm) where the campaign states it
    calibration: dict[str, dict[str, Component]] = field(default_factory=dict)


def _params(step: StepRecord) -> dict[str, Any]:
    return json.loads(step.attrs.get("target_json", "{}") or "{}")


def _wall_mm(step: StepRecord) -> float:
    reference = float(step.attrs.get("reference_distance_mm", math.nan))
    return reference if math.isfinite(reference) else float(step.attrs.get("distance_mm", math.nan))


def _artefact_points(step: StepRecord, frames: range, gap_mm: float) -> np.ndarray:
    """The measurement of ``frames``: per pixel the mean of the frames in which it saw the artefact, (n, 3)."""
    total, count = 0.0, 0
    for k in frames:
        cloud = np.stack([step.frame(c, k) for c in ("x", "y", "z")], axis=-1).reshape(-1, 3).astype(np.float64)
        artefact = np.all(np.isfinite(cloud), axis=1) & (cloud[:, 2] < _wall_mm(step) - gap_mm / 2)
        total = total + np.where(artefact[:, None], cloud, 0.0)
        count = count + artefact
    seen = np.asarray(count) > 0
    return np.asarray(total)[seen] / np.asarray(count)[seen, None]


#: what an evaluator gives: the figures of one measurement and per sphere the share of its points the fit used
#: (empty for the plate), or why the measurement is not evaluated
Evaluated = tuple[dict[str, float], tuple[float, ...]] | str


def bar_sides(points: np.ndarray, orientation_deg: float, tilt_deg: float, iterations: int = 20) -> np.ndarray:
    """Which of the ball bar's points lie on the sphere at the ``orientation_deg`` end (True) rather than the
    other (VDI/VDE 2634-2: each sphere of the bar fitted on its own): projected on the bar's nominal direction
    in space, the threshold midway between the two sides' means, iterated from the centroid (two means in one
    dimension), so a bar tilted towards the wall, whose nearer sphere gives more points, splits at its gap.

    Examples
    --------
    Ten points of a near sphere, four of a far one, on a bar along the range axis (tilt 90 deg).

    >>> near, far = np.array([0.0, 0.0, 850.0]), np.array([0.0, 0.0, 1150.0])
    >>> spread = np.linspace(-20.0, 20.0, 10)[:, None] * np.array([1.0, 1.0, 0.5])
    >>> points = np.vstack([near + spread, far + spread[:4]])
    >>> bar_sides(points, 0.0, 90.0).tolist() == [False] * 10 + [True] * 4
    True
    """
    phi, tilt = math.radians(orientation_deg), math.radians(tilt_deg)
    axis = np.array([math.cos(phi) * math.cos(tilt), math.sin(phi) * math.cos(tilt), math.sin(tilt)])
    along = (points - points.mean(axis=0)) @ axis
    threshold = 0.0
    for _ in range(iterations):
        side = along >= threshold
        if side.all() or not side.any():
            break
        moved = (along[side].mean() + along[~side].mean()) / 2
        if moved == threshold:
            break
        threshold = moved
    return along >= threshold


def _sphere_bar(points: np.ndarray, params: dict[str, Any], focal_px: float) -> Evaluated:
    if len(points) < 2 * MIN_POINTS:
        return f"{len(points)} points on the ball bar"
    side = bar_sides(points, float(params.get("orientation_deg", 0.0)), float(params.get("tilt_deg", 0.0)))
    halves = points[~side], points[side]
    if min(len(h) for h in halves) < MIN_POINTS:
        return f"{min(len(h) for h in halves)} points on a sphere"
    incidence = float(params.get("max_incidence_deg", MAX_INCIDENCE_DEG))
    margin = float(params.get("rim_margin_px", RIM_MARGIN_PX)) / focal_px
    try:
        fits = [fit_sphere_cap(h, float(params["diameter_mm"]) / 2, incidence, margin) for h in halves]
    except ValueError as error:  # fewer than 4 points inside a rim
        return str(error)
    if min(f.n_points - f.n_rim for f in fits) < MIN_POINTS:
        return f"{min(f.n_points - f.n_rim for f in fits)} points on a sphere inside its rim"
    sizes = [probing_error_size(f, float(params["diameter_mm"])) for f in fits]
    return {
        "probing_error_form_mm": max(probing_error_form(f) for f in fits),
        "probing_error_size_mm": max(sizes, key=abs),
        "sphere_spacing_error_mm": sphere_spacing_error(fits[0], fits[1], float(params["spacing_mm"])),
    }, tuple(f.used_share for f in fits)


def _flatness(points: np.ndarray, params: dict[str, Any], _: float) -> Evaluated:
    if len(points) < MIN_POINTS:
        return f"{len(points)} points on the plate"
    return {"flatness_error_mm": flatness_error(fit_flat(points))}, ()


def evaluate_acceptance(steps: Sequence[StepRecord], camera: CameraInfo,
                        progress: Callable[[str], None]) -> AcceptanceResult:
    """Every measurement of the ``sphere_bar`` and ``flatness`` steps, and the campaign's MPEs."""
    result = AcceptanceResult()
    focal_px = focal_length_px(camera)
    for step in steps:
        kind = step.attrs.get("procedure")
        params = _params(step)
        progress(f"{step.step_id} {kind}")
        for name, (mpe, _) in QUANTITIES.items():
            if mpe in params:
                result.mpe_mm[name] = params[mpe]
        result.calibration[step.step_id] = acceptance_calibration(params)
        evaluate = _sphere_bar if kind == "sphere_bar" else _flatness
        pose = float(params.get("orientation_deg" if kind == "sphere_bar" else "tilt_deg", 0.0))
        # recorded in the camera frame (x right, y down); reported as the campaign states it (right, up; 0 - y: no -0)
        x_mm, y_mm = params.get("offset_mm", (0.0, 0.0))
        placement = {"offset_mm": (float(x_mm), 0.0 - float(y_mm)), "tilt_deg": float(params.get("tilt_deg", 0.0))}
        distance = _wall_mm(step) - float(params.get("gap_mm", 500.0))
        recorded = step.group["z"].shape[0]
        per = min(int(params.get("frames_per_measurement", recorded)), recorded)
        if recorded % per:
            result.notes.append(f"{step.step_id}: the last {recorded % per} of {recorded} frames make no whole "
                                f"measurement of {per} frames, not evaluated")
        for first in range(0, recorded - per + 1, per):
            frames = range(first, first + per)
            evaluated = evaluate(_artefact_points(step, frames, float(params.get("gap_mm", 500.0))), params, focal_px)
            if isinstance(evaluated, str):
                result.notes.append(f"{step.step_id} frames {first}-{first + per - 1}: {evaluated}, not evaluated")
                continue
            result.measurements.append(Measurement(step.step_id, frames, distance, pose, *evaluated, **placement))
    return result


def acceptance_calibration(params: dict[str, Any]) -> dict[str, Component]:
    """The artefact's calibration components of a step: each stated uncertainty divided by the certificate's
    coverage factor (GUM 4.3.3), sensitivity 1: P_S and SD are measured minus calibrated value, and the form
    deviation the certificate states for the spheres or the plate is part of the measured P_F or F."""
    k = float(params.get("calibration_coverage_factor", 2.0))
    return {name: Component(f"{what} (certificate, Type B)", from_multiple(float(params[key]), k))
            for name, (what, key, _) in CALIBRATED.items() if params.get(key) is not None}


def figure_values(result: AcceptanceResult) -> dict[str, FigureValue]:
    """Key figures: per quantity the measurement of largest magnitude, with the steps measured and the budget of
    the step it comes from (the artefact's calibration; empty, not estimated, where the campaign states none)."""
    figures: dict[str, FigureValue] = {}
    for name, (_, reduce) in QUANTITIES.items():
        rows = [m for m in result.measurements if name in m.values]
        if not rows:
            continue
        worst = max(rows, key=lambda m: abs(m.values[name]))
        value = worst.values[name] if reduce == "signed" else max(m.values[name] for m in rows)
        component = result.calibration.get(worst.step_id, {}).get(name)
        figures[name] = FigureValue(value, sorted({m.step_id for m in rows}), (component,) if component else ())
    return figures


def _uncertainty_basis(name: str, figure: FigureValue) -> str:
    """What a figure's uncertainty rests on, in words (report, JSON)."""
    if figure.budget:
        return f"{figure.budget[0].name}; {NO_TYPE_A}"
    what, _, field_name = CALIBRATED[name]
    return f"not estimated: the campaign states no uncertainty of the {what} ({field_name}); {NO_TYPE_A}"


def rim_rule_deviation(result: AcceptanceResult) -> str | None:
    """The sphere fits' departure from VDI/VDE 2634-2 (which allows leaving out at most 0.3 % of a measurement's
    points): the rim rule's range of shares of a sphere's points used; None without a sphere measured."""
    shares = [share for m in result.measurements for share in m.points_used]
    if not shares:
        return None
    return (f"deviation from VDI/VDE 2634-2: the rim rule fits each sphere to {100 * min(shares):.0f}-"
            f"{100 * max(shares):.0f} % of its points (per sphere and measurement: acceptance_positions' "
            f"points_used); the guideline allows leaving out at most {100 * MAX_EXCLUDED_SHARE:g} %")


def verdicts(result: AcceptanceResult) -> dict[str, AcceptanceVerdict]:
    """Per quantity: the figure, its maximum permissible error, pass / fail / marginal with the figure's expanded
    uncertainty (``metrics.uncertainty.conformity``; ``no_mpe`` without an MPE), that uncertainty (None: not
    estimated) and what it rests on, the frames averaged per measurement (None when its positions differ:
    ``acceptance_table`` has them) and its departure from the guideline (the sphere quantities' rim rule; None
    for the plate)."""
    out: dict[str, AcceptanceVerdict] = {}
    deviation = rim_rule_deviation(result)
    for name, figure in figure_values(result).items():
        assert figure.value is not None
        mpe = result.mpe_mm.get(name)
        u = standard_uncertainty(figure)
        expanded = None if u is None else expanded_uncertainty(u)
        verdict = "no_mpe" if mpe is None else conformity(figure.value, mpe, expanded, "max_abs")
        averaged = {len(m.frames) for m in result.measurements if name in m.values}
        out[name] = {"value": figure.value, "mpe_mm": mpe, "verdict": verdict, "expanded_uncertainty_mm": expanded,
                     "uncertainty_basis": _uncertainty_basis(name, figure),
                     "frames_per_measurement": averaged.pop() if len(averaged) == 1 else None,
                     "deviation": None if name == "flatness_error_mm" else deviation}
    return out


def acceptance_table(result: AcceptanceResult) -> list[AcceptancePositionRow]:
    """Per step: where the artefact stood (distance, the middle's offset right of and above the camera axis, the
    bar's orientation in the image plane, its tilt towards the wall or the plate's tilt about the vertical),
    its frames evaluated, measurements and frames averaged per measurement, the worst measurement
    of each quantity (NaN where not measured) and per measurement and sphere the share of its points the fit
    used (None for the plate) (report, JSON)."""
    rows: list[AcceptancePositionRow] = []
    for step_id in dict.fromkeys(m.step_id for m in result.measurements):
        ms = [m for m in result.measurements if m.step_id == step_id]
        bar = bool(ms[0].points_used)
        rows.append({"step": step_id, "distance_mm": ms[0].distance_mm, "pose_deg": ms[0].pose_deg,
                     "offset_mm": list(ms[0].offset_mm), "orientation_deg": ms[0].pose_deg if bar else None,
                     "tilt_deg": ms[0].tilt_deg,
                     "frames": float(sum(len(m.frames) for m in ms)), "measurements": float(len(ms)),
                     "frames_per_measurement": float(len(ms[0].frames)),
                     "probing_error_form_mm": _worst(ms, "probing_error_form_mm"),
                     "probing_error_size_mm": _worst(ms, "probing_error_size_mm"),
                     "sphere_spacing_error_mm": _worst(ms, "sphere_spacing_error_mm"),
                     "flatness_error_mm": _worst(ms, "flatness_error_mm"),
                     "points_used": [list(m.points_used) for m in ms] if ms[0].points_used else None})
    return rows


def _worst(measurements: Sequence[Measurement], name: str) -> float:
    """The value of quantity ``name`` of largest magnitude over ``measurements`` (NaN where none measures it)."""
    values = [m.values[name] for m in measurements if name in m.values]
    return max(values, key=abs) if values else math.nan
