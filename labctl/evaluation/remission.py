"""Evaluation of ``remission_angle`` runs: repeatability and trueness over angle per material (Thesis 2024, 5.4).

Per step (material, robot angle) the ROI on the optical axis gives the axis
distance, the pooled repeatability and the invalid and off-target fractions
(metrics/remission.py). Per material, trueness is reported twice: against the
material's own 0 deg distance (Thesis 2024, 5.4.1, Fig. 6-11) and against the
geometric reference R + delta / cos(theta) - e tan(theta), with delta and e
fitted to the curve of PTFE (Thesis 2024, 5.4.2, labctl's improvement). The
geometric trueness therefore still holds b of the fit's model for that
material: the camera's range offset, the radius error and the material's
sub-surface bias, which is what trueness should show.

Key figures (docs/keyfigures.md): ``repeatability_skin_40deg_mm`` and
``repeatability_skin_70deg_mm`` are the largest repeatability over the skin-like
materials (silicone, gelatine, collagen) at +40 and -40 deg (resp. +-70 deg):
a face shows both sides, so the worse side counts. Steps whose ROI is not on
the target do not count; the figure's source lists every skin-like step at
that angle.

The radius R of a step is its ``robot_radius_mm`` attribute or, for runs
recorded without it, the radius the run's stored campaign planned for it.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from drivers.protocols import CameraInfo
from labctl.errors import InputError
from labctl.evaluation.keyfigures import FigureValue
from labctl.evaluation.sections import Misalignment, RemissionAngleRow
from labctl.run.store import StepRecord
from metrics.remission import (
    ROI_SIZE_PX,
    MisalignmentFit,
    RoiMeasurement,
    axis_roi,
    fit_misalignment,
    geometric_reference,
    measure_roi,
    target_window,
    trueness_vs_zero,
    with_ring,
)
from metrics.uncertainty import Component
from procedures.remission_angle import MATERIALS, SKIN_LIKE

#: material whose distance curve gives the misalignment (Thesis 2024, 5.4.1: the best-case target)
FIT_MATERIAL = "ptfe"
#: robot angles of the key figures (Thesis 2024, 6.5.1: most angles in a face lie between 40 and 70 deg)
KEY_ANGLES_DEG = {"repeatability_skin_40deg_mm": 40.0, "repeatability_skin_70deg_mm": 70.0}
#: two recorded angles count as the same within this
ANGLE_TOLERANCE_DEG = 0.5


@dataclass(frozen=True)
class RemissionRow:
    """One step: the ROI measurement and both trueness values."""

    step_id: str
    material: str
    angle_deg: float
    radius_mm: float
    roi: RoiMeasurement
    trueness_zero_mm: float
    reference_mm: float
    trueness_geometric_mm: float


@dataclass
class RemissionResult:
    """Rows per material and angle, the misalignment fitted to ``fit_material``, notes.

    ``roi`` is (first row, first column, height, width) in pixels. Without a fit
    the geometric reference is the commanded radius (delta = e = 0).
    """

    rows: list[RemissionRow]
    roi: tuple[int, int, int, int]
    fit_material: str
    fit: MisalignmentFit | None
    notes: list[str] = field(default_factory=list)

    @property
    def materials(self) -> list[str]:
        present = {r.material for r in self.rows}
        return [m for m in MATERIALS if m in present] + sorted(present - set(MATERIALS))

    def material_rows(self, material: str) -> list[RemissionRow]:
        """The rows of one material, by angle."""
        return sorted((r for r in self.rows if r.material == material), key=lambda r: r.angle_deg)


def _planned_radii(step: StepRecord) -> dict[int, float]:
    """Robot radius of every planned step of the run's stored campaign, by step index."""
    from labctl.run.config import parse_campaign

    campaign = parse_campaign(str(step.group.file.attrs["campaign_toml"]), "stored campaign")
    return {s.index: s.robot_radius_mm for s in campaign.steps() if s.robot_radius_mm is not None}


def _radii(steps: Sequence[StepRecord]) -> dict[str, float]:
    """Commanded radius per step: its ``robot_radius_mm`` attribute, else the stored campaign's plan."""
    radii: dict[str, float] = {}
    plans: dict[str, dict[int, float]] = {}
    for s in steps:
        value = float(s.attrs.get("robot_radius_mm", math.nan))
        if not math.isfinite(value):
            name = s.group.file.filename
            if name not in plans:
                plans[name] = _planned_radii(s)
            index = int(s.attrs["index"])
            if index not in plans[name]:
                raise InputError(f"{name}: step {s.step_id} records no robot radius and its stored campaign "
                                 "plans none for it")
            value = plans[name][index]
        radii[s.step_id] = value
    return radii


class _Measured(NamedTuple):
    record: StepRecord
    material: str
    angle_deg: float
    radius_mm: float
    roi: RoiMeasurement


def _measure(step: StepRecord, roi: tuple[slice, slice], radius: float, camera: CameraInfo) -> _Measured:
    """The ROI with a ring of one pixel around it: its pixels next to one off the target are left out."""
    grown, inner = with_ring(roi, camera.height, camera.width)
    index = (slice(None), *grown)
    x, y, z = (step.group[c][index] for c in ("x", "y", "z"))
    angle = float(step.attrs["robot_angle_deg"])
    return _Measured(step, str(step.attrs["target"]), angle, radius,
                     measure_roi(x, y, z, target_window(angle, radius), inner=inner))


