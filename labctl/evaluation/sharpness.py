"""Evaluation of ``slanted_edge`` runs: SFR over distance, hyperfocal distance, intensity resolution.

Per position the stack-mean intensity of the chart is divided pixel-wise by
the stack mean of the white sheet at the same distance (Thesis 2024, 5.1.2), the near-
vertical and near-horizontal edges are found automatically, and the ISO 12233
e-SFR of each gives SFR10, SFR50 and SFR area. "Horizontal" results come from
the near-vertical edge (they resolve horizontal detail, with the sensor's
horizontal angular resolution FOV_h / W), "vertical" ones from the near-
horizontal edge. A position whose edge was not found, is clipped or has no
SFR10 or SFR50 is invalid (hollow in the plots, ignored by the distance figures; the table's note
gives the reason).

The intensity resolution's Type A uncertainty is the delete-a-group jackknife of the SFR10 at best focus over
``JACKKNIFE_GROUPS`` contiguous groups of frames of the chart and white stacks (``metrics.sfr.sfr10_jackknife``):
once best focus is known, its two stacks are read again for their means without each group (keeping every
position's replicates until then would hold hundreds of MB at 640 x 480).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from drivers.protocols import CameraInfo
from labctl.evaluation.sections import SlantedEdgeRow
from labctl.run.store import StepRecord
from metrics.optics import sensor_angular_resolution_deg
from metrics.plausibility import above_nyquist
from metrics.sfr import SFRResult, edge_sfr, find_edge_rois, normalize_by_white, sfr10_jackknife
from metrics.sharpness import (
    best_focus_distance,
    hyperfocal_distance,
    ied_pixels,
    ied_pixels_at_centre,
    imagery_resolution_deg,
    lateral_mm,
    position_spacing,
    sharpness_peak_at_sweep_end,
)
from metrics.stack import leave_group_out_means, stack_stats
from metrics.uncertainty import contiguous_groups

#: contiguous groups of frames of the intensity resolution's jackknife (fewer frames: one group per frame)
JACKKNIFE_GROUPS = 10


@dataclass(frozen=True)
class EdgeMeasurement:
    """SFR of one edge orientation at one distance."""

    sfr10: float
    sfr50: float
    sfr_area: float
    angle_deg: float
    roi: tuple[int, int, int, int]
    valid: bool
    warnings: tuple[str, ...]
    frequency: np.ndarray = field(repr=False)
    sfr: np.ndarray = field(repr=False)
    #: why the measurement is invalid ("" when valid)
    reason: str = ""


@dataclass(frozen=True)
class SharpnessPosition:
    distance_mm: float
    chart_step: str
    white_step: str
    exposure_us: float
    horizontal: EdgeMeasurement | None
    vertical: EdgeMeasurement | None


@dataclass
class SharpnessResult:
    positions: list[SharpnessPosition]
    sensor_resolution_deg: tuple[float, float]
    hyperfocal_mm: float = math.nan
    #: the sweep's spacing at the hyperfocal distance and at best focus (their resolution:
    #: metrics.sharpness.position_spacing)
    hyperfocal_spacing_mm: float = math.nan
    best_focus_spacing_mm: float = math.nan
    best_focus_mm: float = math.nan
    resolution_deg: tuple[float, float] = (math.nan, math.nan)
    #: Type A standard uncertainties of ``resolution_deg`` (the jackknife of the SFR10 at best focus; NaN where
    #: not evaluated)
    resolution_u_deg: tuple[float, float] = (math.nan, math.nan)
    ied_px: float = math.nan  # a face at the image centre (pinhole model)
    ied_px_angular: float = math.nan  # with the mean angular pixel size FOV / pixels (Thesis 2024, eq. 6-2)
    #: set when the sharpness peaks at an end of the sweep (best focus is then a bound)
    focus_warning: str | None = None
    notes: list[str] = field(default_factory=list)

    def series(self, orientation: str, attr: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(distances, values, valid) of one orientation's ``attr`` over distance."""
        d, v, ok = [], [], []
        for p in self.positions:
            m = getattr(p, orientation)
            d.append(p.distance_mm)
            v.append(getattr(m, attr) if m is not None else math.nan)
            ok.append(m is not None and m.valid)
        return np.array(d), np.array(v), np.array(ok)


def _measure(image: np.ndarray, roi: tuple[int, int, int, int]) -> EdgeMeasurement:
    x, y, w, h = roi
    result: SFRResult = edge_sfr(image[y : y + h, x : x + w])
    reason = _invalid_reason(result)
    return EdgeMeasurement(result.sfr10, result.sfr50, result.sfr_area, result.angle_deg, roi, not reason,
                           tuple(result.warnings), result.frequency, result.sfr, reason)


