"""Checkerboard corner positions as residual families of the reconcile (docs/reconcile.md).

What the depth and intensity comparison cannot see, a checkerboard shows:
where features land in the image. Of every ``checkerboard`` step the inner
corners are found in the stack-mean intensity image (metrics/distortion.py,
the evaluation's detector) and refined again in each of the first
``MAX_FRAMES`` frames (``refine_corners``); their mean is the measured
position, the scatter over the frames gives the variance of that mean. The
simulation re-creates each corner from the board's geometry: the tile corner
(i, j) of the board (``tile_mm``, its ``offset_mm``, 0.2 mm in front of the
wall) through the model's true optics (pinhole of the true FOV, Brown radial
distortion: sim/sensor.py ``SensorOptics``) to its image position, and the
model's reported ray there (the slope x/z, y/z the camera gives that pixel).

Two families, both in mm in the board plane:

* ``corner_image``: measured minus simulated image position, converted from
  px by the board distance over the datasheet focal length (Z / f_x, Z / f_y);
  the px figures are reported beside it;
* ``corner_cloud``: measured minus simulated lateral position of the corner in
  the point cloud, as the slope x/z, y/z (the cloud sampled bilinearly at the
  measured corner, Thesis 2024, 5.2.2) times the board distance. A range error
  moves points along their rays, so it leaves this family alone. As the cloud
  is read where the corner was found, the image position's error enters it
  too: with rays as the pinhole's (no distortion, or one left in the cloud) the
  two families agree; with the distortion corrected in the cloud the cloud
  family stays at the true position while the image family moves.

The board's placement is what a lab does not know to a fraction of a pixel:
per step and family a lateral shift (two) and an in-plane rotation about the
optical axis (one), and per reference group (laser, stage) an error dZ of the
board distance (the camera's mounting offset: it scales a step's corners by
-dZ / Z in both families) are profiled out by weighted least squares. A FOV
error moves the image corners only, so the cloud family pins dZ and one board
distance determines the FOV; several distances separate them also by their
scaling (a FOV error alike at every distance, dZ by 1 / Z).

Weights and floor: every corner axis has the variance of its mean from the
frames plus a comparison floor (``CORNER_FLOOR_PX`` in the image: the
analytic projection against the detector on a blurred, pixel-integrated
image; 0.05 px RMS on simulated boards with nothing hidden, 0.03 px at
640 x 480). The cloud rows carry the image position's variance and floor as
well (the cloud is read at the found corner) plus ``SLOPE_FLOOR`` in slope. The family's gap is the RMS
of the systematic residual sqrt(max(0, mean(r^2 - var))), its floor
sqrt(mean(var + floor^2)); consistency as for depth (labctl/reconcile/goodness.py:
gap at most floor and no step above ``STEP_FACTOR`` floors).

Candidates: the effects whose declaration says how the corners show them
(``Observed.corners``, sim/effects/base.py): ``radial_distortion`` (k1 of
r_d = r_u (1 + k1 (r_u / R)^2), with the distortion in the cloud or not,
whichever the cloud family supports) and ``fov_error`` (the true horizontal
and vertical FOV); those with fewer parameters first. Each is fitted by
nonlinear least squares on the whitened, profiled residual of both families
(scipy.optimize.least_squares; the predictions are analytic, so a fit costs
milliseconds). The corners are the replications: the score is Schwarz's
criterion over them, sum over (step, family) cells of n ln(RSS_0 / RSS_1)
minus k ln(N) (N corner axes), and standard errors are (J'J)^-1 RSS / (N - k).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy import ndimage, optimize

from labctl.reconcile.goodness import STEP_FACTOR, StepFit, rounded, steps_above_floor
from labctl.reconcile.observe import MAX_FRAMES, StepScene, opened_run, step_scene
from labctl.reconcile.results import CornerFamilyGoodness, CornerGoodnessSummary, Parameters
from labctl.run.store import RunReader, StepRecord
from metrics.distortion import Corners, detect_corners, refine_corners, sample_cloud
from metrics.stack import stack_stats
from sim.effects import EFFECTS, Effect
from sim.geometry import Pose
from sim.model import SimModel
from sim.sensor import SensorOptics

CORNER_FLOOR_PX = 0.1  # analytic projection against the detector, twice its null RMS (bench/reconcile_null.py)
SLOPE_FLOOR = 5e-5  # the same in the cloud, as slope x/z (0.05 mm at 1 m)
BOARD_GAP_MM = 0.2  # the board stands this far in front of the wall (sim/scenes/targets.py)
MIN_FRAMES = 2  # the corners' scatter over the stack, part of their floor, needs two frames
MIN_TILE_PX = 6.0  # below, cornerSubPix's window (0.4 tile) is 2 px and the grid's labels become unreliable
FAMILIES = ("corner_image", "corner_cloud")
FAMILY_UNIT = "mm in the board plane"


@dataclass(frozen=True)
class CornerObservation:
    """The corners of one checkerboard step: board index, mean image position and cloud slope, their variances."""

    scene: StepScene
    board_ij: np.ndarray  # (N, 2) tile corner index on the board, (0, 0) at the board's centre
    uv: np.ndarray  # (N, 2) stack-mean image position, px (OpenCV: pixel centres at integers)
    uv_var: np.ndarray  # (N, 2) variance of that mean, px^2
    slope: np.ndarray  # (N, 2) x/z and y/z of the stack-mean cloud at the corner
    slope_var: np.ndarray  # (N, 2) variance of that mean
    tile_mm: float
    offset_mm: tuple[float, float]
    plane_mm: float  # camera to board

    @property
    def step_id(self) -> str:
        return self.scene.step_id


def _board_index(corners: Corners, tile_mm: float, offset_mm: tuple[float, float], plane_mm: float,
                 fov_deg: tuple[float, float]) -> np.ndarray:
    """The board index of every detected corner: the detector counts from the corner nearest the image centre,
    whose board index follows from its position through the datasheet pinhole."""
    h, w = corners.image_shape
    fx, fy = (w / 2) / math.tan(math.radians(fov_deg[0]) / 2), (h / 2) / math.tan(math.radians(fov_deg[1]) / 2)
    u, v = corners.centre_uv
    i0 = round(((u - (w - 1) / 2) / fx * plane_mm - offset_mm[0]) / tile_mm)
    j0 = round(((v - (h - 1) / 2) / fy * plane_mm - offset_mm[1]) / tile_mm)
    return corners.ij + np.array([i0, j0])


def observe_corners(step: StepRecord, scene: StepScene, fov_deg: tuple[float, float],
                    max_frames: int = MAX_FRAMES) -> CornerObservation | None:
    """The corners of one checkerboard step (None when no board is found, its tiles are under ``MIN_TILE_PX``
    or the stack has under ``MIN_FRAMES`` frames)."""
    n = min(int(step.group["intensity"].shape[0]), max_frames)
    if n < MIN_FRAMES or scene.wall_distance_mm is None:
        return None
    frames = np.asarray(step.group["intensity"][:n], np.float64)
    try:
        corners = detect_corners(np.nan_to_num(stack_stats(frames).mean, nan=0.0))
    except ValueError:
        return None
    if min(np.abs(corners.tile_px)) < MIN_TILE_PX:
        return None
    uv = np.stack([refine_corners(frame, corners) for frame in frames])  # (n, N, 2)
    cloud = np.stack([np.asarray(step.group[c][:n], np.float64) for c in ("x", "y", "z")], axis=-1)
    mean_uv = np.nanmean(uv, axis=0) if np.isfinite(uv).any() else corners.uv
    samples = np.stack([sample_cloud(frame, mean_uv) for frame in cloud])  # (n, N, 3)
    with np.errstate(invalid="ignore", divide="ignore"):
        slope = samples[..., :2] / samples[..., 2:3]
    ok = np.isfinite(uv).all(axis=(0, 2)) & np.isfinite(slope).all(axis=(0, 2))
    if ok.sum() < 3:
        return None
    tile = float(scene.target_params.get("tile_mm", 19.0))
    offset = tuple(float(v) for v in scene.target_params.get("offset_mm", (0.0, 0.0)))
    plane = float(scene.wall_distance_mm) - BOARD_GAP_MM
    board = _board_index(corners, tile, offset, plane, fov_deg)[ok]
    return CornerObservation(scene, board, uv[:, ok].mean(0), uv[:, ok].var(0, ddof=1) / n,
                             slope[:, ok].mean(0), slope[:, ok].var(0, ddof=1) / n, tile, offset, plane)


def observe_corner_run(path: str | Path | RunReader, fov_deg: tuple[float, float],
                       max_frames: int = MAX_FRAMES) -> tuple[list[CornerObservation], list[str]]:
    """The corner observations of every checkerboard step of the run at ``path`` (or open in it: ``opened_run``),
    and notes on boards not found."""
    out, notes = [], []
    with opened_run(path) as run:
        for step in run.steps():
            if step.attrs.get("target") != "checkerboard" or not {"x", "y", "z", "intensity"} <= set(step.group):
                continue
            scene = step_scene(step)
            found = observe_corners(step, scene, fov_deg, max_frames) if scene is not None else None
            if found is None:
                notes.append(f"{step.step_id}: no checkerboard corners of at least {MIN_TILE_PX:g} px tiles found in "
                             f"{MIN_FRAMES} or more frames; its corners are not compared")
            else:
                out.append(found)
    return out, notes


def predict_corners(obs: CornerObservation, model: SimModel, width: int, height: int,
                    geometry: SensorOptics | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(N, 2) image positions and (N, 2) reported slopes of the step's corners under ``model``: each board
    corner through the true optics (sim/sensor.py ``SensorOptics``), the reported ray read there."""
    geo = geometry or sensor_optics(model, width, height)
    pin = geo.optics.pinhole
    world = np.stack([obs.board_ij[:, 0] * obs.tile_mm + obs.offset_mm[0],
                      obs.board_ij[:, 1] * obs.tile_mm + obs.offset_mm[1], np.full(len(obs.board_ij), obs.plane_mm)])
    cam = Pose.at_origin(model.lab.tilt_x_deg, model.lab.tilt_y_deg).to_camera(world)
    u, v = geo.optics.distort(pin.cx + pin.fx * cam[0] / cam[2], pin.cy + pin.fy * cam[1] / cam[2])
    if geo.tx.shape[0] == 1:  # separable: the slopes are linear in u and v, also beyond the border
        tx, ty = (u - pin.cx) / pin.fx, (v - pin.cy) / pin.fy
    else:  # the reported rays of a corrected distortion, read bilinearly
        tx, ty = (ndimage.map_coordinates(np.asarray(m, float), np.stack([v, u]), order=1, mode="nearest")
                  for m in (geo.tx, geo.ty))
    return np.column_stack([u, v]), np.column_stack([tx, ty])


