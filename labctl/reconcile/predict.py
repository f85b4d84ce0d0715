"""The simulation's noise-free prediction of a measured step, on the binned grid.

The reconcile workflow compares bin means, so the simulator runs the camera
at the bin grid: ``bin_px`` x ``bin_px`` pixels become one pixel (width and
height divided by ``bin_px``, no lens blur: ``binned_profile``). The bin's centre
ray is then exactly the binned pixel's ray (``Pinhole``: c = (W - 1) / 2,
f = (W / 2) / tan(FOV / 2)). The render samples each bin at k x k rays, as the
measured camera samples each of its pixels, and the measured bin is the plain
mean of its pixels. So a smooth surface's bin mean is the plain mean over the
bin's rays (``z_plain``; the render's light-weighted means kept only for the
pixels' own 1 / b^2 share, ``Predictor.tof_depth``) plus its curvature: the
mean of a quadratic over the pixels' samples exceeds the mean over the bin's
by f'' (b^2 - 1) / (24 b^2 k^2) per axis, with f'' the second difference over
neighbouring bins (``bin_curvature``; 0.05 mm on a plate tilted by 60 deg at
850 mm in 16-pixel bins, where z'' = 2 z tan^2(tilt) / f^2). A ToF bin's light
gets the same term and the lens PSF's, which spreads each pixel's light where
it curves (``Predictor.pixels_light``). The range hooks, of a stereo camera
and of a ToF camera alike, are averaged over the bin's pixels (``pixels_mean``;
``Predictor._pixels_reported``, ``Predictor._tof_expected``).
Bins that straddle a depth or reflectance edge are flagged (``edge``) and left
out of the comparison.

Per step the prediction also holds what a full-resolution pixel of each bin
shows over its stack: its temporal depth noise, its valid fraction and the
correlation of its noise with its neighbours' (labctl/reconcile/noise_model.py),
and what the candidate effects' signatures are built from: the range and the z / range ratio of the reported rays (ToF), the
light before vignetting, the pixel's dominant-return phasor mean (multipath),
and the frames' mean drift factor. Renders are cached per step and per
setting of the effects that change what the render sees
(``Effect.changes_render``; the last ``RENDERS_PER_STEP`` per step), so that effects acting after the render
re-simulate a whole run in milliseconds per step.
"""

from __future__ import annotations

import dataclasses
import functools
import json
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from functools import cached_property, lru_cache
from typing import Any

import numpy as np
from scipy import ndimage

from labctl.kernel_threads import serial_kernels
from labctl.reconcile.finite import finite
from labctl.reconcile.noise_model import (
    disparity_noise_px,
    dot_window_stats,
    in_range_share,
    stereo_light,
    stereo_statistics,
    stored_depth_bias,
    tof_noise,
    tof_stored_bias,
    tof_valid_fraction,
)
from labctl.reconcile.observe import Observation, StepScene, bin_mean
from metrics.stack import central_roi
from sim.effects import (
    EFFECTS,
    EffectParams,
    acting,
    frame_offset_mm,
    output_step_mm,
    plate_placement_mm,
    shading_factor,
)
from sim.geometry import Pose
from sim.model import SimModel
from sim.optics import CameraOptics
from sim.profiles import CameraProfile
from sim.render import OVERSAMPLE, RenderMove, render, sub_pixel_directions
from sim.scenes.targets import PLATE_MATERIALS, build_scene, plate_scene
from sim.sensor import SensorOptics, blur_diameter_px, camera_optics
from sim.stereo import StereoSensor, dot_pattern
from sim.tof import ToFSensor, range_noise_mm, surface_properties

#: two steps carry the offset of the same calibration when their offsets (reference - laser, each formed from the
#: same float) agree to far below the laser's 0.1 mm resolution
OFFSET_MATCH_MM = 1e-6
#: a bin whose rays' light bends by more than this share of itself (its second difference over three neighbouring
#: rays, half a bin apart) holds a fold or a grazing contour of one surface, which its rays cannot average: the
#: face mask's nose hiding part of the cheek bends it by up to 140 % (binned 10-16 % off its pixels' mean). The
#: smooth light of the robot's plates bends by at most 23 %, seen nearly edge-on at 80 deg.
FOLD_LIGHT = 0.5
#: renders kept per step for as many settings of the effects that change them: a fit of a lens distortion tries a
#: new one at every step it takes, and a complete campaign's 205 steps hold about 1 MB each at the bin grid (a
#: fit of 50 tries kept them all: 10 GB). The plain model's and a fit's current and previous settings.
RENDERS_PER_STEP = 3
#: a wall moved by a shift within this of one it was drawn at is taken between that render and one drawn this much
#: further (``Predictor._render``, ``RenderMove``): a fit's steps move the shift by tenths of a millimetre, its
#: Jacobian's columns and the parameters' secant slopes by nanometres to a tenth of a micrometre, so that each step
#: draws two renders instead of one per column. The complete blaze-101 campaign's 119 laser-referenced steps (walls,
#: charts, stars, the slanted edge, the ball bar, the face) a full reach from the render, at 1.47 mm: depth within
#: 1.1e-7 mm and light within 1e-8 of itself of the walls drawn there (the ball bar's sphere the furthest off)
SHIFT_REACH_MM = 1e-3
#: a calibration wall's shift is solved until its central depth is within this of the recorded distance
#: (``calibration_shift``): far below the comparison's depth floor (labctl/reconcile/residuals.py Z_FLOOR_MM, 0.02 mm)
SHIFT_TOLERANCE_MM = 1e-4
#: the most central depths it takes after the one at s = 0: a D455 with a disparity bias of 0.058 px at a 1.68 px
#: period (the error's slope 0.2 of the distance) takes 3, its plain model 2 (two in all before the root was solved)
SHIFT_ITERATIONS = 12


