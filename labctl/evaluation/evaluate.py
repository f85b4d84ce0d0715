"""Evaluation: from run files to metrics and key figures.

Stacks are streamed one step at a time (never a whole run in memory). Several
run files of the same camera can be evaluated together; each key figure names
the steps it came from.
"""

from __future__ import annotations

import contextlib
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from labctl.blas import one_blas_thread
from labctl.errors import InputError
from labctl.evaluation.capture import CaptureResult, evaluate_captures
from labctl.evaluation.conditions import BackgroundHashes, RunConditions, run_conditions
from labctl.evaluation.depth_quality import (
    VendorPosition,
    key_steps,
    reference_flags,
    vendor_position,
    with_uncertainties,
)
from labctl.evaluation.depth_quality import figure_values as vendor_figures
from labctl.evaluation.geometry import GeometryResult, evaluate_geometry, precision_key, wall_noise
from labctl.evaluation.geometry import figure_values as geometry_figures
from labctl.evaluation.keyfigures import CameraDescription, FigureValue, clean, standard_uncertainty
from labctl.evaluation.plausibility import PlausibilityInputs, plausibility_flags
from labctl.evaluation.read_ahead import SLOTS, read_ahead
from labctl.evaluation.remission import RemissionResult, evaluate_remission
from labctl.evaluation.remission import figure_values as remission_figures
from labctl.evaluation.scenes import AlignmentRecord, FaceMaskResult, alignment, face_mask
from labctl.evaluation.sections import DepthSweepRow
from labctl.evaluation.sharpness import SharpnessResult, evaluate_slanted_edge
from labctl.evaluation.suitability import (
    FACE_DISTANCE,
    FACE_PRECISION,
    FACE_TRUENESS,
    Suitability,
    face_depth_values,
    face_wall_row,
    suitability,
)
from labctl.evaluation.uncertainty import calibrated_reference, fov_components, offset_calibration, scaled
from labctl.evaluation.vdi2634 import AcceptanceResult, evaluate_acceptance
from labctl.evaluation.vdi2634 import figure_values as acceptance_figures
from labctl.kernel_threads import every_kernel_thread, kernel_threads_beside
from labctl.run.store import RunReader, StepRecord
from metrics.depth import (
    DepthErrors,
    DepthErrorUncertainties,
    center_repeatability_uncertainty,
    depth_error_uncertainties,
    depth_errors,
)
from metrics.optics import pixel_aspect_distortion_pct, sensor_angular_resolution_deg
from metrics.plausibility import quantization_step
from metrics.sharpness import ied_pixels, ied_pixels_at_centre
from metrics.stack import StackStats, leave_group_out_means, stack_stats
from metrics.surface import SurfaceTexture, sq_jackknife, surface_texture
from metrics.uncertainty import (
    Component,
    combined_standard_uncertainty,
    contiguous_groups,
    expanded_uncertainty,
    rectangular,
)
from metrics.xy_error import XYPrecision

#: distance at which the single-position key figures are taken (docs/keyfigures.md)
KEY_DISTANCE_MM = 2000.0
#: a step counts as "at 2000 mm" when its reference lies within this distance
KEY_DISTANCE_TOLERANCE_MM = 150.0
#: contiguous groups of frames of the surface Sq's jackknife (a stack of fewer frames: one group per frame)
SURFACE_GROUPS = 10
#: the budget component of the surface Sq figures
SURFACE_COMPONENT = "frames: delete-a-group jackknife of the stack (Type A)"
#: the threads busy beside the depth sweep's compiled kernels: the read-ahead and the run files' hash
SWEEP_BACKGROUND_THREADS = 2


@dataclass(frozen=True)
class DepthPosition:
    """One wall step's depth errors and the Type A standard uncertainty of its centre repeatability."""

    step_id: str
    errors: DepthErrors
    repeatability_center_u_mm: float = math.nan


@dataclass(frozen=True)
class SurfaceResult:
    step_id: str
    reference_mm: float
    texture: SurfaceTexture