def sensor_optics(model: SimModel, width: int, height: int) -> SensorOptics:
    """The model's true and reported optics at the run's sensor size."""
    return SensorOptics(model.profile().with_overrides({"width": width, "height": height}), model.effect_params())


@dataclass(frozen=True)
class CornerGoodness:
    """The corner families' gaps and floors (mm in the board plane), per step and over the run."""

    gaps: dict[str, float]
    floors: dict[str, float]
    gap_px: float
    gap_floor_px: float
    steps: list[StepFit]

    @property
    def gap_mm(self) -> float:
        """Both families together (RMS over their rows)."""
        return self.gaps["all"]

    @property
    def gap_floor_mm(self) -> float:
        return self.floors["all"]

    def family_consistent(self, family: str) -> bool:
        gap, floor = self.gaps.get(family, math.nan), self.floors.get(family, math.nan)
        return (not math.isfinite(gap) or gap <= floor) and all(
            s.ratio <= STEP_FACTOR for s in self.steps if s.family == family)

    @property
    def consistent(self) -> bool:
        return all(self.family_consistent(f) for f in FAMILIES)

    def summary(self) -> CornerGoodnessSummary:
        """The record reconcile.json gives: per family gap, floor, unit and consistency (the image family also in
        px), both families together, and the steps above their floors."""
        def family(name: str) -> CornerFamilyGoodness:
            return CornerFamilyGoodness(gap=rounded(self.gaps[name]), gap_floor=rounded(self.floors[name]),
                                        unit=FAMILY_UNIT, consistent_with_noise=self.family_consistent(name))

        image = family("corner_image")
        image.gap_px, image.gap_floor_px = rounded(self.gap_px), rounded(self.gap_floor_px)
        return CornerGoodnessSummary(corner_image=image, corner_cloud=family("corner_cloud"), gap=rounded(self.gap_mm),
                                     gap_floor=rounded(self.gap_floor_mm), consistent_with_noise=self.consistent,
                                     steps_above_floor=steps_above_floor(self.steps))


