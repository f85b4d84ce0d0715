"""Active-stereo depth physics (Thesis 2024, 2.3.2; Giancola et al. 2018).

Per step (noise-free, once):

* left IR image = lamps' ambient light on the scene (reflectance cos^m; Thesis
  2024, 6.2.1, lights the targets of the stereo camera) plus, with the projector
  on, its random dot pattern (~ 1/r^2), blurred by the lens PSF (and
  ``defocus``), times ``vignetting``;
* matching needs texture: where the local IR contrast (std / mean over the
  matching window) is below ``texture_threshold`` the pixel is invalid — with
  the projector off, textureless targets (wall, PTFE, the inside of tiles) fail;
  background light (``ambient_light``, a uniform level b added after the blur)
  lowers that contrast, and the sub-pixel matching noise grows by
  (m + b) / m, m the window's mean light without it (Konolige 2010);
* occlusion: a point the right camera (baseline b to the right) cannot see is
  invalid, as are points outside its view (the left band of D4xx depth maps);
* ``disparity_bias``: the matcher's sub-pixel bias, periodic in the disparity
  of the camera's own pixels, moves the noise-free depth (before ``range_scale``
  and ``range_offset``);
* disparity d = f b / z with noise s (1 + g theta^2 / (pi/2 - theta)^2) pixels,
  s fixed by ``noise_mm_at_2m`` (so sigma_z = z^2 s / (f b)), the angle term
  adapted from Nguyen, Izadi & Lovell 2012;
* per frame: disparity noise, quantization to ``disparity_step_px``, depth
  effects (offset, scale, drift), x, y along the reported rays, ``quantization``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from sim.effects import (
    EffectParams,
    RangeStage,
    acting,
    background_level,
    frame_offset_mm,
    output_step_mm,
    shading_factor,
)
from sim.geometry import Pose
from sim.kernels import stereo_frame
from sim.noise import NoiseBank, make_bank
from sim.profiles import CameraProfile
from sim.render import Rendered, render
from sim.scenes.base import Scene
from sim.sensor import SensorOptics
from sim.tof import IRRADIANCE_REF, REFERENCE_RANGE_MM, surface_properties

MATCHING_WINDOW_PX = 7
DOT_DENSITY = 0.15
IR_NOISE = 0.01
AMBIENT_LEVEL = 1000.0
PROJECTOR_LEVEL = 2000.0


@dataclass(frozen=True)
class StereoPrepared:
    disparity: np.ndarray
    sigma_disp: np.ndarray
    valid: np.ndarray
    ir: np.ndarray
    bank: NoiseBank
    seed: int
    step_index: int


def dot_pattern(height: int, width: int) -> np.ndarray:
    """The projector's fixed pseudo-random dot pattern on the pixel grid (1 on a dot, 0 off)."""
    rng = np.random.default_rng(455)
    return (rng.random((height, width)) < DOT_DENSITY).astype(float)


def local_contrast(image: np.ndarray, window: int = MATCHING_WINDOW_PX) -> np.ndarray:
    """std / mean of ``image`` over a square window (texture available for matching)."""
    mean = ndimage.uniform_filter(image, window)
    sq = ndimage.uniform_filter(image**2, window)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(mean > 0, np.sqrt(np.maximum(sq - mean**2, 0.0)) / mean, 0.0)