@dataclass
class Evaluation:
    runs: list[str]
    camera: CameraDescription
    depth: list[DepthPosition] = field(default_factory=list)
    vendor: list[VendorPosition] = field(default_factory=list)
    surface: SurfaceResult | None = None
    sharpness: SharpnessResult | None = None
    geometry: GeometryResult | None = None
    remission: RemissionResult | None = None
    acceptance: AcceptanceResult | None = None
    face: FaceMaskResult | None = None
    alignment: AlignmentRecord | None = None
    captures: list[CaptureResult] = field(default_factory=list)
    figures: dict[str, FigureValue] = field(default_factory=dict)
    #: the suitability checks' inputs beyond the key figures (labctl/evaluation/suitability.py: the depth figures
    #: on the face, with the face's and the wall's distance), with their uncertainty budgets
    face_depth: dict[str, FigureValue] = field(default_factory=dict)
    #: per run file, the conditions it records (labctl/evaluation/conditions.py)
    conditions: list[RunConditions] = field(default_factory=list)
    #: quantization step (mm) of the x, y and z output on the wall, NaN where continuous
    quantization_mm: dict[str, float] = field(default_factory=dict)
    #: plausibility flags per figure name (labctl/evaluation/plausibility.py)
    flags: dict[str, list[dict[str, str]]] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)


def camera_description(reader: RunReader) -> CameraDescription:
    """What keyfigures.json says about the camera."""
    dev = reader.devices.get("camera", {})
    cam = reader.camera
    return CameraDescription(
        model=dev.get("model", "unknown"), serial=dev.get("serial", "unknown"),
        firmware=dev.get("firmware", "unknown"), backend=dev.get("backend", "unknown"),
        width=cam.width, height=cam.height, fov_deg=list(cam.fov_deg), frame_rate_hz=cam.frame_rate_hz,
        wavelength_nm=cam.wavelength_nm, simulated=bool(reader.attrs.get("simulated", False)))


def _same_camera(a: CameraDescription, b: CameraDescription) -> bool:
    return (a.model, a.serial, a.width, a.height) == (b.model, b.serial, b.width, b.height)


def _key_step(steps: Sequence[StepRecord]) -> StepRecord | None:
    """The step whose reference distance is nearest 2000 mm, if within tolerance."""
    best = min(steps, key=lambda s: abs(s.attrs["reference_distance_mm"] - KEY_DISTANCE_MM), default=None)
    if best is None or not abs(best.attrs["reference_distance_mm"] - KEY_DISTANCE_MM) <= KEY_DISTANCE_TOLERANCE_MM:
        return None
    return best


def _detect_quantization(found: dict[str, float], z: np.ndarray, first_xy: tuple[np.ndarray, np.ndarray]) -> None:
    """Fill in the quantization step of x, y and z from this wall step (its z stack, its first frame's x and y)
    where no earlier step showed one (a step without valid pixels, e.g. below a camera's minimum range, shows
    none)."""
    for channel, values in (("x", first_xy[0]), ("y", first_xy[1]), ("z", z)):
        if not math.isfinite(found.get(channel, math.nan)):
            found[channel] = quantization_step(values)


@dataclass(frozen=True)
class _SurfaceInputs:
    """What the surface texture at the key step takes from its stacks: the x, y and z stack statistics and z's
    means without each group of frames (None with fewer than two frames)."""

    means: dict[str, StackStats]
    z_left_out: np.ndarray | None


