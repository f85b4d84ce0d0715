"""Evaluation of the geometric procedures: checkerboard, Boehler star, x/y noise on the wall (Thesis 2024, 5.1.3-5.3).

* ``checkerboard``: corners of the stack-mean intensity image; distortion of
  the intensity image and of the point cloud (the key figures use labctl's
  radial part, what remains after the effective FOV is fitted; the raw EBU
  max deviation and the medians are reported alongside); x/y trueness (stack
  mean) and accuracy (first frame) from neighbouring corner spacings.
* ``boehler_star``: the automated Boehler-star resolution of the stack-mean
  cloud, rings binned by the point spacing on the star (``auto_binning``);
  the 72-segment star where it is resolved, else the 24-segment one (Thesis 2024, 6.3.2).
* x/y repeatability and precision: per-pixel std of x and y over the wall
  stacks of ``xy_sweep`` steps, or of ``depth_sweep`` steps when the run has no
  ``xy_sweep`` (the same wall captures).
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

from drivers.protocols import CameraInfo
from labctl.run.store import StepRecord
from metrics.boehler import BoehlerResult, analyze_boehler
from metrics.distortion import CloudDistortion, Corners, DistortionResult, cloud_distortion, detect_corners, distortion
from metrics.stack import stack_stats
from metrics.xy_error import XYErrors, XYPrecision, xy_errors, xy_precision

KEY_DISTANCE_MM = 2000.0
KEY_TOLERANCE_MM = 150.0


def _mean_cloud(step: StepRecord) -> np.ndarray:
    return np.stack([stack_stats(step.read(c)).mean for c in ("x", "y", "z")], axis=-1)


def _distance(step: StepRecord) -> float:
    reference = step.attrs.get("reference_distance_mm", math.nan)
    return float(reference) if math.isfinite(reference) else float(step.attrs.get("distance_mm", math.nan))


def _placed(step: StepRecord, gap_mm: float = 0.0) -> float:
    """Where the procedure put the target: the step's camera-wall distance less the target's gap to the wall
    (for ``distance_mm = "best_focus"`` this is the best focus distance)."""
    return float(step.attrs.get("distance_mm", math.nan)) - gap_mm


@dataclass(frozen=True)
class CheckerboardResult:
    step_id: str
    distance_mm: float  # the measured reference (laser) where there is one
    placed_mm: float  # where the procedure put the board
    tile_mm: float
    image: np.ndarray
    cloud: np.ndarray
    corners: Corners
    intensity: DistortionResult
    cloud_distortion: CloudDistortion | None
    xy: XYErrors | None


@dataclass(frozen=True)
class StarResult:
    step_id: str
    segments: int
    placed_mm: float  # where the procedure put the star
    cloud: np.ndarray
    result: BoehlerResult


@dataclass
class GeometryResult:
    checkerboard: CheckerboardResult | None = None
    stars: list[StarResult] = field(default_factory=list)
    chosen_star: StarResult | None = None
    precision: list[tuple[str, float, XYPrecision]] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)


def evaluate_checkerboard(step: StepRecord, camera: CameraInfo) -> CheckerboardResult:
    """Distortion of the intensity image and of the cloud, and x/y errors, of one checkerboard step."""
    tile = float(json.loads(step.attrs.get("target_json", "{}") or "{}").get("tile_mm", 19.0))
    image = stack_stats(step.read("intensity")).mean
    cloud = _mean_cloud(step)
    corners = detect_corners(np.nan_to_num(image, nan=0.0))
    distance = _distance(step)
    intensity = distortion(corners, tile, distance, camera.fov_deg)
    cloud_result = cloud_distortion(cloud, intensity.corners, tile, camera.fov_deg)
    first = np.stack([step.frame(c, 0) for c in ("x", "y", "z")], axis=-1)
    return CheckerboardResult(step.step_id, distance, _placed(step), tile, image, cloud, intensity.corners, intensity,
                              cloud_result, xy_errors(cloud, first, intensity.corners, tile))


def evaluate_geometry(steps: Sequence[StepRecord], camera: CameraInfo,
                      progress: Callable[[str], None]) -> GeometryResult:
    """Every geometric figure the given steps allow."""
    out = GeometryResult()
    boards = [s for s in steps if s.attrs.get("procedure") == "checkerboard"]
    for step in boards[-1:]:  # the last board of the runs (a repeat after re-mounting replaces it)
        progress(f"{step.step_id} checkerboard")
        try:
            out.checkerboard = board = evaluate_checkerboard(step, camera)
            warnings = board.intensity.warnings + (board.cloud_distortion.warnings if board.cloud_distortion else ())
            out.notes.extend(f"{step.step_id}: {w}" for w in warnings)
        except ValueError as exc:
            out.notes.append(f"{step.step_id}: checkerboard not evaluated: {exc}")
    for step in (s for s in steps if s.attrs.get("procedure") == "boehler_star"):
        target = json.loads(step.attrs.get("target_json", "{}") or "{}")
        segments = int(target.get("segments", 72))
        progress(f"{step.step_id} Boehler star ({segments})")
        cloud = _mean_cloud(step)
        try:
            placed = _placed(step, float(target.get("gap_mm", 0.0)))
            out.stars.append(StarResult(step.step_id, segments, placed, cloud,
                                        analyze_boehler(cloud, segments, binning=None, fov_deg=camera.fov_deg)))
        except ValueError as exc:
            out.notes.append(f"{step.step_id}: Boehler star not evaluated: {exc}")
    resolved = [s for s in out.stars if math.isfinite(s.result.resolution_mm)]
    if resolved:
        out.chosen_star = min(resolved, key=lambda s: (s.segments != 72, s.result.resolution_mm))
    elif out.stars:
        out.notes.append("no Boehler star resolved anywhere: cloud resolution figures are null")
    walls = [s for s in steps if s.attrs.get("procedure") == "xy_sweep"] or [
        s for s in steps if s.attrs.get("procedure") == "depth_sweep"]
    for step in walls:
        progress(f"{step.step_id} x/y noise")
        out.precision.append((step.step_id, _distance(step), xy_precision(step.read("x"), step.read("y"))))
    return out


def figure_values(result: GeometryResult) -> dict[str, tuple[float, list[str]]]:
    """Key figures (docs/keyfigures.md) with their source steps."""
    figures: dict[str, tuple[float, list[str]]] = {}
    board = result.checkerboard
    if board is not None:
        src = [board.step_id]
        figures["radial_distortion_intensity_w_pct"] = (board.intensity.radial_distortion_w_pct, src)
        figures["radial_distortion_intensity_h_pct"] = (board.intensity.radial_distortion_h_pct, src)
        if board.cloud_distortion is not None:
            figures["radial_distortion_cloud_w_pct"] = (board.cloud_distortion.distortion_w_pct, src)
            figures["radial_distortion_cloud_h_pct"] = (board.cloud_distortion.distortion_h_pct, src)
        if board.xy is not None:
            figures["x_trueness_q90_mm"] = (board.xy.trueness.x_q90_mm, src)
            figures["y_trueness_q90_mm"] = (board.xy.trueness.y_q90_mm, src)
            figures["x_accuracy_q90_mm"] = (board.xy.accuracy.x_q90_mm, src)
            figures["y_accuracy_q90_mm"] = (board.xy.accuracy.y_q90_mm, src)
    if result.chosen_star is not None:
        star = result.chosen_star
        figures["cloud_resolution_h_deg"] = (star.result.angular_h_deg, [star.step_id])
        figures["cloud_resolution_v_deg"] = (star.result.angular_v_deg, [star.step_id])
    if result.precision:
        ids = [sid for sid, _, _ in result.precision]
        for axis in "xy":
            for where in ("center", "off_axis"):
                worst = np.nanmax([getattr(p, f"repeatability_{where}_{axis}_mm") for _, _, p in result.precision])
                figures[f"{axis}_repeatability_{where}_mm"] = (float(worst), ids)
        near = min(result.precision, key=lambda item: abs(item[1] - KEY_DISTANCE_MM))
        if abs(near[1] - KEY_DISTANCE_MM) <= KEY_TOLERANCE_MM:
            figures["x_precision_q90_mm"] = (near[2].precision_q90_x_mm, [near[0]])
            figures["y_precision_q90_mm"] = (near[2].precision_q90_y_mm, [near[0]])
    return figures