@dataclass(frozen=True)
class Prediction:
    """Noise-free binned prediction of one step."""

    z: np.ndarray  # mm, NaN where the camera reports nothing
    intensity: np.ndarray
    range_mm: np.ndarray  # ToF: range along the ray; stereo: z
    range_dom: np.ndarray  # range of the dominant surface as rendered (before any range effect)
    z_per_range: np.ndarray  # z / range of the reported ray (1 for stereo)
    light: np.ndarray  # returned light before vignetting (ToF amplitude units)
    phasor_mean: complex  # mean dominant-return phasor over the image (ToF)
    cos_alpha: np.ndarray  # cosine of each bin's ray to the optical axis
    edge: np.ndarray  # bins next to a depth or reflectance edge
    noise_mm: np.ndarray  # temporal std of a full-resolution pixel's z, NaN where not predicted
    noise_log_spread: np.ndarray  # what the model cannot know of ln noise_mm (where z sits on the output grid)
    valid_rate: np.ndarray  # expected fraction of valid pixel-frames (NaN where not predicted)
    valid_spread: np.ndarray  # the model's uncertainty of valid_rate (stereo: pixels at the texture threshold)
    correlation: np.ndarray  # expected variance of a bin mean over the per-pixel variance / n (1: independent)
    #: bins holding pixels within the camera's range (ToF; z and intensity continue beyond it, ``predict``)
    reported: np.ndarray | bool = True
    #: ToF: each bin's range as its pixels weight their own rays, before the range effects, and the bins no edge runs
    #: through, with the pixels a bin's side holds: what the range's slopes across a bin are taken from
    pixel_range: np.ndarray | None = None
    smooth: np.ndarray | None = None
    bin_px: int = 1

    @cached_property
    def _range_slope(self) -> tuple[np.ndarray | float, np.ndarray | float]:
        """The range's change per pixel across the bin, down the rows and along the columns (``range_spread``; 0
        for a stereo camera), taken when a signature asks for it."""
        if self.pixel_range is None or self.smooth is None:
            return 0.0, 0.0
        down, across = range_spread(self.pixel_range, self.bin_px, self.smooth)[0]
        return down, across

    @property
    def range_slope_down(self) -> np.ndarray | float:
        return self._range_slope[0]

    @property
    def range_slope_across(self) -> np.ndarray | float:
        return self._range_slope[1]


@dataclass(frozen=True)
class _ToFBins:
    """What a ToF camera's bins hold before their depth and light are taken (``Predictor._tof_expected``)."""

    range_mm: np.ndarray  # noise-free range, NaN where nothing is hit
    hooked: np.ndarray  # the range effects' mean change over the bin's pixels, part of range_mm (0 where not hit)
    amplitude: np.ndarray  # 0 where nothing is hit
    ambient: float
    share: np.ndarray  # the bin's share of pixels within the camera's range (``in_range_share``)
    pixel_range: np.ndarray  # the range as each pixel weights its own rays, before the range effects


