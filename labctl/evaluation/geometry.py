"""Evaluation of the geometric procedures: checkerboard, Boehler star, x/y noise on the wall (Thesis 2024, 5.1.3-5.3).

* ``checkerboard``: corners of the stack-mean intensity image; distortion of
  the intensity image and of the point cloud (the key figures use labctl's
  radial part, what remains after the effective FOV is fitted; the raw EBU
  max deviation and the medians are reported alongside); x/y trueness (stack
  mean) and accuracy (first frame) from neighbouring corner spacings. The
  Type A uncertainty of the radial distortion and x/y trueness figures is a
  delete-a-group jackknife of the stack: the frames in ``JACKKNIFE_GROUPS``
  contiguous groups, each left out in turn, the corners refined again on the
  mean of the others and the six figures evaluated again; that of x/y accuracy
  the spread of the figure over the frames, each taken as the single frame
  (docs/keyfigures.md, Uncertainty).
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
from labctl.evaluation.keyfigures import FigureValue
from labctl.evaluation.uncertainty import tile_size
from labctl.run.store import StepRecord
from metrics.boehler import BoehlerResult, analyze_boehler, angular_resolution_u_deg
from metrics.distortion import (
    CloudDistortion,
    Corners,
    DistortionResult,
    bilinear_samples,
    cloud_distortion,
    detect_corners,
    distortion,
    refined_distortion,
)
from metrics.stack import StackStats, leave_group_out_means, stack_stats
from metrics.uncertainty import Component, contiguous_groups, delete_a_group_jackknife
from metrics.xy_error import (
    XYErrors,
    XYPrecision,
    single_frame_q90_spread,
    spacing_errors,
    tile_sensitivity,
    xy_errors,
    xy_precision,
)

KEY_DISTANCE_MM = 2000.0
KEY_TOLERANCE_MM = 150.0
#: contiguous groups of frames of the radial distortion's jackknife (a stack of fewer frames: one group per frame)
JACKKNIFE_GROUPS = 10
#: the budget component of the radial distortion figures
JACKKNIFE_COMPONENT = "frames: delete-a-group jackknife of the stack (Type A)"
#: the replicates' corners are refined until they move by less than this (px): the detector's 1e-4 px is about
#: what a replicate's corners differ from the full stack's by, and stopping there would understate their spread
JACKKNIFE_TOLERANCE_PX = 1e-6


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
    radial_uncertainty: RadialUncertainty | None = None
    xy_uncertainty: XYUncertainty | None = None


@dataclass(frozen=True)
class RadialUncertainty:
    """Type A standard uncertainties (%) of the four radial distortion figures: the delete-a-group jackknife of
    the stack over ``groups`` groups of frames (NaN where fewer than two of its replicates could be evaluated)."""

    intensity_w_pct: float
    intensity_h_pct: float
    cloud_w_pct: float
    cloud_h_pct: float
    groups: int


@dataclass(frozen=True)
class XYUncertainty:
    """Type A standard uncertainties (mm) of the x/y trueness Q90 (the delete-a-group jackknife of the stack) and
    accuracy Q90 (the figure's spread over the frames, each taken as the single frame): NaN where not evaluated."""

    trueness_x_mm: float
    trueness_y_mm: float
    accuracy_x_mm: float
    accuracy_y_mm: float


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


@dataclass(frozen=True)
class _Channel:
    """One channel of a stack, read once: its mean, its first frame, its means without each group of frames and
    every frame's values at the corners."""

    mean: np.ndarray
    first: np.ndarray
    left_out: np.ndarray | None
    at_corners: np.ndarray | None = None


def _read_channel(step: StepRecord, channel: str, groups: list[range] | None, buffer: np.ndarray | None,
                  uv: np.ndarray | None = None) -> tuple[_Channel, np.ndarray]:
    """The channel's :class:`_Channel` (``left_out`` None without ``groups``, ``at_corners`` the (N, M) values
    of its N frames at the M corners ``uv``, None without them) and the buffer it was read into."""
    buffer = step.read(channel, out=buffer)
    left_out = leave_group_out_means(buffer, groups) if groups else None
    at_corners = None if uv is None else bilinear_samples(np.moveaxis(buffer, 0, -1), uv).T
    return _Channel(stack_stats(buffer).mean, buffer[0].copy(), left_out, at_corners), buffer


def evaluate_checkerboard(step: StepRecord, camera: CameraInfo) -> CheckerboardResult:
    """Distortion of the intensity image and of the cloud, x/y errors, and the Type A uncertainties of the radial
    distortion and x/y trueness (the delete-a-group jackknife of the stack) and of the x/y accuracy (its spread
    over the frames), of one checkerboard step. Each channel is read once: its mean, its first frame, its means
    without each group of frames and its frames' values at the corners come from the same read."""
    tile = float(json.loads(step.attrs.get("target_json", "{}") or "{}").get("tile_mm", 19.0))
    frames = int(step.group["intensity"].shape[0])
    groups = contiguous_groups(frames, min(JACKKNIFE_GROUPS, frames)) if frames >= 2 else None
    intensity_channel, buffer = _read_channel(step, "intensity", groups, None)
    image = intensity_channel.mean
    corners = detect_corners(np.nan_to_num(image, nan=0.0))
    distance = _distance(step)
    intensity = distortion(corners, tile, distance, camera.fov_deg)
    replicas = [] if intensity_channel.left_out is None else [
        _replica(np.nan_to_num(left_out, nan=0.0), corners, tile, distance, camera.fov_deg)
        for left_out in intensity_channel.left_out]
    del intensity_channel
    xyz = []
    for c in ("x", "y", "z"):
        channel, buffer = _read_channel(step, c, groups, buffer, intensity.corners.uv if c in "xy" else None)
        xyz.append(channel)
    del buffer
    cloud = np.stack([c.mean for c in xyz], axis=-1)
    cloud_result = cloud_distortion(cloud, intensity.corners, tile, camera.fov_deg)
    first = np.stack([c.first for c in xyz], axis=-1)
    radial_u = xy_u = None
    if groups is not None:
        rows = np.array([_replicate_figures(replica, xyz, g, tile, camera.fov_deg) for g, replica in enumerate(replicas)])
        jackknife = delete_a_group_jackknife(rows)
        radial_u = RadialUncertainty(*jackknife[:4], groups=len(groups))
        xy_u = XYUncertainty(*jackknife[4:], *single_frame_q90_spread(xyz[0].at_corners, xyz[1].at_corners,
                                                                      intensity.corners, tile))
    return CheckerboardResult(step.step_id, distance, _placed(step), tile, image, cloud, intensity.corners, intensity,
                              cloud_result, xy_errors(cloud, first, intensity.corners, tile), radial_u, xy_u)


def _replica(image: np.ndarray, corners: Corners, tile_mm: float, distance_mm: float,
             fov_deg: tuple[float, float]) -> DistortionResult | None:
    """The intensity image's distortion of one jackknife replicate (None where its corners do not refine)."""
    try:
        return refined_distortion(image, corners, tile_mm, distance_mm, fov_deg, JACKKNIFE_TOLERANCE_PX)
    except ValueError:
        return None


def _replicate_figures(replica: DistortionResult | None, xyz: list[_Channel], g: int, tile_mm: float,
                       fov_deg: tuple[float, float]) -> tuple[float, ...]:
    """The four radial distortion figures and the x and y trueness Q90 of jackknife replicate ``g`` (NaN where
    they cannot be evaluated)."""
    if replica is None:
        return (math.nan,) * 6
    cloud = np.stack([c.left_out[g] for c in xyz], axis=-1)
    trueness = spacing_errors(cloud, replica.corners, tile_mm)
    try:
        cloud_result = cloud_distortion(cloud, replica.corners, tile_mm, fov_deg)
        cloud_figures = (cloud_result.distortion_w_pct, cloud_result.distortion_h_pct)
    except ValueError:
        cloud_figures = (math.nan, math.nan)
    return (replica.radial_distortion_w_pct, replica.radial_distortion_h_pct, *cloud_figures,
            trueness.x_q90_mm, trueness.y_q90_mm)


def evaluate_geometry(steps: Sequence[StepRecord], camera: CameraInfo, progress: Callable[[str], None],
                      precision: list[tuple[str, float, XYPrecision]] | None = None) -> GeometryResult:
    """Every geometric figure the given steps allow; ``precision``: the x/y noise of the walls
    (:func:`noise_walls`) where the caller took it already while reading their stacks (:func:`wall_noise`)."""
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
    if precision is not None:
        out.precision = precision
        return out
    walls = noise_walls(steps)
    key = precision_key(walls)
    for step in walls:
        progress(f"{step.step_id} x/y noise")
        out.precision.append(wall_noise(step, step.read("x"), step.read("y"), key))
    return out


def noise_walls(steps: Sequence[StepRecord]) -> list[StepRecord]:
    """The wall steps the x/y noise is taken on: the ``xy_sweep`` steps, else the ``depth_sweep`` steps."""
    return [s for s in steps if s.attrs.get("procedure") == "xy_sweep"] or [
        s for s in steps if s.attrs.get("procedure") == "depth_sweep"]


def precision_key(walls: Sequence[StepRecord]) -> StepRecord | None:
    """The wall step the x/y precision figures come from (nearest 2000 mm), whose Q90s get their uncertainties."""
    return min(walls, key=lambda s: abs(_distance(s) - KEY_DISTANCE_MM), default=None)


def wall_noise(step: StepRecord, x: np.ndarray, y: np.ndarray, key: StepRecord | None,
               stats: tuple[StackStats, StackStats] | None = None) -> tuple[str, float, XYPrecision]:
    """The x/y noise of one wall step from its (N, H, W) ``x`` and ``y`` stacks (the precision Q90s' uncertainties
    at the ``key`` step of :func:`precision_key`), as :attr:`GeometryResult.precision` lists it; ``stats``: the
    stacks' :func:`~metrics.stack.stack_stats` where already computed."""
    return step.step_id, _distance(step), xy_precision(x, y, q90_uncertainty=step is key, stats=stats)


def _xy_figures(xy: XYErrors, u: XYUncertainty | None, tile_mm: float, src: list[str]) -> dict[str, FigureValue]:
    """The x/y trueness and accuracy Q90 with their budgets: the frames' Type A component ``u`` and the tile
    size's (:func:`labctl.evaluation.uncertainty.tile_size` through the Q90's sensitivity to the tile, GUM
    5.1.3); empty (not estimated) without ``u``."""
    figures = {}
    for kind, errors, label in (("trueness", xy.trueness, JACKKNIFE_COMPONENT),
                                ("accuracy", xy.accuracy, "frames: spread of the single frame (Type A)")):
        for axis in "xy":
            budget: tuple[Component, ...] = ()
            if u is not None:
                tile = tile_size(tile_mm)
                budget = (Component(label, getattr(u, f"{kind}_{axis}_mm")),
                          Component(tile.name, tile.value * abs(tile_sensitivity(getattr(errors, f"{axis}_errors")))))
            figures[f"{axis}_{kind}_q90_mm"] = FigureValue(getattr(errors, f"{axis}_q90_mm"), src, budget)
    return figures


def figure_values(result: GeometryResult) -> dict[str, FigureValue]:
    """Key figures (docs/keyfigures.md) with their source steps and uncertainty budgets (the radial distortion
    and x/y trueness figures': the jackknife of the stack; x/y accuracy: its spread over the frames; those of
    x/y on the checkerboard with the tile size's component; the x/y noise figures' their own; the cloud
    resolution's: its ring width, :func:`metrics.boehler.angular_resolution_u_deg`)."""
    figures: dict[str, FigureValue] = {}
    board = result.checkerboard
    if board is not None:
        src = [board.step_id]
        u = board.radial_uncertainty

        def radial(value: float, part: str) -> FigureValue:
            budget = () if u is None else (Component(JACKKNIFE_COMPONENT, getattr(u, part)),)
            return FigureValue(value, src, budget)

        figures["radial_distortion_intensity_w_pct"] = radial(board.intensity.radial_distortion_w_pct, "intensity_w_pct")
        figures["radial_distortion_intensity_h_pct"] = radial(board.intensity.radial_distortion_h_pct, "intensity_h_pct")
        if board.cloud_distortion is not None:
            figures["radial_distortion_cloud_w_pct"] = radial(board.cloud_distortion.distortion_w_pct, "cloud_w_pct")
            figures["radial_distortion_cloud_h_pct"] = radial(board.cloud_distortion.distortion_h_pct, "cloud_h_pct")
        if board.xy is not None:
            figures.update(_xy_figures(board.xy, board.xy_uncertainty, board.tile_mm, src))
    if result.chosen_star is not None:
        star = result.chosen_star
        for axis in "hv":
            u = angular_resolution_u_deg(star.result, axis)
            budget = (Component(f"ring width {star.result.ring_width_mm:g} mm: resolution of the figure (Type B)",
                                u),) if math.isfinite(u) else ()
            figures[f"cloud_resolution_{axis}_deg"] = FigureValue(getattr(star.result, f"angular_{axis}_deg"),
                                                                  [star.step_id], budget)
    if result.precision:
        ids = [sid for sid, _, _ in result.precision]
        for i, axis in enumerate("xy"):
            for where in ("center", "off_axis"):
                values = [getattr(p, f"repeatability_{where}_{axis}_mm") for _, _, p in result.precision]
                worst = int(np.nanargmax(values)) if np.isfinite(values).any() else 0
                sid, _, at = result.precision[worst]
                figures[f"{axis}_repeatability_{where}_mm"] = FigureValue(float(np.nanmax(values)), ids, (Component(
                    f"frames at {sid}: the pixel's sample std (Type A)", getattr(at, f"repeatability_{where}_u_mm")[i]),))
        near = min(result.precision, key=lambda item: abs(item[1] - KEY_DISTANCE_MM))
        if abs(near[1] - KEY_DISTANCE_MM) <= KEY_TOLERANCE_MM:
            for i, axis in enumerate("xy"):
                figures[f"{axis}_precision_q90_mm"] = FigureValue(
                    getattr(near[2], f"precision_q90_{axis}_mm"), [near[0]],
                    (Component("frames: jackknife of the stack (Type A)", near[2].precision_q90_u_mm[i]),))
    return figures