class CornerComparison:
    """Measured corners against a model's: the rows of both families, their nuisance, weights and floors."""

    def __init__(self, observations: list[CornerObservation], width: int, height: int,
                 fov_deg: tuple[float, float]) -> None:
        self.obs = observations
        self.width, self.height = width, height
        self.focal_px = ((width / 2) / math.tan(math.radians(fov_deg[0]) / 2),
                         (height / 2) / math.tan(math.radians(fov_deg[1]) / 2))
        # px -> mm in the board plane (image rows), slope -> mm (cloud rows): per corner axis
        self.to_mm = [(np.array([o.plane_mm / self.focal_px[0], o.plane_mm / self.focal_px[1]]), o.plane_mm)
                      for o in observations]
        # the cloud is read at the measured corner: its position's scatter and floor enter the cloud rows too
        self.var = [np.stack([o.uv_var * m[0] ** 2, o.uv_var * m[0] ** 2 + o.slope_var * m[1] ** 2])
                    for o, m in zip(observations, self.to_mm)]
        self.floor_sq = [np.stack([np.broadcast_to((CORNER_FLOOR_PX * m[0]) ** 2, o.uv.shape),
                                   np.broadcast_to((CORNER_FLOOR_PX * m[0]) ** 2 + (SLOPE_FLOOR * m[1]) ** 2,
                                                   o.uv.shape)])
                         for o, m in zip(observations, self.to_mm)]

    @property
    def n_rows(self) -> int:
        return sum(2 * 2 * len(o.uv) for o in self.obs)

    def residuals(self, model: SimModel) -> list[np.ndarray]:
        """Per step (2 families, N corners, 2 axes) measured minus simulated, mm in the board plane, with the
        board's placement profiled out (``_profile``)."""
        geo = sensor_optics(model, self.width, self.height)
        pin = geo.optics.pinhole
        raws, centred = [], []
        for o, (m_img, m_cloud) in zip(self.obs, self.to_mm):
            uv, slope = predict_corners(o, model, self.width, self.height, geo)
            raws.append(np.stack([(o.uv - uv) * m_img, (o.slope - slope) * m_cloud]))
            centred.append(np.stack([np.column_stack([uv[:, 0] - pin.cx, uv[:, 1] - pin.cy]) * m_img,
                                     slope * m_cloud]))
        return self._profile(raws, centred)

    def _profile(self, raws: list[np.ndarray], centred: list[np.ndarray]) -> list[np.ndarray]:
        """Weighted least squares of the residual rows by the board's placement, removed: per step and family a
        shift (two) and a small rotation about the optical axis, d = (t_u - theta v, t_v + theta u) with (u, v)
        the corner from the centre in mm; per reference group (laser, stage) an error dZ of the board distance,
        which scales every corner of a step by -dZ / Z in both families."""
        groups = sorted({o.scene.reference for o in self.obs})
        blocks, n_cols = [], 6 * len(self.obs) + len(groups)
        for s, (o, r, c) in enumerate(zip(self.obs, raws, centred)):
            design = np.zeros(r.shape + (n_cols,))  # (family, corner, axis, column)
            for f in range(2):
                design[f, :, 0, 6 * s + 3 * f] = 1.0
                design[f, :, 1, 6 * s + 3 * f + 1] = 1.0
                design[f, :, 0, 6 * s + 3 * f + 2] = -c[f][:, 1]
                design[f, :, 1, 6 * s + 3 * f + 2] = c[f][:, 0]
            design[..., 6 * len(self.obs) + groups.index(o.scene.reference)] = -c / o.plane_mm
            blocks.append(design.reshape(-1, n_cols))
        x = np.concatenate(blocks)
        y = np.concatenate([r.ravel() for r in raws])
        w = np.sqrt(np.concatenate([(1.0 / (v + f)).ravel() for v, f in zip(self.var, self.floor_sq)]))
        coef = np.linalg.lstsq(x * w[:, None], y * w, rcond=None)[0]
        rest = y - x @ coef
        sizes = np.cumsum([0] + [r.size for r in raws])
        return [rest[sizes[i]:sizes[i + 1]].reshape(r.shape) for i, r in enumerate(raws)]

    def whitened(self, model: SimModel) -> np.ndarray:
        """All rows of ``residuals`` divided by their standard deviation (variance plus floor), flattened."""
        return np.concatenate([(r / np.sqrt(v + f)).ravel()
                               for r, v, f in zip(self.residuals(model), self.var, self.floor_sq)])

    def cells(self) -> np.ndarray:
        """(step, family) cell of every row of ``whitened``: 2 s + family."""
        return np.concatenate([np.repeat([2 * s, 2 * s + 1], o.uv.size) for s, o in enumerate(self.obs)])

    def goodness(self, model: SimModel) -> CornerGoodness:
        """Gaps and floors of both families under ``model``."""
        res = self.residuals(model)
        steps, sums = [], {f: [0.0, 0.0, 0] for f in (*FAMILIES, "all")}
        px = [0.0, 0.0, 0]
        for o, r, var, fl, (m_img, _) in zip(self.obs, res, self.var, self.floor_sq, self.to_mm):
            for f, family in enumerate(FAMILIES):
                systematic, floor_sq = float(np.sum(r[f] ** 2 - var[f])), float(np.sum(var[f] + fl[f]))
                steps.append(StepFit(o.step_id, family, math.sqrt(max(0.0, systematic) / r[f].size),
                                     math.sqrt(floor_sq / r[f].size)))
                for key in (family, "all"):
                    sums[key][0] += systematic
                    sums[key][1] += floor_sq
                    sums[key][2] += r[f].size
            px[0] += float(np.sum((r[0] ** 2 - var[0]) / m_img**2))
            px[1] += float(np.sum((var[0] + fl[0]) / m_img**2))
            px[2] += r[0].size
        gaps = {k: math.sqrt(max(0.0, s) / n) if n else math.nan for k, (s, _, n) in sums.items()}
        floors = {k: math.sqrt(f / n) if n else math.nan for k, (_, f, n) in sums.items()}
        return CornerGoodness(gaps, floors, math.sqrt(max(0.0, px[0]) / px[2]), math.sqrt(px[1] / px[2]), steps)


