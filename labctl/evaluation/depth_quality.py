"""Datasheet-comparable figures of the depth-sweep wall (``metrics.depth_quality``).

At every wall position the Depth Quality Tool's ROI (centred 40 % of width and
height) of the first ``DQT_FRAMES`` frame(s) and Basler's centre 40 x 40 pixels
of every frame give the vendor figures. The z stack is the one the depth
evaluation reads anyway; of x and y only the first frame is read: a pixel's
x/z and y/z are those of its ray, the same in every frame (x = z (u - c_x) / f
for the stereo camera's deprojection, x = r d_x with z = r d_z for a ToF
camera's), so each frame's window x, y follow from its z; the key figures take them at the distances the
vendors quote (1000 mm and 2000 mm, the step whose reference distance is nearest, within 150 mm). The
subpixel RMS needs the stereo baseline: it is taken from the camera model's
datasheet (``STEREO_BASELINE_MM``) and is null for other cameras.

Z accuracy is measured against the step's absolute reference (``absolute_reference_mm``: the laser
reading moved to the camera's depth origin by the campaign's ``devices.camera.depth_origin_offset_mm``),
never against the offset-calibrated ``reference_distance_mm``, which is the camera's own depth at the
calibration distance and hides its range offset. Without an absolute reference it is NaN, and its key
figure null with a ``no_absolute_reference`` flag saying why (docs/keyfigures.md).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from drivers.protocols import CameraInfo
from labctl.evaluation.keyfigures import FigureValue
from labctl.evaluation.sections import DepthQualityRow
from labctl.evaluation.uncertainty import absolute_reference, scaled
from labctl.run.store import StepRecord
from metrics.depth_quality import (
    DQT_FRAMES,
    Cloud,
    VendorFigures,
    VendorUncertainties,
    centre_window,
    dqt_roi,
    vendor_figures,
    vendor_uncertainties,
)
from metrics.uncertainty import Component

#: stereo baseline (mm) by product name (Intel RealSense D400 Series datasheet)
STEREO_BASELINE_MM = {"D415": 55.0, "D435": 50.0, "D455": 95.0, "D457": 95.0}
#: the distances (mm) at which the vendor figures become key figures
VENDOR_DISTANCES_MM = (1000.0, 2000.0)
TOLERANCE_MM = 150.0

#: the key figures that need the absolute reference (null without it)
ABSOLUTE_REFERENCE_FIGURES = ("z_accuracy_{d}mm_pct",)
#: key-figure name pattern -> VendorFigures field
FIELDS = {
    "fill_rate_{d}mm_pct": "fill_rate_pct",
    "z_accuracy_{d}mm_pct": "z_accuracy_pct",
    "plane_fit_rms_{d}mm_mm": "plane_fit_rms_mm",
    "subpixel_rms_{d}mm_px": "subpixel_rms_px",
    "spatial_precision_{d}mm_mm": "spatial_precision_mm",
    "temporal_precision_{d}mm_mm": "temporal_precision_mm",
}


def stereo_baseline_mm(model: str) -> float | None:
    """Baseline of a known stereo camera model (None for other cameras)."""
    return next((value for key, value in STEREO_BASELINE_MM.items() if key in model), None)


def focal_length_px(camera: CameraInfo) -> float:
    """Horizontal focal length in pixels of the pinhole with the camera's width and horizontal FOV."""
    return (camera.width / 2) / math.tan(math.radians(camera.fov_deg[0]) / 2)


@dataclass(frozen=True)
class VendorPosition:
    """The vendor figures of one wall step: ``reference_mm`` is the step's reference distance (where it stands,
    offset-calibrated), ``figures.reference_mm`` the absolute reference Z accuracy is measured against (NaN
    without one, ``missing_reference`` then saying why)."""

    step_id: str
    reference_mm: float
    figures: VendorFigures
    missing_reference: str
    #: the figures' Type A uncertainties (None at a step whose figures do not become key figures:
    #: :func:`with_uncertainties`)
    uncertainties: VendorUncertainties | None = None
    #: the absolute reference's components in mm (empty without one)
    reference_budget: tuple[Component, ...] = ()


def missing_absolute_reference(attrs: Mapping[str, Any]) -> str:
    """Why a step has no absolute reference (``absolute_reference_mm``, docs/runfile.md); empty when it has one.
    A run file written before the attribute existed reads as a campaign without the offset."""
    if math.isfinite(float(attrs.get("absolute_reference_mm", math.nan))):
        return ""
    if not math.isfinite(float(attrs.get("depth_origin_offset_mm", math.nan))):
        return "no devices.camera.depth_origin_offset_mm in the campaign"
    return "no laser reading in the step"


def _clouds(first_xy: tuple[np.ndarray, np.ndarray], z: np.ndarray, camera: CameraInfo) -> tuple[Cloud, Cloud]:
    """x, y, z (N, h, w) of the Depth Quality Tool's ROI in every frame (the first frame's x and y,
    ``first_xy``, as the tool's figures take them) and of Basler's centre window (each frame's x, y from its z
    along the pixel's ray)."""
    rows, cols = dqt_roi(camera.height, camera.width)
    w_rows, w_cols = centre_window(camera.height, camera.width)
    x0, y0 = first_xy
    roi_z = z[:, rows, cols]
    dqt = (np.broadcast_to(x0[None, rows, cols], roi_z.shape), np.broadcast_to(y0[None, rows, cols], roi_z.shape),
           roi_z)
    wz = z[:, w_rows, w_cols]
    with np.errstate(divide="ignore", invalid="ignore"):
        slope_x, slope_y = x0[w_rows, w_cols] / wz[0], y0[w_rows, w_cols] / wz[0]
    return dqt, (slope_x * wz, slope_y * wz, wz)