def _invalid_reason(result: SFRResult) -> str:
    """Why an edge's SFR is not used for the distance figures ("" when it is)."""
    if result.clipped:
        return next((w for w in result.warnings if w.startswith("clipping")), "clipped ESF")
    if not math.isfinite(result.sfr10):
        return "no SFR10: the SFR does not fall to 10 % within the evaluated frequencies"
    if not math.isfinite(result.sfr50):
        return "no SFR50: the SFR does not fall to 50 % within the evaluated frequencies"
    return ""


def edge_note(edge: EdgeMeasurement | None) -> str:
    """The table's note on one edge: why it is invalid, or the Nyquist warning of a valid one."""
    if edge is None:
        return "edge not found"
    if edge.reason:
        return edge.reason
    return "SFR10 above Nyquist (0.5 cy/px): aliasing" if above_nyquist(edge.sfr10) else ""


def measure_position(chart: np.ndarray, white: np.ndarray) -> tuple[EdgeMeasurement | None, EdgeMeasurement | None, list[str]]:
    """SFR of the near-vertical (horizontal resolution) and near-horizontal edge of one chart image."""
    image = normalize_by_white(chart, white)
    notes: list[str] = []
    found: dict[str, EdgeMeasurement | None] = {"vertical": None, "horizontal": None}
    try:
        rois = find_edge_rois(np.nan_to_num(image, nan=0.0))
    except ValueError as exc:
        return None, None, [str(exc)]
    for roi in rois:
        if found[roi.orientation] is None:
            try:
                found[roi.orientation] = _measure(image, (roi.x, roi.y, roi.w, roi.h))
            except ValueError as exc:
                notes.append(f"{roi.orientation} edge: {exc}")
    # a near-vertical edge resolves horizontal detail and vice versa
    return found["vertical"], found["horizontal"], notes


def _mean_image(step: StepRecord, channel: str = "intensity") -> np.ndarray:
    return stack_stats(step.read(channel)).mean


def _left_out(step: StepRecord, groups: int) -> np.ndarray:
    """The (``groups``, H, W) means of the step's intensity stack without each of that many contiguous groups of
    frames."""
    stack = step.read("intensity")
    return leave_group_out_means(stack, contiguous_groups(stack.shape[0], groups))


def _resolution_u(chart: StepRecord, white: StepRecord, position: SharpnessPosition,
                  resolution_deg: tuple[float, float]) -> tuple[float, float]:
    """Standard uncertainties of the two imagery resolutions sensor / SFR10 at ``position`` (best focus): the
    SFR10's delete-a-group jackknife over ``JACKKNIFE_GROUPS`` groups of frames of the ``chart`` and ``white``
    stacks, on each edge's ROI, times the sensitivity |d resolution / d SFR10| = resolution / SFR10 (GUM 5.1.3);
    NaN with fewer than two frames."""
    groups = min(JACKKNIFE_GROUPS, *(int(s.group["intensity"].shape[0]) for s in (chart, white)))
    if groups < 2:
        return math.nan, math.nan
    charts, whites = (_left_out(step, groups) for step in (chart, white))
    out = []
    for edge, resolution in ((position.horizontal, resolution_deg[0]), (position.vertical, resolution_deg[1])):
        if edge is None:
            out.append(math.nan)
            continue
        x, y, w, h = edge.roi
        u_sfr10 = sfr10_jackknife(charts[:, y : y + h, x : x + w], whites[:, y : y + h, x : x + w])
        out.append(resolution / edge.sfr10 * u_sfr10)
    return out[0], out[1]


def evaluate_slanted_edge(steps: Sequence[StepRecord], camera: CameraInfo,
                          progress: Callable[[str], None]) -> SharpnessResult | None:
    """Thesis 2024, 5.1.2 over every chart position that has a white reference at the same distance."""
    charts = {s.attrs["distance_mm"]: s for s in steps if s.attrs.get("target") == "slanted_edge"}
    whites = {s.attrs["distance_mm"]: s for s in steps if s.attrs.get("target") == "white_sheet"}
    sensor = (sensor_angular_resolution_deg(camera.fov_deg[0], camera.width),
              sensor_angular_resolution_deg(camera.fov_deg[1], camera.height))
    result = SharpnessResult(positions=[], sensor_resolution_deg=sensor)
    missing = sorted(set(charts) - set(whites))
    if missing:
        result.notes.append(f"no white reference at {', '.join(f'{d:g}' for d in missing)} mm: positions skipped")
    for distance in sorted(set(charts) & set(whites)):
        chart, white = charts[distance], whites[distance]
        progress(f"{chart.step_id} slanted edge")
        h, v, notes = measure_position(_mean_image(chart), _mean_image(white))
        result.notes.extend(f"{chart.step_id}: {n}" for n in notes)
        result.positions.append(SharpnessPosition(float(distance), chart.step_id, white.step_id,
                                                  float(chart.attrs.get("exposure_us", math.nan)), h, v))
    if not result.positions:
        return None
    _summarize(result)
    if all(math.isfinite(r) for r in result.resolution_deg):
        best = next(p for p in result.positions if p.distance_mm == result.best_focus_mm)
        progress(f"{best.chart_step} intensity resolution uncertainty")
        result.resolution_u_deg = _resolution_u(charts[best.distance_mm], whites[best.distance_mm], best,
                                                result.resolution_deg)
    if math.isfinite(result.hyperfocal_mm):
        result.ied_px = ied_pixels_at_centre(camera.fov_deg[0], camera.width, result.hyperfocal_mm)
        result.ied_px_angular = ied_pixels(result.sensor_resolution_deg[0], result.hyperfocal_mm)
    return result