@kernel_threads_beside(SWEEP_BACKGROUND_THREADS)
def evaluate_depth_sweep(
    steps: Sequence[StepRecord], reader: RunReader, evaluation: Evaluation, progress: Callable[[str], None],
    calibration: StepRecord | None = None, xy_noise: bool = False,
) -> list[tuple[str, float, XYPrecision]] | None:
    """Thesis 2024, 4.2 on the wall steps: curves over distance, key figures with their uncertainty budgets
    (``calibration``: the offset calibration the references rest on, None without one), surface at 2000 mm;
    the vendors' depth-quality figures at every distance. With ``xy_noise`` (the run has no ``xy_sweep``), the
    x/y noise of every step too (:func:`~labctl.evaluation.geometry.wall_noise`), returned for the geometry (else
    None).

    Each step's arrays are read once, up to two steps ahead of their evaluation (labctl/evaluation/read_ahead.py):
    z where the step has a reference, x and y whole where they give the x/y noise or the surface, else their first
    frames, the stacks into the buffers of the step three before (nothing of a step's arrays is kept past its
    turn but what is computed from them), each frame's chunk as stored, decompressed by Blosc
    (labctl/run/chunk_read.py). The stacks' statistics (``stack_stats``) and the figures of a step run beside the
    reading of the next (about 60 ms a step each on the 2 cores). The compiled kernels leave a core each to the
    read-ahead and the run files' hash (labctl/kernel_threads.py), but for the key steps' jackknives (about a
    second), beside which the reading runs ahead and then waits."""
    usable = [s for s in steps if math.isfinite(s.attrs.get("reference_distance_mm", math.nan))]
    if len(usable) < len(steps):
        evaluation.notes.append(
            f"{len(steps) - len(usable)} depth_sweep step(s) have no reference distance and were skipped"
        )
    key = _key_step(usable)
    key_u: DepthErrorUncertainties | None = None
    offset = offset_calibration(calibration) if calibration else ()  # the references' components: read once
    vendor_keys = set(key_steps({s.step_id: s.attrs["reference_distance_mm"] for s in usable}).values())
    with_z = {id(s) for s in usable}
    noise_key = precision_key(steps) if xy_noise else None

    buffers: list[dict[str, np.ndarray]] = [{} for _ in range(SLOTS)]  # per read-ahead slot, the stacks read

    def whole(rec: StepRecord) -> bool:
        """Whether the step's x and y are read and reduced whole (the x/y noise, the surface), not their first frame."""
        return xy_noise or rec is key

    def load(rec: StepRecord, slot: int) -> dict[str, np.ndarray]:
        def stack(channel: str) -> np.ndarray:
            buffers[slot][channel] = rec.read(channel, buffers[slot].get(channel), by_chunk=True)
            return buffers[slot][channel]

        arrays = {c: stack(c) if whole(rec) else rec.group[c][:1] for c in ("x", "y")}
        if id(rec) in with_z:
            arrays["z"] = stack("z")
        return arrays

    noise: list[tuple[str, float, XYPrecision]] | None = [] if xy_noise else None
    surface: _SurfaceInputs | None = None
    for rec, arrays in read_ahead(steps if xy_noise else usable, load):
        progress(rec.step_id)
        all_stats = {c: stack_stats(arrays[c]) for c in (("x", "y", "z") if whole(rec) else ("z",)) if c in arrays}
        if id(rec) in with_z:
            z = arrays["z"]
            first_xy = (arrays["x"][0], arrays["y"][0])
            _detect_quantization(evaluation.quantization_mm, z, first_xy)
            stats = all_stats["z"]
            errors = depth_errors(stats, z[0], rec.attrs["reference_distance_mm"])
            if rec is key:  # its jackknives take about a second: every core, the reading having run ahead meanwhile
                reference_u = combined_standard_uncertainty(calibrated_reference(rec.attrs, offset))
                frames = z.shape[0]
                with every_kernel_thread():
                    key_u = depth_error_uncertainties(z, stats, rec.attrs["reference_distance_mm"], reference_u)
                    surface = _SurfaceInputs(
                        {"x": all_stats["x"], "y": all_stats["y"], "z": stats},
                        leave_group_out_means(z, contiguous_groups(frames, min(SURFACE_GROUPS, frames)))
                        if frames >= 2 else None)
            evaluation.depth.append(DepthPosition(rec.step_id, errors, center_repeatability_uncertainty(stats)))
            position = vendor_position(rec, z, first_xy, reader.camera, evaluation.camera.model)
            if rec.step_id in vendor_keys:  # the steps the vendor key figures come from: their uncertainties too
                position = with_uncertainties(position, rec, z, first_xy, reader.camera, evaluation.camera.model)
            evaluation.vendor.append(position)
        if noise is not None:
            progress(f"{rec.step_id} x/y noise")
            with every_kernel_thread() if rec is noise_key else contextlib.nullcontext():  # jackknives: as the key step's
                noise.append(wall_noise(rec, arrays["x"], arrays["y"], noise_key, (all_stats["x"], all_stats["y"])))
        del arrays, all_stats
    _depth_figures(evaluation, key, key_u, surface, offset, progress)
    return noise