def vendor_position(step: StepRecord, z: np.ndarray, first_xy: tuple[np.ndarray, np.ndarray], camera: CameraInfo,
                    model: str) -> VendorPosition:
    """The vendor figures of one wall step whose (N, H, W) z stack is ``z`` and whose first frame's x and y are
    ``first_xy``, Z accuracy against its absolute reference (the Depth Quality Tool's of the first ``DQT_FRAMES``
    frames)."""
    dqt, window = _clouds(first_xy, z, camera)
    absolute = float(step.attrs.get("absolute_reference_mm", math.nan))
    figures = vendor_figures(tuple(c[:DQT_FRAMES] for c in dqt), window, absolute,  # type: ignore[arg-type]
                             focal_length_px(camera), stereo_baseline_mm(model))
    return VendorPosition(step.step_id, float(step.attrs["reference_distance_mm"]), figures,
                          missing_absolute_reference(step.attrs))


def with_uncertainties(position: VendorPosition, step: StepRecord, z: np.ndarray,
                       first_xy: tuple[np.ndarray, np.ndarray], camera: CameraInfo, model: str) -> VendorPosition:
    """``position`` (of ``step``, whose z stack is ``z`` and first frame's x and y ``first_xy``) with the Type A
    uncertainties of its figures (every frame taken singly) and the components of its absolute reference."""
    dqt, window = _clouds(first_xy, z, camera)
    uncertainties = vendor_uncertainties(dqt, window, position.figures.reference_mm, focal_length_px(camera),
                                         stereo_baseline_mm(model))
    return dataclasses.replace(position, uncertainties=uncertainties, reference_budget=absolute_reference(step.attrs))


def key_steps(references: Mapping[str, float]) -> dict[int, str]:
    """The steps the key figures are taken from: per distance of ``VENDOR_DISTANCES_MM``, the step (of
    ``references``: step id -> reference distance, in the run's order) whose reference distance is nearest it,
    the first of equals; left out where none is within ``TOLERANCE_MM``."""
    found = {}
    for distance in VENDOR_DISTANCES_MM:
        near = min(references, key=lambda step: abs(references[step] - distance), default=None)
        if near is not None and abs(references[near] - distance) <= TOLERANCE_MM:
            found[int(distance)] = near
    return found


def _nearest(positions: Sequence[VendorPosition]) -> dict[int, VendorPosition]:
    """The positions :func:`key_steps` chooses, per distance."""
    by_id = {p.step_id: p for p in positions}
    return {d: by_id[step] for d, step in key_steps({p.step_id: p.reference_mm for p in positions}).items()}


def _budget(position: VendorPosition, field: str) -> tuple[Component, ...]:
    """The uncertainty budget of one vendor figure of ``position``: the frames' Type A component, and for Z
    accuracy the absolute reference's components in % of it (sensitivity 100 / reference, GUM 5.1.3; empty,
    not estimated, without them)."""
    if position.uncertainties is None:
        return ()
    frames = Component("frames: spread over the stack (Type A)", getattr(position.uncertainties, field))
    if field != "z_accuracy_pct":
        return (frames,)
    if not position.reference_budget:
        return ()
    return (frames, *scaled(position.reference_budget, 100.0 / position.figures.reference_mm))


def figure_values(positions: Sequence[VendorPosition]) -> dict[str, FigureValue]:
    """Key figures at ``VENDOR_DISTANCES_MM`` with their source step and uncertainty budget (absent where no step
    is near)."""
    figures: dict[str, FigureValue] = {}
    for distance, near in _nearest(positions).items():
        for pattern, field in FIELDS.items():
            figures[pattern.format(d=distance)] = FigureValue(getattr(near.figures, field), [near.step_id],
                                                              _budget(near, field))
    return figures


def reference_flags(positions: Sequence[VendorPosition]) -> dict[str, dict[str, str]]:
    """The ``no_absolute_reference`` flag (``{"check", "message"}``) of each key figure that is null because its
    step has no absolute reference."""
    flags = {}
    for distance, near in _nearest(positions).items():
        if not near.missing_reference:
            continue
        for pattern in ABSOLUTE_REFERENCE_FIGURES:
            flags[pattern.format(d=distance)] = {"check": "no_absolute_reference", "message": (
                f"{near.missing_reference} ({near.step_id}): this figure is measured from the camera's depth "
                "origin (the laser reading minus devices.camera.depth_origin_offset_mm, docs/campaign.md), not "
                "against the offset-calibrated reference, which is the camera's own depth and hides its range offset")}
    return flags


def vendor_table(positions: Sequence[VendorPosition]) -> list[DepthQualityRow]:
    """Per-position vendor figures as rows (report and ``keyfigures.json``)."""
    return [{"step": p.step_id, "reference_mm": p.reference_mm, "absolute_reference_mm": p.figures.reference_mm,
             "fill_rate_pct": p.figures.fill_rate_pct,
             "z_accuracy_pct": p.figures.z_accuracy_pct, "plane_fit_rms_mm": p.figures.plane_fit_rms_mm,
             "plane_fit_rms_pct": p.figures.plane_fit_rms_pct, "subpixel_rms_px": p.figures.subpixel_rms_px,
             "spatial_precision_mm": p.figures.spatial_precision_mm,
             "temporal_precision_mm": p.figures.temporal_precision_mm} for p in positions]