def _sweep_end_warning(end: str, distances: np.ndarray) -> str:
    """The warning for a sharpness peak at the ``end`` ("near" or "far") of the valid positions."""
    edge = float(distances.max() if end == "far" else distances.min())
    beyond = "farther" if end == "far" else "nearer"
    return (f"the sharpness peaks at the {end} end of the sweep ({edge:g} mm): the sharpest distance may lie "
            f"{beyond}; extend the slanted_edge sweep to locate best focus")


def _summarize(result: SharpnessResult) -> None:
    """Hyperfocal and best focus from the SFR area of both orientations; resolution at best focus."""
    d, area_h, ok_h = result.series("horizontal", "sfr_area")
    _, area_v, ok_v = result.series("vertical", "sfr_area")
    both = ok_h & ok_v
    area = np.where(both, (area_h + area_v) / 2, np.nan)
    if not both.any():
        result.notes.append("no position with both edges valid: sharpness figures are null")
        return
    result.hyperfocal_mm = hyperfocal_distance(d, area, both)
    result.best_focus_mm = best_focus_distance(d, area, both)
    result.hyperfocal_spacing_mm = position_spacing(d, area, both, result.hyperfocal_mm)
    result.best_focus_spacing_mm = position_spacing(d, area, both, result.best_focus_mm)
    end = sharpness_peak_at_sweep_end(d, area, both)
    if end is not None:
        result.focus_warning = _sweep_end_warning(end, d[both])
        result.notes.append(f"warning: {result.focus_warning}")
    best = next(p for p in result.positions if p.distance_mm == result.best_focus_mm)
    result.resolution_deg = (
        imagery_resolution_deg(result.sensor_resolution_deg[0], best.horizontal.sfr10),
        imagery_resolution_deg(result.sensor_resolution_deg[1], best.vertical.sfr10),
    )


def resolution_table(result: SharpnessResult) -> list[SlantedEdgeRow]:
    """Per position: SFR figures, imagery resolution (angular and lateral) per orientation."""
    rows: list[SlantedEdgeRow] = []
    for p in result.positions:
        h = _edge_columns(p.horizontal, result.sensor_resolution_deg[0], p.distance_mm)
        v = _edge_columns(p.vertical, result.sensor_resolution_deg[1], p.distance_mm)
        rows.append({"distance_mm": p.distance_mm, "step": p.chart_step,
                     "sfr10_h": h.sfr10, "sfr50_h": h.sfr50, "sfr_area_h": h.sfr_area, "valid_h": h.valid,
                     "resolution_h_deg": h.resolution_deg, "resolution_h_mm": h.resolution_mm, "note_h": h.note,
                     "sfr10_v": v.sfr10, "sfr50_v": v.sfr50, "sfr_area_v": v.sfr_area, "valid_v": v.valid,
                     "resolution_v_deg": v.resolution_deg, "resolution_v_mm": v.resolution_mm, "note_v": v.note})
    return rows


class _EdgeColumns(NamedTuple):
    """One orientation's columns of the slanted-edge table (NaN where the edge was not found)."""

    sfr10: float
    sfr50: float
    sfr_area: float
    valid: bool
    resolution_deg: float
    resolution_mm: float
    note: str


def _edge_columns(m: EdgeMeasurement | None, sensor_deg: float, distance_mm: float) -> _EdgeColumns:
    """The columns of one orientation's edge ``m`` at ``distance_mm``, for a sensor of ``sensor_deg`` per pixel."""
    angular = imagery_resolution_deg(sensor_deg, m.sfr10) if m is not None else math.nan
    return _EdgeColumns(sfr10=m.sfr10 if m else math.nan, sfr50=m.sfr50 if m else math.nan,
                        sfr_area=m.sfr_area if m else math.nan, valid=bool(m and m.valid), resolution_deg=angular,
                        resolution_mm=lateral_mm(angular, distance_mm) if math.isfinite(angular) else math.nan,
                        note=edge_note(m))