def _depth_figures(evaluation: Evaluation, key: StepRecord | None, key_u: DepthErrorUncertainties | None,
                   surface: _SurfaceInputs | None, offset: tuple[Component, ...],
                   progress: Callable[[str], None]) -> None:
    """The depth sweep's key figures from its positions (``offset``: the offset calibration's components, empty
    without one), and the surface texture at the ``key`` step."""
    missing = [p for p in evaluation.vendor if p.missing_reference]
    if missing:
        reasons = "; ".join(sorted({p.missing_reference for p in missing}))
        evaluation.notes.append(f"{len(missing)} depth_sweep step(s) have no absolute reference ({reasons}): the "
                                "Depth Quality Tool's Z accuracy is null there (docs/campaign.md, Reference distance)")
    evaluation.figures.update(vendor_figures(evaluation.vendor))
    if not evaluation.depth:
        return
    figures = evaluation.figures
    repeat = [p for p in evaluation.depth if math.isfinite(p.errors.repeatability_center_mm)]
    if repeat:
        worst = max(repeat, key=lambda p: p.errors.repeatability_center_mm)
        figures["z_repeatability_center_mm"] = FigureValue(
            worst.errors.repeatability_center_mm, [p.step_id for p in evaluation.depth],
            (Component(f"frames at {worst.step_id}: centre pixel's sample std (Type A)", worst.repeatability_center_u_mm),)
        )
    if key is None or key_u is None or surface is None:
        evaluation.notes.append("no depth_sweep step within 150 mm of 2000 mm: single-position figures are null")
        return
    at_key = next(p for p in evaluation.depth if p.step_id == key.step_id).errors
    reference = calibrated_reference(key.attrs, offset)
    for name, value, budget in (
        ("z_trueness_q90_mm", at_key.trueness_q90_mm,
         _with_reference(Component("frames: jackknife of the stack (Type A)", key_u.trueness_q90_mm),
                         scaled(reference, abs(key_u.trueness_reference_sensitivity)))),
        ("z_accuracy_q90_mm", at_key.accuracy_q90_mm,
         _with_reference(Component("frames: spread of the single frame (Type A)", key_u.accuracy_q90_mm),
                         scaled(reference, abs(key_u.accuracy_reference_sensitivity)))),
        ("z_precision_q90_mm", at_key.precision_q90_mm,
         (Component("frames: jackknife of the stack (Type A)", key_u.precision_q90_mm),)),
    ):
        figures[name] = FigureValue(value, [key.step_id], budget)
    progress(f"{key.step_id} surface")
    means, z_left_out = surface.means, surface.z_left_out
    valid = means["z"].valid & means["x"].valid & means["y"].valid
    try:
        texture = surface_texture(means["x"].mean, means["y"].mean, means["z"].mean, valid)
    except ValueError as exc:
        evaluation.notes.append(f"surface texture at {key.step_id} not evaluated: {exc}")
        return
    evaluation.surface = SurfaceResult(key.step_id, key.attrs["reference_distance_mm"], texture)
    u = (sq_jackknife(means["x"].mean, means["y"].mean, z_left_out, valid, texture.cutoff_mm)
         if z_left_out is not None else (math.nan,) * 3)
    for name, value, u_sq in (
        ("surface_primary_sq_mm", texture.sq_primary_mm, u[0]),
        ("surface_waviness_sq_mm", texture.sq_waviness_mm, u[1]),
        ("surface_roughness_sq_mm", texture.sq_roughness_mm, u[2]),
    ):
        figures[name] = FigureValue(value, [key.step_id], (Component(SURFACE_COMPONENT, u_sq),))


def _with_reference(frames: Component, reference: tuple[Component, ...]) -> tuple[Component, ...]:
    """The budget of a figure measured against the reference: the frames' component and the reference's; empty
    (not estimated) where the reference's uncertainty is not known."""
    return (frames, *reference) if reference else ()