def _fit(measured: list[_Measured], material: str, notes: list[str]) -> MisalignmentFit | None:
    rows = [m for m in measured if m.material == material and m.roi.on_target]
    if not rows:
        notes.append(f"no {material} steps on target: misalignment not fitted, geometric reference = radius")
        return None
    try:
        return fit_misalignment([m.angle_deg for m in rows], [m.roi.distance_mm for m in rows],
                                [m.radius_mm for m in rows], [m.roi.distance_se_mm for m in rows])
    except ValueError as exc:
        notes.append(f"misalignment not fitted ({exc}): geometric reference = radius")
        return None


def evaluate_remission(steps: Sequence[StepRecord], camera: CameraInfo, progress: Callable[[str], None],
                       roi_size: int = ROI_SIZE_PX, fit_material: str = FIT_MATERIAL) -> RemissionResult | None:
    """Thesis 2024, 5.4 over the ``remission_angle`` steps (None when there are none).

    Trueness vs 0 deg compares steps of the same material and radius.
    """
    steps = [s for s in steps if s.attrs.get("procedure") == "remission_angle"]
    if not steps:
        return None
    roi = axis_roi(camera.height, camera.width, roi_size)
    radii = _radii(steps)
    notes: list[str] = []
    measured = []
    for s in steps:
        progress(f"{s.step_id} remission")
        m = _measure(s, roi, radii[s.step_id], camera)
        if not m.roi.on_target:
            notes.append(f"{s.step_id} ({m.material}, {m.angle_deg:g} deg): ROI {100 * m.roi.invalid_fraction:.0f} % "
                         f"invalid, {100 * m.roi.off_target_fraction:.0f} % off target: not evaluated")
        measured.append(m)
    fit = _fit(measured, fit_material, notes)
    rows: list[RemissionRow] = []
    for material, radius in sorted({(m.material, m.radius_mm) for m in measured}):
        curve = sorted((m for m in measured if (m.material, m.radius_mm) == (material, radius)),
                       key=lambda m: m.angle_deg)
        zero = trueness_vs_zero([m.angle_deg for m in curve], [m.roi.distance_mm for m in curve],
                                ANGLE_TOLERANCE_DEG)
        if not np.isfinite(zero).any() and any(m.roi.on_target for m in curve):
            notes.append(f"{material} at {radius:g} mm: no 0 deg step on target: trueness vs 0 deg is null")
        for m, t0 in zip(curve, zero):
            reference = float(fit.reference(m.angle_deg, radius) if fit else geometric_reference(m.angle_deg, radius))
            rows.append(RemissionRow(m.record.step_id, material, m.angle_deg, radius, m.roi, float(t0), reference,
                                     m.roi.distance_mm - reference))
    rows.sort(key=lambda r: r.step_id)
    r0, c0 = roi
    return RemissionResult(rows, (r0.start, c0.start, r0.stop - r0.start, c0.stop - c0.start), fit_material, fit,
                           notes)


def figure_values(result: RemissionResult) -> dict[str, FigureValue]:
    """``repeatability_skin_40deg_mm`` and ``repeatability_skin_70deg_mm``: max over skin-like materials, both signs,
    with the Type A uncertainty of the step that gives the maximum (jackknife over its frames)."""
    figures = {}
    for name, key_angle in KEY_ANGLES_DEG.items():
        rows = [r for r in result.rows
                if r.material in SKIN_LIKE and abs(abs(r.angle_deg) - key_angle) <= ANGLE_TOLERANCE_DEG]
        measured = [r for r in rows if r.roi.on_target]
        if not measured:
            figures[name] = FigureValue(math.nan, [r.step_id for r in rows])
            continue
        worst = max(measured, key=lambda r: r.roi.repeatability_mm)
        figures[name] = FigureValue(worst.roi.repeatability_mm, [r.step_id for r in rows], (Component(
            f"frames at {worst.step_id}: jackknife of the ROI stack (Type A)", worst.roi.repeatability_u_mm),))
    return figures


def remission_table(result: RemissionResult) -> list[RemissionAngleRow]:
    """Per step: material, angle, axis distance, repeatability, fractions and both trueness values."""
    return [
        {
            "step": r.step_id,
            "material": r.material,
            "angle_deg": r.angle_deg,
            "radius_mm": r.radius_mm,
            "on_target": r.roi.on_target,
            "distance_mm": r.roi.distance_mm,
            "distance_se_mm": r.roi.distance_se_mm,
            "repeatability_mm": r.roi.repeatability_mm,
            "plane_rms_mm": r.roi.plane_rms_mm,
            "invalid_fraction": r.roi.invalid_fraction,
            "off_target_fraction": r.roi.off_target_fraction,
            "trueness_zero_mm": r.trueness_zero_mm,
            "reference_mm": r.reference_mm,
            "trueness_geometric_mm": r.trueness_geometric_mm,
        }
        for r in result.rows
    ]


def misalignment_summary(result: RemissionResult) -> Misalignment | None:
    """The fitted misalignment with standard errors and residual RMS (None without a fit)."""
    f = result.fit
    if f is None:
        return None
    return {
        "material": result.fit_material,
        "target_offset_mm": f.delta_mm, "target_offset_se_mm": f.delta_se_mm,
        "camera_axis_offset_mm": f.e_mm, "camera_axis_offset_se_mm": f.e_se_mm,
        "bias_mm": f.bias_mm, "bias_se_mm": f.bias_se_mm,
        "residual_rms_mm": f.residual_rms_mm, "angles": len(f.angles_deg),
    }
