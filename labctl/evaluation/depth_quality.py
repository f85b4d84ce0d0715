"""Datasheet-comparable figures of the depth-sweep wall (``metrics.depth_quality``).

At every wall position the Depth Quality Tool's ROI (centred 40 % of width and
height) of the first ``DQT_FRAMES`` frame(s) and Basler's centre 40 x 40 pixels
of every frame give the vendor figures. The z stack is the one the depth
evaluation reads anyway; of x and y only the first frame is read: a pixel's
x/z and y/z are those of its ray, the same in every frame (x = z (u - c_x) / f
for the stereo camera's deprojection, x = r d_x with z = r d_z for a ToF
camera's), so each frame's window x, y follow from its z; the key figures take them at the distances the
vendors quote (1000 mm and 2000 mm, the nearest step within 150 mm). The
subpixel RMS needs the stereo baseline: it is taken from the camera model's
datasheet (``STEREO_BASELINE_MM``) and is null for other cameras.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from drivers.protocols import CameraInfo
from labctl.evaluation.sections import DepthQualityRow
from labctl.run.store import StepRecord
from metrics.depth_quality import DQT_FRAMES, VendorFigures, centre_window, dqt_roi, vendor_figures

#: stereo baseline (mm) by product name (Intel RealSense D400 Series datasheet)
STEREO_BASELINE_MM = {"D415": 55.0, "D435": 50.0, "D455": 95.0, "D457": 95.0}
#: the distances (mm) at which the vendor figures become key figures
VENDOR_DISTANCES_MM = (1000.0, 2000.0)
TOLERANCE_MM = 150.0

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
    step_id: str
    figures: VendorFigures


def vendor_position(step: StepRecord, z: np.ndarray, camera: CameraInfo, model: str) -> VendorPosition:
    """The vendor figures of one wall step whose (N, H, W) z stack is ``z``."""
    rows, cols = dqt_roi(camera.height, camera.width)
    w_rows, w_cols = centre_window(camera.height, camera.width)
    x0, y0 = (step.group[c][0] for c in ("x", "y"))
    dqt = (x0[None, rows, cols], y0[None, rows, cols], z[:DQT_FRAMES, rows, cols])
    wz = z[:, w_rows, w_cols]
    with np.errstate(divide="ignore", invalid="ignore"):
        slope_x, slope_y = x0[w_rows, w_cols] / wz[0], y0[w_rows, w_cols] / wz[0]
    figures = vendor_figures(dqt, (slope_x * wz, slope_y * wz, wz), step.attrs["reference_distance_mm"],
                             focal_length_px(camera), stereo_baseline_mm(model))  # type: ignore[arg-type]
    return VendorPosition(step.step_id, figures)


def figure_values(positions: Sequence[VendorPosition]) -> dict[str, tuple[float, list[str]]]:
    """Key figures at ``VENDOR_DISTANCES_MM`` with their source step (absent where no step is near)."""
    figures: dict[str, tuple[float, list[str]]] = {}
    for distance in VENDOR_DISTANCES_MM:
        near = min(positions, key=lambda p: abs(p.figures.reference_mm - distance), default=None)
        if near is None or abs(near.figures.reference_mm - distance) > TOLERANCE_MM:
            continue
        for pattern, field in FIELDS.items():
            figures[pattern.format(d=int(distance))] = (getattr(near.figures, field), [near.step_id])
    return figures


def vendor_table(positions: Sequence[VendorPosition]) -> list[DepthQualityRow]:
    """Per-position vendor figures as rows (report and ``keyfigures.json``)."""
    return [{"step": p.step_id, "reference_mm": p.figures.reference_mm, "fill_rate_pct": p.figures.fill_rate_pct,
             "z_accuracy_pct": p.figures.z_accuracy_pct, "plane_fit_rms_mm": p.figures.plane_fit_rms_mm,
             "plane_fit_rms_pct": p.figures.plane_fit_rms_pct, "subpixel_rms_px": p.figures.subpixel_rms_px,
             "spatial_precision_mm": p.figures.spatial_precision_mm,
             "temporal_precision_mm": p.figures.temporal_precision_mm} for p in positions]