def evaluate_sharpness(steps: Sequence[StepRecord], reader: RunReader, evaluation: Evaluation,
                       progress: Callable[[str], None]) -> None:
    """Thesis 2024, 5.1.2 figures from the slanted-edge steps."""
    result = evaluate_slanted_edge(steps, reader.camera, progress)
    if result is None:
        evaluation.notes.append("slanted_edge steps without white references: sharpness figures are null")
        return
    evaluation.sharpness = result
    evaluation.notes.extend(result.notes)
    ids = [p.chart_step for p in result.positions] + [p.white_step for p in result.positions]
    best = [p.chart_step for p in result.positions if p.distance_mm == result.best_focus_mm]
    hyperfocal = _position_budget(result.hyperfocal_spacing_mm)
    fov, width, d = reader.camera.fov_deg, reader.camera.width, result.hyperfocal_mm
    ied_fov = fov_components(lambda h, v: ied_pixels_at_centre(h, width, d), fov) if hyperfocal else ()
    ied_angular_fov = (fov_components(lambda h, v: ied_pixels(sensor_angular_resolution_deg(h, width), d), fov)
                       if hyperfocal else ())
    for name, value, source, budget in (
        ("hyperfocal_distance_mm", result.hyperfocal_mm, ids, hyperfocal),
        ("best_focus_distance_mm", result.best_focus_mm, ids,
         _position_budget(result.best_focus_spacing_mm) if result.focus_warning is None else ()),
        ("intensity_resolution_h_deg", result.resolution_deg[0], best,
         _resolution_budget(result.resolution_u_deg[0], result.resolution_deg[0], 0, fov)),
        ("intensity_resolution_v_deg", result.resolution_deg[1], best,
         _resolution_budget(result.resolution_u_deg[1], result.resolution_deg[1], 1, fov)),
        ("ied_pixels_at_hyperfocal", result.ied_px, ids,
         (*scaled(hyperfocal, result.ied_px / result.hyperfocal_mm), *ied_fov)),
        ("ied_pixels_at_hyperfocal_angular", result.ied_px_angular, ids,
         (*scaled(hyperfocal, result.ied_px_angular / result.hyperfocal_mm), *ied_angular_fov)),
    ):
        evaluation.figures[name] = FigureValue(value, source, budget)


def _resolution_budget(u_deg: float, resolution_deg: float, axis: int,
                       fov_deg: tuple[float, float]) -> tuple[Component, ...]:
    """The budget of an intensity resolution: the SFR10's jackknife over the chart's and white sheet's frames at
    best focus, through the sensitivity resolution / SFR10 (GUM 5.1.3); and the FOV's tolerance, the resolution
    being the sensor's angular resolution FOV / pixels over the SFR10, so proportional to the FOV angle of its
    ``axis`` (0: horizontal, 1: vertical). Empty (not estimated) where the jackknife is not."""
    if not math.isfinite(u_deg):
        return ()
    return (Component("frames: delete-a-group jackknife of the SFR10 at best focus (Type A)", u_deg),
            *fov_components(lambda h, v: resolution_deg * (h, v)[axis] / fov_deg[axis], fov_deg))


def _position_budget(spacing_mm: float) -> tuple[Component, ...]:
    """The budget of a distance the slanted-edge sweep reports (hyperfocal, best focus): the sweep's spacing at
    it as the resolution of the figure (rectangular over one spacing, GUM F.2.2.1); empty (not estimated) where
    the figure is a bound (the sweep's nearest valid position; best focus at an end of the sweep). The IED
    counts (62.5 mm f / d) take the hyperfocal distance's with the sensitivity |dIED/dd| = IED / d (GUM 5.1.3)."""
    if not math.isfinite(spacing_mm):
        return ()
    return (Component("sweep spacing at the position: resolution of the figure (Type B)", rectangular(spacing_mm / 2)),)


def evaluate_face_depth(steps: Sequence[StepRecord], evaluation: Evaluation, progress: Callable[[str], None],
                        calibration: StepRecord | None = None) -> None:
    """The depth precision and trueness the suitability checks read on the face (the wall step
    :func:`~labctl.evaluation.suitability.face_wall_row` chooses), with the budgets of the key figures of the same
    name: the jackknife over the stack's frames, and for trueness the reference's components through its
    sensitivity (``calibration``: the offset calibration the references rest on)."""
    values = {name: f.value for name, f in evaluation.figures.items()}
    rows = depth_table(evaluation)
    row = face_wall_row(values, rows)
    if row is None:
        return
    step = next(s for s in steps if s.step_id == row["step"])
    progress(f"{step.step_id} depth on the face")
    z = step.read("z")
    reference = calibrated_reference(step.attrs, offset_calibration(calibration) if calibration else ())
    u = depth_error_uncertainties(z, stack_stats(z), step.attrs["reference_distance_mm"],
                                  combined_standard_uncertainty(reference))
    jackknife = "frames: jackknife of the stack (Type A)"
    budgets = {FACE_PRECISION: (Component(jackknife, u.precision_q90_mm),),
               FACE_TRUENESS: _with_reference(Component(jackknife, u.trueness_q90_mm),
                                              scaled(reference, abs(u.trueness_reference_sensitivity)))}
    sources = {FACE_DISTANCE: evaluation.figures["hyperfocal_distance_mm"].source}
    evaluation.face_depth = {name: FigureValue(value, sources.get(name, [step.step_id]), budgets.get(name, ()))
                             for name, value in face_depth_values(values, rows).items()}