# ------------------------------------------------------------------------------------------------ candidates
@dataclass(frozen=True)
class CornerCandidate:
    """An effect the corner families make visible, its parameter vector, bounds and start."""

    name: str
    start: Callable[[SimModel], np.ndarray]
    bounds: tuple[np.ndarray, np.ndarray]
    params: Callable[[np.ndarray], Parameters]
    keys: tuple[str, ...]  # the names of the vector's entries (for standard errors)
    variants: tuple[Parameters, ...] = field(default_factory=lambda: ({},))  # fixed settings tried in turn


def corner_candidate(effect: Effect) -> CornerCandidate:
    """The corner candidate of an effect whose ``observed.corners`` says how the corners show it."""
    corners = effect.observed.corners
    return CornerCandidate(effect.name, lambda model: np.array(corners.start(model.profile()), float),
                           (np.array(corners.lower, float), np.array(corners.upper, float)), corners.params,
                           corners.keys, tuple(dict(v) for v in corners.variants))


def corner_candidates() -> tuple[CornerCandidate, ...]:
    """The library's corner candidates, those with fewer parameters first (the registry's order among equals)."""
    found = [corner_candidate(e) for e in EFFECTS.values() if e.observed is not None and e.observed.corners]
    return tuple(sorted(found, key=lambda c: len(c.keys)))