def binned_profile(profile: CameraProfile, width: int, height: int, bin_px: int) -> CameraProfile:
    """The measured camera (``width`` x ``height``) with ``bin_px`` x ``bin_px`` pixels merged into one.

    The binned camera has no optical blur: blur moves light across edges, and bins within the blur's reach of
    an edge are left out of the comparison (``Predictor.blur_reach_bins``); what it does to a smooth light,
    spreading it over the PSF's variance where the light curves, the ToF bins' light gets back
    (``Predictor.pixels_light``).
    """
    return profile.with_overrides({"width": width // bin_px, "height": height // bin_px, "lens_sigma_px": 0.0})


def binned_effects(model: SimModel, width: int, height: int) -> dict[str, EffectParams]:
    """The model's effects for the binned camera: all but the blur (``blur_px``), each as its ``binned`` hook
    gives it for the measured camera's ``width`` x ``height`` sensor (e.g. a fixed pattern's random parts stay
    drawn on that grid, each bin taking their bin mean)."""
    effects = {}
    for name, params in model.effect_params().items():
        effect = EFFECTS[name]
        if effect.blur_px is None:
            effects[name] = effect.binned(params, width, height) if effect.binned is not None else params
    return effects


@lru_cache(maxsize=4)
def binned_dots(height: int, width: int, lens_sigma_px: float, bin_px: int) -> np.ndarray:
    """Each binned pixel's share of the projector dots' light after the in-focus lens PSF (read-only)."""
    spread = ndimage.gaussian_filter(dot_pattern(height, width), lens_sigma_px, mode="reflect")
    coverage, _ = bin_mean(spread, bin_px)
    coverage.setflags(write=False)
    return coverage


def scene_and_pose(step: StepScene, model: SimModel, effects: dict[str, EffectParams], wavelength_nm: float):
    """The scene and camera pose of a measured step, as the simulated lab (sim/world.py) builds them."""
    if step.target in PLATE_MATERIALS:
        axis_mm, plate_mm = plate_placement_mm(effects)
        pose = Pose.on_circle(step.robot_angle_deg or 0.0, step.robot_radius_mm or 0.0, axis_mm)
        params = {k: v for k, v in step.target_params.items() if k != "offset_mm"}
        scene = plate_scene(step.target, wavelength_nm, offset_mm=plate_mm, **params)
        return scene, pose
    pose = Pose.at_origin(model.lab.tilt_x_deg, model.lab.tilt_y_deg)
    return build_scene(step.target, step.target_params, wavelength_nm, float(step.wall_distance_mm)), pose


class Predictor:
    """Binned noise-free simulation of measured steps under one model."""

    def __init__(self, model: SimModel, width: int, height: int, bin_px: int,
                 render_cache: dict[tuple[str, ...], Any] | None = None) -> None:
        self.model = model
        full = model.profile().with_overrides({"width": width, "height": height})
        self.full = full
        self.bin_px = bin_px
        self.profile = binned_profile(full, width, height, bin_px)
        self.effects = binned_effects(model, width, height)
        self.full_effects = model.effect_params()  # the measured camera's, its blur included
        self.technology = self.profile.technology
        if self.technology == "tof":
            self.sensor: ToFSensor | StereoSensor = ToFSensor(self.profile, self.effects)
        else:
            self.sensor = StereoSensor(self.profile, self.effects)
            self.sensor.dots = binned_dots(height, width, full.lens_sigma_px, bin_px)
            self.sensor.matching_focal_baseline = self.sensor.focal_baseline * bin_px  # the disparity's pixels
        geo = self.sensor.geometry
        tx, ty = np.broadcast_arrays(geo.tx.astype(float), geo.ty.astype(float))
        self.z_per_range = 1.0 / np.sqrt(1.0 + tx**2 + ty**2) if self.technology == "tof" else np.ones_like(tx)
        self.cos_alpha = np.broadcast_to(geo.cos_alpha, tx.shape)
        self.cache = render_cache if render_cache is not None else {}

    def geometry_key(self, step: StepScene) -> str:
        """The effect settings that change what this step's render sees (of an effect for which the render only
        keeps the phasors, that it is on)."""
        return self._geometry_keys[step.target in PLATE_MATERIALS]

    @cached_property
    def _geometry_keys(self) -> tuple[str, str]:
        """``geometry_key`` of the steps on the stage and of the plates on the robot."""
        return tuple(json.dumps({k: v.model_dump(mode="json") if EFFECTS[k].render_follows_parameters else True
                                 for k, v in self.effects.items()
                                 if (EFFECTS[k].changes_render if plates else EFFECTS[k].changes_stage_render)},
                                sort_keys=True) for plates in (False, True))

    def _render(self, step: StepScene, shift_mm: float = 0.0):
        """The step's render, its wall ``shift_mm`` nearer than recorded (``wall_shifts``). Each step keeps one
        moved render besides the recorded one, and a second drawn ``SHIFT_REACH_MM`` further when a shift within
        that reach of the first is asked for, which is then taken between the two (``RenderMove``): the shift changes
        with every model a fit tries, by nanometres between its Jacobian's columns, and a wall's render costs
        milliseconds at the bin grid. Of the renders for other settings of the effects
        (``geometry_key``) each step keeps the ``RENDERS_PER_STEP`` last used."""
        key = (step.step_id, self.geometry_key(step))
        if shift_mm:
            moved = self.cache.get((*key, "moved"))
            if moved is None or abs(shift_mm - moved.shift_mm) > SHIFT_REACH_MM:
                moved = _MovedWall(shift_mm, self._draw(_nearer(step, shift_mm)))
                self.cache[(*key, "moved")] = moved
            if shift_mm == moved.shift_mm:
                return moved.rendered
            if moved.along is None:
                moved.along = RenderMove.between(moved.rendered,
                                                 self._draw(_nearer(step, moved.shift_mm + SHIFT_REACH_MM)))
            return moved.along.at((shift_mm - moved.shift_mm) / SHIFT_REACH_MM)
        rendered = self.cache.pop(key, None)
        if rendered is None:
            held = [k for k in self.cache if len(k) == 2 and k[0] == step.step_id]
            for old in held[:max(0, len(held) - RENDERS_PER_STEP + 1)]:  # the least recently used first
                del self.cache[old]
                self.cache.pop((*old, "moved"), None)
            rendered = self._draw(step)
        self.cache[key] = rendered  # (again) the most recently used
        return rendered

    def _draw(self, step: StepScene):
        """Ray-cast one step's scene (on one thread: ``serial_kernels``). The bins' outer rays lie a quarter bin
        inside the image (at 4 px bins, a full pixel): an edge in that margin, which the camera's outer pixels
        see, is found against rays on the image border (``render``'s ``border``), so that its bins are edge bins
        too (a chart's border in the last pixel row gives the stereo matcher texture there); so are the bins
        where a surface folds (``light_folds``)."""
        scene, pose = scene_and_pose(step, self.model, self.effects, self.profile.wavelength_nm)
        with serial_kernels():
            if self.technology == "tof":
                rendered = self.sensor.render_scene(scene, pose, border=True)
            else:
                rendered = render(scene, pose, self.sensor.geometry.optics, surface_properties(scene, {}), border=True)
        # the folds of a surface are edges the bins cannot hold either: found once per render, not per prediction
        return dataclasses.replace(rendered, edge=rendered.edge | light_folds(rendered.irradiance_fine,
                                                                             rendered.oversample))

    def _dot_stats(self, distance_mm: float) -> tuple[np.ndarray, np.ndarray]:
        """The full sensor's blurred dot pattern over the matching window, per bin (``dot_window_stats``;
        cached with the renders, per distance and blur)."""
        optical = {k: v for k, v in self.model.effect_params().items()
                   if EFFECTS[k].blur_px is not None or EFFECTS[k].true_fov_deg is not None}
        key = ("dots", json.dumps([round(distance_mm), {k: v.model_dump(mode="json") for k, v in sorted(optical.items())}]))
        if key not in self.cache:
            optics = SensorOptics(self.full, optical)
            self.cache[key] = dot_window_stats(optics, float(round(distance_mm)), self.bin_px)
        return self.cache[key]

    def shade(self, light: np.ndarray) -> np.ndarray:
        """The bin means of ``light`` (the bins' unshaded light) times the measured camera's per-pixel shading
        (``Effect.shading``: vignetting). A shading that curves within a bin has a bin mean S that differs from
        its centre value to second order in the bin size, and light and shading that both fall across a bin
        add their covariance: mean(L s) = L S + (b^2 - 1) / 12 (dL/du dS/du + dL/dv dS/dv), the pixel
        positions of a bin having variance (b^2 - 1) / 12 px^2 along each axis, with per-pixel slopes from
        neighbouring bins. With the centre's factor alone a cos^5 fitted 4.996 on an amt100 test run (bins of 4
        pixels), 4.998 with S and no covariance."""
        shading = self._shading()
        if shading is None:
            return light
        mean, slope_v, slope_u = shading
        dv, du = np.gradient(light, self.bin_px) if min(light.shape) > 1 else (np.zeros_like(light),) * 2
        return light * mean + (self.bin_px**2 - 1) / 12.0 * (dv * slope_v + du * slope_u)

    def _shading(self) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
        """The measured camera's shading per bin: its bin mean over the pixels, and that mean's slopes per pixel
        down and across (None without shading effects; cached with the renders, per setting of the effects
        that set it)."""
        acts = [k for k in self.full_effects if EFFECTS[k].shading is not None
                or EFFECTS[k].true_fov_deg is not None or EFFECTS[k].lens_distortion is not None]
        if not any(EFFECTS[k].shading is not None for k in acts):
            return None
        key = ("shading", json.dumps({k: self.full_effects[k].model_dump(mode="json") for k in sorted(acts)}))
        if key not in self.cache:
            mean, _ = bin_mean(shading_factor(self.full_effects, SensorOptics(self.full, self.full_effects).cos_alpha),
                               self.bin_px)
            slopes = np.gradient(mean, self.bin_px) if min(mean.shape) > 1 else (np.zeros_like(mean),) * 2
            self.cache[key] = (mean, *slopes)
        return self.cache[key]

    def _shading_slope(self) -> np.ndarray | None:
        """The shading's relative slope per pixel, |grad S| / S, per bin (None without shading effects): the
        texture a vignetting adds to the IR image the matcher sees (``stereo_statistics``)."""
        shading = self._shading()
        if shading is None:
            return None
        mean, slope_v, slope_u = shading
        with np.errstate(invalid="ignore", divide="ignore"):
            return np.where(mean > 0, np.hypot(slope_v, slope_u) / mean, 0.0)

    def blur_reach_bins(self, distance_mm: float) -> int:
        """How many bins the measured camera's blur (3 sigma of the lens PSF plus the defocus disc radius,
        Thesis 2024, eq. 2-5) reaches at ``distance_mm``."""
        reach_px = 3.0 * self.full.lens_sigma_px + 0.5 * blur_diameter_px(self.full_effects, distance_mm,
                                                                          self.full.lens_sigma_px)
        return 1 + int(math.ceil(reach_px / self.bin_px))

    def drift_mm(self, times_s: np.ndarray) -> float:
        """Mean range offset of the frames taken at ``times_s`` (``temperature_drift``; 0 without such effects)."""
        if not len(times_s) or not acting(self.effects, "frame_offset_mm"):
            return 0.0
        return float(np.mean([frame_offset_mm(self.effects, float(t)) for t in times_s]))

    def wall_shifts(self, observations: Sequence[Observation], t0_s: float) -> dict[str, float]:
        """How much nearer than recorded this model's camera puts each laser-referenced wall (step id -> mm).

        A laser-referenced step's recorded distance is the laser reading plus the offset of an offset
        calibration: the camera's own mean depth over the central 10 % x 10 % region of a wall at 2 m minus
        the laser reading there (procedures/offset_calibration.py). The offset therefore holds the camera's
        depth error at the calibration, and every recorded wall is the true one plus that error. The model's
        camera makes its own error there: the walls it saw are each recorded distance minus the shift s at
        which its central depth of the calibration wall, placed at the recorded distance minus s, equals the
        recorded distance (``calibration_shift``). Without it an error that varies with distance (a disparity
        error growing as z^2) would be evaluated at walls off by the error itself. Steps are tied to the
        calibration whose offset they carry.
        """
        shifts: dict[str, float] = {}
        for calibration in observations:
            scene = calibration.scene
            if not scene.sets_offset or scene.applied_offset_mm is None or scene.wall_distance_mm is None:
                continue
            shift = calibration_shift(functools.partial(self._calibration_miss, scene, calibration.times_s - t0_s))
            if not math.isfinite(shift):
                continue
            for o in observations:
                offset = o.scene.applied_offset_mm
                if offset is not None and abs(offset - scene.applied_offset_mm) <= OFFSET_MATCH_MM:
                    shifts.setdefault(o.scene.step_id, shift)
        return shifts

    def _calibration_miss(self, scene: StepScene, times_s: np.ndarray, shift_mm: float) -> float:
        """The model's central depth of the calibration wall ``scene`` placed ``shift_mm`` nearer than recorded,
        minus the recorded distance (``calibration_shift``)."""
        assert scene.wall_distance_mm is not None  # only walls calibrate
        return self.central_depth(scene, times_s, shift_mm) - scene.wall_distance_mm

    def predict_run(self, observations: Sequence[Observation], t0_s: float) -> list[Prediction]:
        """The prediction of every step, the laser-referenced walls where this model's camera saw them
        (``wall_shifts``)."""
        shifts = self.wall_shifts(observations, t0_s)
        return [self.predict(o.scene, o.times_s - t0_s, shifts.get(o.scene.step_id, 0.0)) for o in observations]

    @cached_property
    def _reported_pixels(self) -> np.ndarray:
        """Per bin: the reported centre ray's z / range over the true centre ray's (they differ where a lens
        distortion bends the rays but the camera reports undistorted ones), times the mean over the measured
        camera's pixels in the bin of their own range-sampling excess (``range_excess``)."""
        return self.z_per_range * _true_centre_pixels(self.sensor.geometry.optics,
                                                      camera_optics(self.full, self.full_effects), self.bin_px)

    @cached_property
    def _periodic_hooks(self) -> tuple[bool, bool]:
        """Whether any of the sensor's range hooks is periodic (``Effect.periodic_range``), and whether all are: once
        per predictor, for every step a fit predicts (``_tof_expected``)."""
        hooked = [EFFECTS[name] for name in self.sensor.effects if EFFECTS[name].on_range is not None]
        return any(e.periodic_range for e in hooked), all(e.periodic_range for e in hooked)

    @cached_property
    def _reported_pixels_curvature(self) -> np.ndarray:
        """``_reported_pixels``' curvature over each bin's pixels about its centre value (``bin_curvature``), once
        per predictor: ``tof_depth`` needs it for every step a fit predicts."""
        return bin_curvature(self._reported_pixels, self.bin_px)

    def tof_depth(self, rendered: Any, range_mm: np.ndarray, hooked: np.ndarray | float = 0.0) -> np.ndarray:
        """Per bin, the mean depth of the measured camera's pixels in it, from the bin's range ``range_mm`` (its
        rendered range, drift included) and the mean change the range effects make over its pixels (``hooked``,
        ``_tof_expected``).

        The render weights the bin's rays by their light (``range_dom``, ``z_dom``); each measured pixel weights
        its own rays so, over a footprint b times smaller, and the bin is the plain mean of its pixels. Weighting
        by 1 / r^2 pulls a mean towards the near side by about 2 var(z) / z, var(z) = z^2 tan^2(theta) w^2 / 16
        for rays spread over w rad on a plate tilted by theta (1.3 mm at 40 deg and 3 m over the blaze-101's
        4-pixel bins at 160 x 120), and the variance of b times smaller a footprint is b^2 times smaller. So the
        light weighting is taken off the bin's range but for its 1 / b^2 share (``_pixel_weighted``), and the
        depth is that range times the render's plain mean depth over its plain mean geometric range (``z_plain``
        over ``range_plain`` less the surface's sub-surface bias) and ``_reported_pixels``; the centre ray's
        z / range (``z_per_range``) where nothing is hit. The centre ray's factor alone misses the spread of
        1 / cos over the bin: on a wall square to the axis (z = D) the rays' mean range exceeds D / cos(theta) by
        D w^2 (1 + 2 tan^2 theta) / 24 at field angle theta (3e-5 of D for the amt100's 4-pixel bins at its test
        size), an error growing with the distance, which a warm-up drift fitted over a sweep takes up. Each part
        gets its curvature over the bin's pixels (``bin_curvature``); the range effects' change, already a mean over
        the pixels, only the centre rays' factor's."""
        factor = self._reported_pixels
        with np.errstate(invalid="ignore", divide="ignore"):
            ratio = rendered.z_plain / (rendered.range_plain - rendered.bias_dom)
            weighting = self._pixel_weighted(rendered.range_dom, rendered.range_plain) - rendered.range_dom
            rendered_depth = (range_mm + weighting) * ratio
            hooked_depth = hooked * ratio
        plain = np.isfinite(ratio) & (ratio > 0)
        rendered_depth = np.where(plain, rendered_depth, range_mm * self.z_per_range / factor)
        hooked_depth = np.where(plain, hooked_depth, hooked * self.z_per_range / factor)
        # the curvature of each part over the bin's pixels: the render's, its mean over the bin's own k x k rays;
        # the centre rays' factor, its value at the bin's centre (on a distorted camera's wall, 1.2e-5 of the
        # distance otherwise)
        return ((rendered_depth + hooked_depth) * (factor + self._reported_pixels_curvature)
                + bin_curvature(rendered_depth, self.bin_px, OVERSAMPLE) * factor)

    def pixels_light(self, light: np.ndarray, rendered: Any, smooth: np.ndarray) -> np.ndarray:
        """Per bin, the mean over its pixels of the light the lens blurs onto them, from ``light``, the mean over the
        bin's k x k rays of ``rendered``. A light that curves within a bin differs in the two to second order (as
        ``bin_curvature``'s surface: the pixels' samples spread by (b^2 - 1) / (12 b^2 k^2) of a bin^2 more along
        each axis), and the lens PSF, a Gaussian of ``lens_sigma_px`` and the defocus disc (diameter D px, a
        variance of D^2 / 16 along each axis), spreads each pixel's light over a variance s^2 px^2 more: L''
        s^2 / (2 b^2). Without either, a lit wall's bins put the light of the amt100's corners 5e-5 below their
        pixels' mean and its centre 5e-5 above (bins of 4 pixels), which a vignetting's exponent fitted low by
        7e-5 of itself took up; with the bin's curvature alone 1.7e-5. Taken only where the three bins along an axis
        are ``smooth`` (no edge): across one the second difference is the edge's, not the light's curvature."""
        sigma2 = self.full.lens_sigma_px**2 + blur_diameter_px(self.full_effects, rendered.centre_distance_mm,
                                                               self.full.lens_sigma_px) ** 2 / 16.0
        k = rendered.oversample
        spread = (self.bin_px**2 - 1) / (24 * self.bin_px**2 * k**2) + sigma2 / (2 * self.bin_px**2)
        return light + second_differences(light, smooth) * spread

    def _edge_bins(self, step_id: str, sharp: np.ndarray, reach: int) -> np.ndarray:
        """The bins within ``reach`` bins of a ``sharp`` one (read-only). Each step keeps its last, with what it was
        found from: most models a fit tries move no edge."""
        inputs = (sharp.tobytes(), reach)
        held = self.cache.get(("edge bins", step_id))
        if held is None or held[0] != inputs:
            edge = ndimage.binary_dilation(sharp, iterations=reach)
            edge.setflags(write=False)
            held = (inputs, edge)
            self.cache[("edge bins", step_id)] = held
        return held[1]

    def _valid_fraction(self, step_id: str, cut: np.ndarray, ambient: float, smooth: np.ndarray) -> np.ndarray:
        """The ToF bins' valid fraction (``tof_valid_fraction``) at the light ``cut``, its slopes taken where no
        edge runs (``smooth``). Each step keeps its last one with what it was computed from: most models a fit
        tries change the depth and not the light, and the bins near the cut, averaged over their pixels, cost
        about a quarter of a prediction of the complete campaign (0.04 of 0.14 s)."""
        p = self.sensor.profile
        inputs = (cut.tobytes(), smooth.tobytes(), ambient, p.confidence_threshold_ratio * self.sensor.a_ref,
                  p.saturation_ratio * self.sensor.a_ref)
        held = self.cache.get(("valid fraction", step_id))
        if held is None or held[0] != inputs:
            held = (inputs, tof_valid_fraction(self.sensor, cut, ambient, slopes(cut, self.bin_px, smooth),
                                               self.bin_px))
            self.cache[("valid fraction", step_id)] = held
        return held[1]

    def _pixel_weighted(self, weighted: np.ndarray, plain: np.ndarray) -> np.ndarray:
        """The bin's mean of a quantity as its pixels weight it by their light, from the render's light-weighted
        (``weighted``) and plain (``plain``) means over the bin's rays: the weighting's shift scales with the
        variance of the footprint weighted over, 1 / bin_px^2 of the bin's (``tof_depth``)."""
        return plain + (weighted - plain) / self.bin_px**2

    def _tof_stored(self, z: np.ndarray, amplitude: np.ndarray, ambient: float) -> np.ndarray:
        """The ToF bins' expected stored depth: ``z`` (drift included) plus ``tof_stored_bias`` of the camera's
        output steps, its pixels' depth noise before the rounding from their ``amplitude``."""
        step = output_step_mm(self.effects)
        if step <= 0:
            return z
        seen = amplitude > 0
        sigma = np.where(seen, range_noise_mm(self.sensor.profile, np.where(seen, amplitude, 1.0), ambient), np.nan)
        return z + tof_stored_bias(z, sigma * self.z_per_range, step, self.bin_px)

    def _tof_expected(self, rendered, exposure_us: float) -> _ToFBins:
        """The ToF bins' noise-free range, amplitude and ambient light, whatever the camera's range (``_ToFBins``).

        Where an effect's range hook is periodic (``Effect.periodic_range``) the range effects act on each of the
        bin's pixels (``pixels_mean`` of the range hooks, each pixel's range from the bin's with its slopes and
        curvature where no edge runs, ``range_spread``; the light weighting of its own rays as ``tof_depth`` takes
        it): a far wall's bin at the image's edge spans up to 100 mm of range, over which a wiggling of a 150 mm
        period averages to half its value at the bin's mean range. The smooth hooks (an offset, a scale, a bounce,
        an amplitude-related error) act at the bin's range."""
        weighting = finite(self._pixel_weighted(rendered.range_dom, rendered.range_plain) - rendered.range_dom)
        returned: list[np.ndarray] = []
        periodic, only_periodic = self._periodic_hooks

        def report(range_mm: np.ndarray, light: np.ndarray) -> np.ndarray:
            returned.append(range_mm)
            if not periodic:
                return self.sensor.range_of(range_mm, light)  # smooth over a bin: its value at the bin's range
            pixels = range_mm + weighting
            slope, curvature = range_spread(pixels, self.bin_px, ~sharp_bins(rendered))
            return pixels_mean(lambda r: self.sensor.range_of(r, light), pixels, self.bin_px, slope, curvature,
                               TOF_PIXEL_NODES, stacked=only_periodic) - weighting

        range_mm, amplitude, ambient = self.sensor.expected(rendered, exposure_us, cut=False, report=report)
        before, = returned
        return _ToFBins(range_mm, np.where(np.isfinite(range_mm), range_mm - before, 0.0), amplitude, ambient,
                        in_range_share(range_mm, self.profile.min_range_mm, self.profile.max_range_mm, self.bin_px),
                        before + weighting)

    def central_depth(self, step: StepScene, times_s: np.ndarray, shift_mm: float = 0.0) -> float:
        """The mean predicted depth (``predict``'s z, taken by the same ``_tof_parts`` or ``_stereo_parts`` without
        the rest of a prediction) over the central 10 % x 10 % region of the measured camera (metrics.stack
        central_roi), each reported bin weighted by the region's pixels in it; NaN when none is reported there."""
        rendered = self._render(step, shift_mm)
        exposure = step.exposure_us or self.profile.exposure_us
        drift = self.drift_mm(times_s)
        if isinstance(self.sensor, ToFSensor):
            bins, _, _, _, z = self._tof_parts(rendered, exposure, drift, ~sharp_bins(rendered))
            z = np.where(bins.share > 0, z, np.nan)
        else:
            z = self._stereo_parts(step, rendered, exposure, drift)[2]
        rows, cols = central_roi(self.full.height, self.full.width)
        weight = np.outer(_overlap(rows, z.shape[0], self.bin_px), _overlap(cols, z.shape[1], self.bin_px))
        weight = np.where(np.isfinite(z), weight, 0.0)
        total = weight.sum()
        return float((weight * finite(z)).sum() / total) if total > 0 else math.nan

    def predict(self, step: StepScene, times_s: np.ndarray, shift_mm: float = 0.0) -> Prediction:
        """The step's binned noise-free z, intensity and the maps the candidate signatures need, its wall
        ``shift_mm`` nearer than recorded. What only sets the comparison's bins and the dot pattern's blur
        (the edge bins, the blur's reach) is taken at the recorded distance, so that it stays the same for
        every shift a fit tries."""
        recorded = self._render(step)
        rendered = self._render(step, shift_mm) if shift_mm else recorded
        exposure = step.exposure_us or self.profile.exposure_us
        drift = self.drift_mm(times_s)
        reach = self.blur_reach_bins(recorded.centre_distance_mm)
        sharp = sharp_bins(rendered)
        smooth = ~sharp
        edge = self._edge_bins(step.step_id, sharp, reach)
        if isinstance(self.sensor, ToFSensor):
            # a bin's means continue across the camera's range (the mean over all its pixels, as where part of them
            # is cut): only its valid fraction and noise know the cut (and, as before, the image's mean phasor the
            # multipath's signature takes), so that a model moving a bin out of range changes its comparison by the
            # pixels it cuts, not by a jump of its depth and intensity rows
            bins, range_mm, light, amplitude, z = self._tof_parts(rendered, exposure, drift, smooth)
            reported, ambient = bins.share > 0, bins.ambient
            cut = amplitude if reported.all() else self.shade(np.where(reported, light, 0.0))
            dominant = cut * np.exp(1j * self.sensor.wavenumber * finite(rendered.range_dom))
            noise = tof_noise(self.sensor, cut, ambient, np.broadcast_to(self.z_per_range, z.shape))
            valid = self._valid_fraction(step.step_id, cut, ambient, smooth) * bins.share
            return Prediction(z, amplitude, range_mm, rendered.range_dom, self.z_per_range, light,
                              complex(dominant.mean()), self.cos_alpha, edge, noise, np.zeros_like(z), valid,
                              np.zeros_like(z), _independent(noise), reported, bins.pixel_range, smooth, self.bin_px)
        lit, sigma_d, z = self._stereo_parts(step, rendered, exposure, drift)
        centre = shading_factor(self.effects, self.sensor.geometry.cos_alpha)  # the shading at the bin centres
        ir = self.shade(self.sensor.ir_image(rendered, exposure, step.projector) / centre)
        noise, spread, valid, valid_spread = stereo_statistics(
            self.sensor, z, rendered.z_plain, sigma_d, lit, self._dot_stats(recorded.centre_distance_mm), self.bin_px,
            self._shading_slope(), range_spread(rendered.z_plain, self.bin_px, smooth)[0][1])
        return Prediction(z, ir, z, rendered.range_dom, self.z_per_range, ir, 0j, self.cos_alpha, edge,
                          noise, spread, valid, valid_spread, _independent(noise))

    def _tof_parts(self, rendered: Any, exposure_us: float, drift_mm: float,
                   smooth: np.ndarray) -> tuple[_ToFBins, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """A ToF render's bins (``_tof_expected``), their range (drift included), light before the shading (each
        bin's pixels' mean, ``pixels_light``, taken where ``smooth``), amplitude and expected stored z."""
        bins = self._tof_expected(rendered, exposure_us)
        range_mm = bins.range_mm + drift_mm
        centre = shading_factor(self.effects, self.sensor.geometry.cos_alpha)  # the shading at the bin centres
        light = self.pixels_light(bins.amplitude / centre, rendered, smooth)
        amplitude = self.shade(light)
        z = self._tof_stored(self.tof_depth(rendered, range_mm - bins.hooked, bins.hooked), amplitude, bins.ambient)
        return bins, range_mm, light, amplitude, z

    def _stereo_parts(self, step: StepScene, rendered: Any, exposure_us: float,
                      drift_mm: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """A stereo render's light for the matcher (``stereo_light``), disparity noise (px) and expected stored z."""
        lit = stereo_light(self.sensor, rendered, exposure_us, step.projector)
        sigma_d = disparity_noise_px(self.sensor, rendered, lit)
        return lit, sigma_d, self._stereo_depth(rendered, drift_mm, sigma_d)

    def _pixels_reported(self, z: np.ndarray) -> np.ndarray:
        """The mean over each bin's pixels of the depth the stereo camera reports (its range hooks), from the
        bins' true depth ``z`` as rendered. The pixels of a bin on a tilted surface spread in disparity, and a
        hook that is not linear in it (a pixel locking of period P px) averages over that spread: on the d455's
        plates at 60 deg a bin spans about a pixel of disparity, and the hook taken at the bin's mean put the
        plates 0.5 mm off. Each pixel's depth is the bin's (with its curvature: ``bin_curvature``) plus the slope
        between the neighbouring bins times its offset from the bin's centre; without a hook, the bin's."""
        z = z + bin_curvature(z, self.bin_px, OVERSAMPLE)
        if not acting(self.sensor.effects, "on_range"):
            return z
        slope = [finite(np.gradient(z, axis=axis)) / self.bin_px for axis in (0, 1)]
        return pixels_mean(self.sensor.depth_of, z, self.bin_px, slope)

    def _stereo_depth(self, rendered: Any, drift_mm: float, sigma_d: np.ndarray) -> np.ndarray:
        """A stereo render's binned expected stored z (the noise-free depth plus ``stored_depth_bias`` for the
        disparity noise ``sigma_d``), NaN where nothing is hit or matched."""
        z = self._pixels_reported(self._pixel_weighted(rendered.z_dom, rendered.z_plain))  # as in ``tof_depth``
        z = np.where((rendered.hit_fraction > 0) & np.isfinite(z), z, np.nan)
        p = self.profile
        return z + drift_mm + stored_depth_bias(z, sigma_d, p.disparity_step_px, self.sensor.matching_focal_baseline,
                                                output_step_mm(self.effects), drift_mm, self.bin_px)


@dataclass
class _MovedWall:
    """A wall's render drawn ``shift_mm`` nearer than recorded and, once a shift within ``SHIFT_REACH_MM`` is asked
    for, the renders along the move to one drawn that much further."""

    shift_mm: float
    rendered: Any
    along: RenderMove | None = None


def _nearer(step: StepScene, shift_mm: float) -> StepScene:
    """The step with its wall ``shift_mm`` nearer than recorded."""
    assert step.wall_distance_mm is not None  # only walls are shifted
    return dataclasses.replace(step, wall_distance_mm=step.wall_distance_mm - shift_mm)


def calibration_shift(miss: Callable[[float], float]) -> float:
    """The shift s (mm) at which ``miss``(s), the model's central depth of the calibration wall placed s nearer
    than recorded minus the recorded distance, is 0 to within ``SHIFT_TOLERANCE_MM`` (``Predictor.wall_shifts``);
    NaN where the model sees nothing there. The first step is the fixed-point one, s = miss(0): exact where the
    camera's error does not change with distance. Then the secant method (superlinear): where the error changes
    with distance by a share c of the distance, fixed-point steps only shrink what is left by c each, and a
    periodic error's c is large (a disparity bias of a px and period P px: up to 2 pi a / P, 0.22 at 0.058 px and
    1.68 px, which two such steps left at 0.35 mm on a wall at 2 m)."""
    before, missed_before = 0.0, miss(0.0)
    if not math.isfinite(missed_before):
        return math.nan
    shift = missed_before
    for _ in range(SHIFT_ITERATIONS):
        missed = miss(shift)
        if not math.isfinite(missed) or abs(missed) <= SHIFT_TOLERANCE_MM:
            return shift if math.isfinite(missed) else math.nan
        change = missed - missed_before
        before, missed_before, shift = shift, missed, \
            shift - missed * (shift - before) / change if change else shift + missed
    return shift


def sharp_bins(rendered: Any) -> np.ndarray:
    """The bins of a render an edge runs through: a depth or reflectance edge, or the border of what is hit."""
    return rendered.edge | (rendered.hit_fraction < 1.0)


def _overlap(region: slice, bins: int, bin_px: int) -> np.ndarray:
    """Pixels of ``region`` (a slice of pixel indices) inside each of ``bins`` bins of ``bin_px`` pixels."""
    edges = np.arange(bins + 1) * bin_px
    return np.clip(np.minimum(edges[1:], region.stop) - np.maximum(edges[:-1], region.start), 0, None).astype(float)


def _independent(noise: np.ndarray) -> np.ndarray:
    """The correlation ratio of the simulator's noise: 1 (every pixel drawn independently) where it is predicted."""
    return np.where(np.isfinite(noise), 1.0, np.nan)


@lru_cache(maxsize=8)
def _true_centre_pixels(binned: CameraOptics, full: CameraOptics, bin_px: int) -> np.ndarray:
    """Per bin of ``binned``: 1 / cos of its true centre ray times the mean of ``range_excess`` over the pixels of
    ``full`` in it (once per optics: every model a fit tries builds a predictor)."""
    true_centre = binned.directions(*binned.pixel_grid())[2]
    pixels, _ = bin_mean(range_excess(full), bin_px)
    out = pixels / true_centre
    out.flags.writeable = False
    return out


def range_excess(optics: CameraOptics) -> np.ndarray:
    """Per pixel of ``optics``: the mean over the rays the render samples it with (``OVERSAMPLE`` x ``OVERSAMPLE``)
    of cos(centre ray) / cos(ray), the range they average over the centre ray's on a wall square to the axis."""
    centre = optics.directions(*optics.pixel_grid())[2]
    return (centre[..., None] / sub_pixel_directions(optics, OVERSAMPLE)[2]).mean(axis=-1)


def light_folds(fine: np.ndarray, k: int) -> np.ndarray:
    """Per bin, whether the light of its ``k`` x ``k`` rays (``fine``, (H k, W k)) bends by more than ``FOLD_LIGHT``
    of itself: |L(i - 1) - 2 L(i) + L(i + 1)| / L(i) along a row or a column of rays, at a ray of the bin."""
    bent = np.zeros(fine.shape, dtype=bool)
    with np.errstate(invalid="ignore", divide="ignore"):
        for before, middle, after, inner in ((fine[:-2], fine[1:-1], fine[2:], np.s_[1:-1, :]),
                                             (fine[:, :-2], fine[:, 1:-1], fine[:, 2:], np.s_[:, 1:-1])):
            bent[inner] |= np.abs(before - 2 * middle + after) > FOLD_LIGHT * middle
    h, w = fine.shape[0] // k, fine.shape[1] // k
    return bent.reshape(h, k, w, k).any(axis=(1, 3))


def bin_curvature(z: np.ndarray, bin_px: int, oversample: int = 1) -> np.ndarray:
    """Per bin of a smooth surface's binned values ``z``: the mean over the bin's ``bin_px`` x ``bin_px`` pixels,
    each the mean of its own ``oversample`` x ``oversample`` sub-pixel samples, minus the mean of the bin's own
    ``oversample`` x ``oversample`` samples (``z``, as the bin-grid render samples it; 1: its centre value).

    To second order the mean of a surface over points spread with variance s^2 along an axis exceeds its
    centre value by z'' s^2 / 2. Along each axis, in bins, the pixels' samples spread by (b^2 - 1) / (12 b^2) +
    (k^2 - 1) / (12 k^2 b^2) and the bin's by (k^2 - 1) / (12 k^2), so the difference is z'' (b^2 - 1) /
    (24 b^2 k^2), z'' the second difference over neighbouring bins, summed over rows and columns (0 where a
    neighbour is missing)."""
    return second_differences(z) * (bin_px**2 - 1) / (24 * bin_px**2 * oversample**2)


#: per axis (rows, columns), the bins before, the bins with a neighbour on both sides, and the bins after
_TRIPLES = ((np.s_[:-2], np.s_[1:-1], np.s_[2:]), (np.s_[:, :-2], np.s_[:, 1:-1], np.s_[:, 2:]))


def _neighbour_differences(z: np.ndarray, smooth: np.ndarray | None,
                           difference: Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray]) -> list[np.ndarray]:
    """Per axis (rows, then columns), ``difference(before, bin, after)`` of every bin and its two neighbours along
    the axis: 0 where a neighbour is missing (the border, NaN) or one of the three bins is not ``smooth`` (across
    an edge a difference is the edge's step, not the surface's or the light's shape)."""
    out = []
    for before, inner, after in _TRIPLES:
        value = difference(z[before], z[inner], z[after])
        held = np.isfinite(value)
        if smooth is not None:
            held &= smooth[before] & smooth[inner] & smooth[after]
        along = np.zeros_like(z)
        along[inner] = np.where(held, value, 0.0)
        out.append(along)
    return out


def slopes(z: np.ndarray, bin_px: int, smooth: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per bin, ``z``'s change per pixel down the rows and along the columns: the central difference over the
    neighbouring bins over 2 ``bin_px`` (``_neighbour_differences``)."""
    down, across = _neighbour_differences(z, smooth, lambda before, _, after: (after - before) / (2.0 * bin_px))
    return down, across


#: the most positions along a bin's side at which ``pixels_mean`` takes a hook by default: bins of up to 8 pixels a
#: side take every pixel; larger ones the Gauss quadrature of their pixels' positions with 8 nodes (``pixel_nodes``),
#: which errs by 6e-5 of a sine's amplitude where its phase changes by 16 rad across the bin (a pixel locking of
#: period 1.57 px on the d455's plates at 60 deg in 16-pixel bins), at a quarter of the cost of all 16 x 16 pixels
PIXEL_NODES = 8
#: the same for a ToF camera's range hooks: a wiggling's phase changes by at most 3.8 rad across a bin (a 150 mm
#: period, the shortest the candidate searches, on a far wall's edge bins, 100 mm of range), where 4 nodes err by
#: 2e-5 of its amplitude, at a quarter of the cost of 8 (a complete campaign's fit of a wiggling predicts it some
#: 40 times)
TOF_PIXEL_NODES = 4


@lru_cache(maxsize=8)
def pixel_nodes(bin_px: int, most: int = PIXEL_NODES) -> tuple[np.ndarray, np.ndarray]:
    """The positions (pixels from the bin's centre, along one side) and weights at which ``pixels_mean`` takes a
    hook: each pixel centre with weight 1 / b up to ``most`` pixels, else the ``most``-point Gauss
    quadrature of the b pixel centres, exact for a polynomial of degree below 2 ``most`` in the position:
    the eigenvalues of the Jacobi matrix of the polynomials orthogonal on the pixel centres (three-term
    recurrence by the Stieltjes procedure), the weights the squared first components of its eigenvectors
    (Golub & Welsch 1969)."""
    centres = np.arange(bin_px) - (bin_px - 1) / 2.0
    nodes, weights = (centres, np.full(bin_px, 1.0 / bin_px)) if bin_px <= most else _gauss_nodes(centres, most)
    nodes.flags.writeable = weights.flags.writeable = False  # shared by every caller (cached)
    return nodes, weights


def _gauss_nodes(centres: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """``n``-point Gauss quadrature of equal weights on ``centres`` (``pixel_nodes``)."""
    alpha, beta = np.zeros(n), np.zeros(n)
    before, current = np.zeros(len(centres)), np.ones(len(centres))
    for k in range(n):
        beta[k] = np.mean(current**2)
        alpha[k] = np.mean(centres * current**2) / beta[k]
        ratio = beta[k] / beta[k - 1] if k else 0.0
        before, current = current, (centres - alpha[k]) * current - ratio * before
    off_diagonal = np.sqrt(beta[1:] / beta[:-1])
    nodes, vectors = np.linalg.eigh(np.diag(alpha) + np.diag(off_diagonal, 1) + np.diag(off_diagonal, -1))
    return nodes, vectors[0] ** 2


def pixels_mean(hook: Callable[[np.ndarray], np.ndarray], values: np.ndarray, bin_px: int, slope: Sequence[np.ndarray],
                curvature: Sequence[np.ndarray] = (0.0, 0.0), most: int = PIXEL_NODES, stacked: bool = False) -> np.ndarray:
    """Per bin, the mean over its ``bin_px`` x ``bin_px`` pixels of ``hook`` of each pixel's value. A pixel at o_v,
    o_u pixels from the bin's centre (down, across) takes the bin's ``values`` plus s_v o_v + s_u o_u (``slope``,
    per pixel) plus c_v (o_v^2 - m) / 2 + c_u (o_u^2 - m) / 2 (``curvature``, per pixel^2; m = (b^2 - 1) / 12,
    the mean of o^2 over the pixel centres), so that the pixels' values average to the bin's; the mean is taken
    over every pixel, or for bins of more than ``most`` pixels a side by quadrature (``pixel_nodes``). A hook
    linear in the value gives the bin's value back; a periodic one, sin(k v), is damped: by the Dirichlet kernel
    D(x) = sin(b x / 2) / (b sin(x / 2)) of the bin's b pixels at x = k s_v and k s_u, where the value is linear
    across the bin (``pixels_damping``). ``stacked``: ``hook`` takes every position at once (an array with the
    positions first), as a function of the value alone does (``Effect.periodic_range``)."""
    offsets, weights = pixel_nodes(bin_px, most)
    bowed = offsets**2 - (bin_px**2 - 1) / 12.0
    (s_v, s_u), (c_v, c_u) = slope, curvature
    o, b = offsets[:, None, None], bowed[:, None, None]  # a position along the side per layer
    down = values + s_v * o + c_v * b / 2.0
    across = s_u * o + c_u * b / 2.0
    weight = np.outer(weights, weights).ravel()
    if stacked:  # every position down with every one across, in the order of ``weight``
        at = (down[:, None] + across[None, :]).reshape(-1, *down.shape[1:])
        return np.tensordot(weight, hook(at), axes=1)
    return sum(w * hook(v + u) for w, (v, u) in zip(weight, ((v, u) for v in down for u in across), strict=True))


def pixels_damping(k: np.ndarray, slope: Sequence[np.ndarray], bin_px: int) -> np.ndarray:
    """The factor by which the mean over a bin's pixels of sin(k v + phi) or cos(k v + phi) falls below its value at
    the bin's mean value v, where v changes across the bin by ``slope`` (per pixel, down and across): the product of
    the Dirichlet kernels sin(b x / 2) / (b sin(x / 2)) at x = k s_v and k s_u, the mean of cos(x o) over the b pixel
    offsets o (their sines cancel)."""
    factor = np.ones(np.broadcast_shapes(np.shape(k), *(np.shape(s) for s in slope)))
    for s in slope:
        half = 0.5 * np.abs(k * s)
        with np.errstate(invalid="ignore", divide="ignore"):
            factor = factor * np.where(half > 1e-9, np.sin(bin_px * half) / (bin_px * np.sin(half)), 1.0)
    return factor


#: per axis (rows, columns), the bins that have a next one along it, and those that have one before
_NEIGHBOURS = ((np.s_[:-1], np.s_[1:]), (np.s_[:, :-1], np.s_[:, 1:]))


def range_spread(z: np.ndarray, bin_px: int, smooth: np.ndarray) -> tuple[tuple[np.ndarray, np.ndarray],
                                                                          tuple[np.ndarray, np.ndarray]]:
    """Per bin, ``z``'s slope per pixel and its second difference per pixel^2 down the rows and along the columns
    (``pixels_mean``'s ``slope`` and ``curvature``), from the neighbouring bins where no edge runs (``smooth``):
    the central differences, and at the image's border or beside an edge the one-sided difference with the one
    smooth neighbour (no curvature there); 0 without one."""
    held = np.where(smooth, z, np.nan)
    slope, curvature = [], []
    for axis, (first, last) in enumerate(_NEIGHBOURS):
        step = np.diff(held, axis=axis) / bin_px
        ahead, behind = np.full(held.shape, np.nan), np.full(held.shape, np.nan)
        ahead[first], behind[last] = step, step  # the difference to the next bin, to the one before
        central = (ahead + behind) / 2.0
        slope.append(finite(np.where(np.isnan(central), np.where(np.isnan(ahead), behind, ahead), central)))
        curvature.append(finite((ahead - behind) / bin_px))
    return (slope[0], slope[1]), (curvature[0], curvature[1])


def second_differences(z: np.ndarray, smooth: np.ndarray | None = None) -> np.ndarray:
    """Per bin, the sum over rows and columns of ``z``'s second difference over the neighbouring bins
    (``_neighbour_differences``)."""
    down, across = _neighbour_differences(z, smooth, lambda before, bin_, after: before - 2 * bin_ + after)
    return down + across