def judged_suitability(evaluation: Evaluation) -> Suitability:
    """The suitability verdicts (labctl/evaluation/suitability.py) on the key figures and the face's depth
    figures, each check decided with the expanded uncertainties (k = 2) of the figures that state one."""
    inputs = {**evaluation.figures, **evaluation.face_depth}
    values = {name: clean(f.value) for name, f in inputs.items()}
    standard = {name: standard_uncertainty(f) for name, f in inputs.items()}
    return suitability(values, {name: None if u is None else expanded_uncertainty(u) for name, u in standard.items()})


def count_complete_steps(paths: Sequence[str | Path]) -> int:
    """Complete steps over the run files (the evaluation's unit of progress)."""
    total = 0
    for path in paths:
        with RunReader(path) as reader:
            total += len(reader.steps())
    return total


@one_blas_thread
def evaluate_runs(paths: Sequence[str | Path], progress: Callable[[str], None] = lambda _: None) -> Evaluation:
    """Every metric the given runs allow (all runs must come from one camera)."""
    if not paths:
        raise InputError("no run file given")
    readers = [RunReader(p) for p in paths]
    with contextlib.ExitStack() as stack:
        for reader in readers:
            stack.callback(reader.close)
        camera = camera_description(readers[0])
        for reader in readers[1:]:
            other = camera_description(reader)
            if not _same_camera(camera, other):
                raise InputError(
                    f"{reader.path} is from camera {other.model} {other.serial}, "
                    f"{readers[0].path} from {camera.model} {camera.serial}: evaluate one camera at a time"
                )
        evaluation = Evaluation(runs=[str(r.path) for r in readers], camera=camera)
        hashes = stack.enter_context(BackgroundHashes([r.path for r in readers]))
        cam = readers[0].camera
        evaluation.figures["pixel_aspect_distortion_pct"] = FigureValue(
            pixel_aspect_distortion_pct(cam.fov_deg[0], cam.fov_deg[1], cam.width, cam.height), [],
            fov_components(lambda h, v: pixel_aspect_distortion_pct(h, v, cam.width, cam.height), cam.fov_deg),
        )
        for reader in readers:
            if reader.attrs.get("status") != "complete":
                evaluation.notes.append(f"{reader.path} is {reader.attrs.get('status')}: only its complete steps are used")
        captures = [s for r in readers for s in r.steps("capture")]
        if captures:
            evaluation.captures = evaluate_captures(captures, progress)
        sweep = [s for r in readers for s in r.steps("depth_sweep")]
        calibrations = [s for r in readers for s in r.steps("offset_calibration")]
        calibration = calibrations[-1] if calibrations else None
        geometric = [s for r in readers for s in r.steps()
                     if s.attrs.get("procedure") in ("checkerboard", "boehler_star", "xy_sweep", "depth_sweep")]
        noise = None  # the x/y noise of the walls, where they are the depth sweep's and it reads them
        if sweep:
            xy_noise = not any(s.attrs.get("procedure") == "xy_sweep" for s in geometric)  # noise_walls: the sweep's
            noise = evaluate_depth_sweep(sweep, readers[0], evaluation, progress, calibration, xy_noise)
        elif captures:
            evaluation.notes.append("capture steps only (no reference distance): the key figures are null; see "
                                    "the capture section for depth, noise, validity and the plane fit")
        else:
            evaluation.notes.append("no depth_sweep steps: depth figures are null")
        edges = [s for r in readers for s in r.steps("slanted_edge")]
        if edges:
            evaluate_sharpness(edges, readers[0], evaluation, progress)
        if sweep:
            evaluate_face_depth(sweep, evaluation, progress, calibration)
        if geometric:
            evaluation.geometry = evaluate_geometry(geometric, readers[0].camera, progress, noise)
            evaluation.notes.extend(evaluation.geometry.notes)
            evaluation.figures.update(geometry_figures(evaluation.geometry))
        plates = [s for r in readers for s in r.steps("remission_angle")]
        if plates:
            evaluation.remission = evaluate_remission(plates, readers[0].camera, progress)
            if evaluation.remission is not None:
                evaluation.notes.extend(evaluation.remission.notes)
                evaluation.figures.update(remission_figures(evaluation.remission))
        artefacts = [s for r in readers for s in r.steps() if s.attrs.get("procedure") in ("sphere_bar", "flatness")]
        if artefacts:
            evaluation.acceptance = evaluate_acceptance(artefacts, readers[0].camera, progress)
            evaluation.notes.extend(evaluation.acceptance.notes)
            evaluation.figures.update(acceptance_figures(evaluation.acceptance))
        masks = [s for r in readers for s in r.steps("face_mask")]
        if masks:
            progress(f"{masks[-1].step_id} face mask")
            face = face_mask(masks[-1])
            if face.invalid_fraction < 1.0:
                evaluation.face = face
            else:
                evaluation.notes.append(f"face mask {face.step_id} has no valid point: no point cloud or rendering")
        aligned = [a for a in (alignment(s) for r in readers for s in r.steps("alignment")) if a is not None]
        evaluation.alignment = aligned[-1] if aligned else None
        inputs = PlausibilityInputs(evaluation.sharpness, evaluation.quantization_mm,
                                    evaluation.geometry.precision if evaluation.geometry else [], _noise(evaluation))
        evaluation.flags = plausibility_flags({n: f.value for n, f in evaluation.figures.items()}, inputs)
        for name, flag in reference_flags(evaluation.vendor).items():
            evaluation.flags.setdefault(name, []).append(flag)
        steps = {c: q for c, q in evaluation.quantization_mm.items() if math.isfinite(q)}
        if steps:
            evaluation.notes.append("the wall data are quantized (" + ", ".join(
                f"{c} in steps of {q:g} mm" for c, q in sorted(steps.items())) + "): spreads and errors below a "
                "step are largely rounding (see the flags)")
        evaluation.conditions = [run_conditions(r, h) for r, h in zip(readers, hashes.results())]
        return evaluation