@dataclass(frozen=True)
class CornerFit:
    """A candidate's best fit on the corner families."""

    name: str
    params: Parameters
    score: float  # Schwarz's criterion improvement over the corner axes
    rss0: float
    rss1: float
    stderr: dict[str, float]
    signature: np.ndarray  # the fitted change of the whitened rows
    x: np.ndarray  # the fitted parameter vector (``CornerCandidate.keys``)


def corner_score(rss0: np.ndarray, rss1: np.ndarray, counts: np.ndarray, n_params: int) -> float:
    """sum over (step, family) cells of n ln(RSS_0 / RSS_1) minus k ln(N) (Schwarz 1978, the corner axes as
    replications, each cell with its own residual scale)."""
    used = (rss0 > 0) & (counts > 0)
    return float(np.sum(counts[used] * np.log(rss0[used] / np.maximum(rss1[used], 1e-300)))) \
        - n_params * math.log(max(int(counts.sum()), 2))


def fit_corner_candidate(candidate: CornerCandidate, comparison: CornerComparison, model: SimModel,
                         with_effect: Callable[[SimModel, str, Parameters], SimModel]) -> CornerFit | None:
    """The candidate fitted by nonlinear least squares (each of its variants; the best kept)."""
    cells = comparison.cells()
    r0 = comparison.whitened(model)
    n_cells = 2 * len(comparison.obs)
    counts = np.bincount(cells, minlength=n_cells).astype(float)
    rss0 = np.bincount(cells, r0 * r0, n_cells)
    lo, hi = candidate.bounds
    best: CornerFit | None = None
    for variant in candidate.variants:
        def residual(x: np.ndarray, variant: Parameters = variant) -> np.ndarray:
            return comparison.whitened(with_effect(model, candidate.name, {**candidate.params(x), **variant}))

        x0 = np.clip(candidate.start(model), lo + 1e-9, hi - 1e-9)
        try:
            result = optimize.least_squares(residual, x0, bounds=(lo, hi), x_scale="jac", max_nfev=40)
        except ValueError:
            continue
        r1 = result.fun
        rss1 = np.bincount(cells, r1 * r1, n_cells)
        k = len(x0)
        dof = max(len(r1) - k, 1)
        try:
            cov = np.linalg.pinv(result.jac.T @ result.jac) * float(r1 @ r1) / dof
            stderr = {key: float(math.sqrt(max(cov[i, i], 0.0))) for i, key in enumerate(candidate.keys)}
        except np.linalg.LinAlgError:
            stderr = {}
        fit = CornerFit(candidate.name, {**candidate.params(result.x), **variant},
                        corner_score(rss0, rss1, counts, k), float(rss0.sum()), float(rss1.sum()), stderr, r0 - r1,
                        result.x)
        if best is None or fit.score > best.score:
            best = fit
    return best