class StereoSensor:
    """Per-pixel active-stereo measurement model for one camera profile and set of effects."""

    technology = "stereo"

    def __init__(self, profile: CameraProfile, effects: dict[str, EffectParams]) -> None:
        self.profile = profile
        self.effects = effects
        self.geometry = SensorOptics(profile, effects)
        self.focal_baseline = self.geometry.optics.pinhole.fx * profile.baseline_mm
        self.matching_focal_baseline = self.focal_baseline  # f b in the pixels the matcher works on
        self.subpixel_noise_px = profile.noise_mm_at_2m * self.focal_baseline / REFERENCE_RANGE_MM**2
        self.dots = dot_pattern(profile.height, profile.width)

    def render_scene(self, scene: Scene, pose: Pose) -> tuple[Rendered, np.ndarray]:
        """The left camera's render and where the right camera sees the same points (the geometric part)."""
        left = render(scene, pose, self.geometry.optics, surface_properties(scene, {}))
        return left, self._visible_from_right(scene, pose, left.z_dom)

    def expected(self, rendered: tuple[Rendered, np.ndarray], exposure_us: float,
                 projector: bool = True) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Noise-free depth (mm, NaN where matching fails), validity, left IR image and disparity noise (px)."""
        p = self.profile
        left, visible = rendered
        ir = self.ir_image(left, exposure_us, projector)
        background = self.background(exposure_us)
        z = self.depth(left)
        textured = local_contrast(ir) >= p.texture_threshold
        in_range = (left.hit_fraction > 0) & (z >= p.min_range_mm) & (z <= p.max_range_mm)
        valid = in_range & textured & visible & np.isfinite(z)
        theta = np.arccos(np.clip(left.cos_dom, 1e-6, 1.0))
        angle_term = 1.0 + p.angle_noise_gain * theta**2 / np.maximum(math.pi / 2 - theta, 1e-3) ** 2
        sigma = self.subpixel_noise_px * angle_term
        if background > 0:
            signal = ndimage.uniform_filter(self._light(left, exposure_us, projector), MATCHING_WINDOW_PX)
            with np.errstate(divide="ignore", invalid="ignore"):
                sigma = sigma * np.where(signal > 0, 1.0 + background / signal, 1.0)
        return np.where(valid, z, np.nan), valid, ir, sigma

    def background(self, exposure_us: float) -> float:
        """The effects' background light on the IR image before vignetting: ``background_level`` times the
        projector's light on the 90 % wall at 2 m, scaled by the exposure."""
        return background_level(self.effects) * PROJECTOR_LEVEL * exposure_us / self.profile.exposure_us

    def ir_image(self, left: Rendered, exposure_us: float, projector: bool = True) -> np.ndarray:
        """Noise-free left IR image: lamps plus (with ``projector``) the dots, blurred, plus the background
        light (``background``), times ``vignetting``."""
        ir = (self._light(left, exposure_us, projector) + self.background(exposure_us)) \
            * shading_factor(self.effects, self.geometry.cos_alpha)
        return np.maximum(ir, 0.0)

    def _light(self, left: Rendered, exposure_us: float, projector: bool) -> np.ndarray:
        """The lamps' and (with ``projector``) the dots' light on each pixel after the blur, before vignetting.

        ``self.dots`` holds each pixel's dot coverage (1 or 0, or a fraction for a binned sensor).
        """
        k = left.oversample
        light = AMBIENT_LEVEL * left.passive_fine
        if projector:  # each dot covers whole pixels
            dots = np.repeat(np.repeat(self.dots, k, axis=0), k, axis=1)
            light = light + PROJECTOR_LEVEL * left.irradiance_fine / IRRADIANCE_REF * dots
        return self.geometry.blur(light * (exposure_us / self.profile.exposure_us), left.centre_distance_mm, k)

    def depth(self, left: Rendered) -> np.ndarray:
        """Noise-free depth of the left camera's dominant surface after the effects' range hooks
        (``disparity_bias``, ``range_scale``, ``range_offset``, the empirical corrections)."""
        return self.depth_of(left.z_dom)

    def depth_of(self, z: np.ndarray) -> np.ndarray:
        """The true depth ``z`` as this camera reports it: after the effects' range hooks (``depth``)."""
        stage = RangeStage(self)
        for hook, params in acting(self.effects, "on_range"):
            z = hook(z, params, stage)
        return z

    def prepare(self, scene: Scene, pose: Pose, exposure_us: float, seed: int, step_index: int,
                projector: bool = True) -> StereoPrepared:
        z, valid, ir, sigma_disp = self.expected(self.render_scene(scene, pose), exposure_us, projector)
        return StereoPrepared(
            disparity=(self.focal_baseline / np.where(valid, z, 1.0)).astype(np.float32),
            sigma_disp=sigma_disp.astype(np.float32),
            valid=valid,
            ir=ir.astype(np.float32),
            bank=make_bank(seed, self.profile.width * self.profile.height, 2),
            seed=seed,
            step_index=step_index,
        )

    def _visible_from_right(self, scene: Scene, pose: Pose, z_left: np.ndarray) -> np.ndarray:
        """False where the right camera (baseline to the right) cannot see the left pixel's point."""
        geo, p = self.geometry, self.profile
        right_pose = Pose(pose.rotation, pose.position + pose.rotation @ np.array([p.baseline_mm, 0.0, 0.0]))
        right = render(scene, right_pose, geo.optics, surface_properties(scene, {}), supersample=1, oversample=1)
        u, v = geo.optics.pixel_grid()
        with np.errstate(invalid="ignore", divide="ignore"):
            u_right = np.round(u - self.focal_baseline / z_left)
        inside = np.isfinite(u_right) & (u_right >= 0) & (u_right <= p.width - 1)
        cols = np.clip(np.nan_to_num(u_right), 0, p.width - 1).astype(int)
        z_seen = right.z_dom[v.astype(int), cols]
        tolerance = np.maximum(20.0, 0.02 * np.nan_to_num(z_left))
        return inside & ~(z_seen < z_left - tolerance)

    def frame(self, prep: StereoPrepared, k: int, t_s: float) -> tuple[np.ndarray, ...]:
        """Frame ``k`` at device time ``t_s``: (x, y, z, intensity, confidence)."""
        p = self.profile
        h, w = p.height, p.width
        drift, step = frame_offset_mm(self.effects, t_s), output_step_mm(self.effects)
        off_disp, off_ir = prep.bank.offsets(prep.seed, prep.step_index, k)
        x, y, z, intensity, confidence = (np.empty((h, w), np.float32) for _ in range(5))
        stereo_frame(prep.disparity, prep.sigma_disp, prep.valid, self.geometry.tx, self.geometry.ty, prep.ir,
                     IR_NOISE, prep.bank.samples, off_disp, off_ir, drift, p.disparity_step_px,
                     self.focal_baseline, step, x, y, z, intensity, confidence)
        return x, y, z, intensity, confidence