def _noise(evaluation: Evaluation) -> dict[str, float]:
    """Median per-pixel noise where the stack-mean figures are taken: z on the wall at 2000 mm, x and y on
    the wall step nearest the checkerboard (for the plausibility of stack means, labctl/evaluation/plausibility.py)."""
    noise: dict[str, float] = {}
    at_key = [p for p in evaluation.depth if abs(p.errors.reference_mm - KEY_DISTANCE_MM) <= KEY_DISTANCE_TOLERANCE_MM]
    if at_key:
        noise["z"] = min(at_key, key=lambda p: abs(p.errors.reference_mm - KEY_DISTANCE_MM)).errors.precision_median_mm
    geo = evaluation.geometry
    if geo is not None and geo.precision and geo.checkerboard is not None:
        board = geo.checkerboard.distance_mm
        _, _, near = min(geo.precision, key=lambda item: abs(item[1] - board))
        noise.update(x=near.precision_median_x_mm, y=near.precision_median_y_mm)
    return noise


def depth_table(evaluation: Evaluation) -> list[DepthSweepRow]:
    """Per-position depth errors as rows (for the report and JSON consumers)."""
    rows: list[DepthSweepRow] = []
    for p in evaluation.depth:
        e = p.errors
        rows.append({
            "step": p.step_id,
            "reference_mm": e.reference_mm,
            "trueness_median_mm": e.trueness_median_mm,
            "trueness_q90_mm": e.trueness_q90_mm,
            "accuracy_median_mm": e.accuracy_median_mm,
            "accuracy_q90_mm": e.accuracy_q90_mm,
            "precision_median_mm": e.precision_median_mm,
            "precision_q90_mm": e.precision_q90_mm,
            "repeatability_center_mm": e.repeatability_center_mm,
            "invalid_fraction": e.invalid_fraction,
        })
    return rows

