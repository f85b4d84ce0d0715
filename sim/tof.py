"""Continuous-wave Time-of-Flight sensor physics (Thesis 2024, 2.3.1).

Per step (noise-free, once):

1. render the scene (sim/render.py): per pixel the returned light
   rho cos^m / r^2 and the correlation phasor sum of its sub-samples;
2. amplitude A = A_ref (t_exp / t_default) irradiance / irradiance(90 % wall at 2 m),
   blurred by the lens PSF (and the ``defocus`` disc), times ``vignetting``;
   A_ref is fixed by the profile's ``noise_mm_at_2m`` through eq. 2-9;
3. range: the dominant surface's range, or with ``flying_pixels`` (or
   ``multipath``) the phase of the blurred phasor sum (plus the multipath
   return), the bounce off a second surface (``floor_multipath``), then the
   range effects: ``wiggling``, ``range_scale``, ``range_offset``,
   ``intensity_related_error``, ``fixed_pattern``, then the empirical
   corrections a reconcile fitted (``empirical_range``,
   ``empirical_pixel_map``); ``material_bias`` lengthens ranges on
   translucent materials;
4. noise (eq. 2-9, Li 2014): sigma_r = c / (4 sqrt2 pi f_mod) sqrt(A + B) / (c_d A)
   with B = A + B_ambient, B_ambient = (ambient_ratio + background) A_ref t_exp / t_default, background
   the effects' background light (``ambient_light``);
   the amplitude itself scatters by sqrt(B / 2).

Per frame (sim/kernels.py): noise from the step's bank, ``temperature_drift``,
x, y, z along the reported rays, ``quantization``, validity (confidence
threshold, saturation, measurement range). Phase unwrapping is taken as
perfect (multi-frequency cameras).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from sim.effects import (
    EFFECTS,
    EffectParams,
    PhasorStage,
    RangeStage,
    acting,
    background_level,
    frame_offset_mm,
    output_step_mm,
    shading_factor,
)
from sim.geometry import Pose
from sim.kernels import tof_frame
from sim.materials import get_material
from sim.noise import NoiseBank, make_bank
from sim.profiles import CameraProfile
from sim.render import C_MM_PER_S, Rendered, SurfaceProperties, render
from sim.scenes.base import Scene
from sim.sensor import SensorOptics

REFERENCE_RANGE_MM = 2000.0
REFERENCE_REFLECTANCE = 0.90
IRRADIANCE_REF = REFERENCE_REFLECTANCE / (REFERENCE_RANGE_MM / 1000.0) ** 2


def noise_constant_mm(modulation_mhz: float) -> float:
    """c / (4 sqrt(2) pi f_mod) in mm: the prefactor of eq. 2-9."""
    return C_MM_PER_S / (4.0 * math.sqrt(2.0) * math.pi * modulation_mhz * 1e6)


def range_noise_mm(profile: CameraProfile, amplitude: np.ndarray, ambient: float) -> np.ndarray:
    """Eq. 2-9: sigma = k sqrt(A + B) / (c_d A) with B = A + ambient."""
    k = noise_constant_mm(profile.modulation_mhz)
    with np.errstate(divide="ignore", invalid="ignore"):
        return k * np.sqrt(2.0 * amplitude + ambient) / (profile.modulation_contrast * amplitude)


def reference_amplitude(profile: CameraProfile) -> float:
    """A_ref such that eq. 2-9 gives ``noise_mm_at_2m`` at 2 m on the 90 % wall (centre pixel).

    With B = A + r_a A: sigma = k sqrt(2 + r_a) / (c_d sqrt(A)), solved for A.
    """
    k = noise_constant_mm(profile.modulation_mhz)
    return (k * math.sqrt(2.0 + profile.ambient_ratio) / (profile.modulation_contrast * profile.noise_mm_at_2m)) ** 2


def surface_properties(scene: Scene, effects: dict[str, EffectParams]) -> SurfaceProperties:
    """Per-surface sub-surface bias (scaled by the effects' ``subsurface_scale``, 0 without) and Lambertian
    exponent."""
    materials = [get_material(name) for name in scene.materials()] or [get_material("wall")]
    scale = 0.0
    for hook, params in acting(effects, "subsurface_scale"):
        scale = scale + hook(params)
    return SurfaceProperties(
        bias_mm=np.array([scale * m.subsurface_bias_mm for m in materials]),
        lambert=np.array([m.lambertian_exponent for m in materials]),
    )


@dataclass(frozen=True)
class ToFPrepared:
    """Noise-free per-pixel maps of one step, reused for every frame of its stack."""

    range_mm: np.ndarray
    amplitude: np.ndarray
    ambient: float
    bank: NoiseBank
    seed: int
    step_index: int


class ToFSensor:
    """Per-pixel CW-ToF measurement model for one camera profile and set of effects."""

    technology = "tof"

    def __init__(self, profile: CameraProfile, effects: dict[str, EffectParams]) -> None:
        self.profile = profile
        self.effects = effects
        self.geometry = SensorOptics(profile, effects)
        self.a_ref = reference_amplitude(profile)
        self.wavenumber = 4.0 * math.pi * profile.modulation_mhz * 1e6 / C_MM_PER_S
        present = [EFFECTS[name] for name in effects]
        self.mixes_returns = any(e.mixes_returns for e in present)
        self.mixed_pixels = any(e.mixed_pixels for e in present)

    def render_scene(self, scene: Scene, pose: Pose, border: bool = False) -> Rendered:
        """The ray-cast light of a scene through this camera's optics (the expensive, geometric part); ``border``:
        edges between the outer samples and the image border found too (``render``)."""
        return render(scene, pose, self.geometry.optics, surface_properties(scene, self.effects),
                      modulation_mhz=self.profile.modulation_mhz if self.mixes_returns else None, border=border)

    def shading(self) -> np.ndarray | float:
        """The factor the effects' ``shading`` puts on the light after the blur (1 without)."""
        return shading_factor(self.effects, self.geometry.cos_alpha)

    def returns(self, r: Rendered, exposure_us: float) -> np.ndarray:
        """Per pixel, the correlation phasor of every return reaching it (each sub-pixel's surface at its own
        range) through the optical PSF, in amplitude units; needs a render that kept the phasors
        (``mixes_returns``)."""
        return self._returns(r, self._scale(exposure_us), self.shading())

    def _scale(self, exposure_us: float) -> float:
        """Amplitude units per unit of rendered irradiance at ``exposure_us``."""
        return self.a_ref * (exposure_us / self.profile.exposure_us) / IRRADIANCE_REF

    def _returns(self, r: Rendered, scale: float, shading: np.ndarray | float) -> np.ndarray:
        assert r.phasor_fine is not None
        return self.geometry.blur(r.phasor_fine, r.centre_distance_mm, r.oversample) * scale * shading

    def expected(self, r: Rendered, exposure_us: float, cut: bool = True,
                 report: Callable[[np.ndarray, np.ndarray], np.ndarray] | None = None,
                 ) -> tuple[np.ndarray, np.ndarray, float]:
        """Noise-free range (mm, NaN where invalid), amplitude (0 where invalid) and ambient light of a render;
        with ``cut`` False, the camera's range is left to the caller (invalid only where nothing was hit).
        ``report`` maps each pixel's range and returned light to the range it reports (default ``range_of``; a
        binned camera's prediction averages it over the pixels of a bin)."""
        p = self.profile
        focus_distance_mm = r.centre_distance_mm
        gain = exposure_us / p.exposure_us
        scale = self._scale(exposure_us)
        light = self.geometry.blur(r.irradiance_fine, focus_distance_mm, r.oversample) * scale
        shading = self.shading()
        amplitude = np.maximum(light * shading, 0.0)
        phasor, stage = None, None
        if r.phasor is not None:
            returns = self._returns(r, scale, shading)
            stage = PhasorStage(self, complex(returns.mean()))
            if self.mixed_pixels:
                phasor = returns
            else:  # the dominant surface alone
                phasor = amplitude * np.exp(1j * self.wavenumber * np.nan_to_num(r.range_dom))
        range_mm = (report or self.range_of)(self._returned_range(r.range_dom, phasor, stage), light)
        in_range = (r.hit_fraction > 0) & ((range_mm >= p.min_range_mm) & (range_mm <= p.max_range_mm) if cut else True)
        valid = in_range & np.isfinite(range_mm)
        ambient = (p.ambient_ratio + background_level(self.effects)) * self.a_ref * gain
        return np.where(valid, range_mm, np.nan), np.where(valid, amplitude, 0.0), ambient

    def prepare(self, scene: Scene, pose: Pose, exposure_us: float, seed: int, step_index: int) -> ToFPrepared:
        range_mm, amplitude, ambient = self.expected(self.render_scene(scene, pose), exposure_us)
        return ToFPrepared(
            range_mm=np.nan_to_num(range_mm, nan=0.0).astype(np.float32),
            amplitude=amplitude.astype(np.float32),
            ambient=ambient,
            bank=make_bank(seed, self.profile.width * self.profile.height, 2),
            seed=seed,
            step_index=step_index,
        )

    def _returned_range(self, range_dom: np.ndarray, phasor: np.ndarray | None,
                        stage: PhasorStage | None = None) -> np.ndarray:
        """Range per pixel of its dominant or, where an effect ``mixes_returns``, its mixed return: ``phasor`` is
        then the pixel's correlation phasor, which the effects' ``phasor`` hooks act on first (with ``stage``:
        the scene's mean return)."""
        if phasor is None or stage is None:
            return range_dom
        for hook, params in acting(self.effects, "phasor"):
            phasor = hook(phasor, params, stage)
        ref = np.nan_to_num(range_dom)
        residual = np.angle(phasor * np.exp(-1j * self.wavenumber * ref))
        return np.where(np.isfinite(range_dom), ref + residual / self.wavenumber, np.nan)

    def range_of(self, range_mm: np.ndarray, light: np.ndarray) -> np.ndarray:
        """The range a pixel at ``range_mm`` that returns ``light`` (before vignetting) reports: after the
        effects' range hooks, before temporal noise."""
        stage = RangeStage(self, light)
        for hook, params in acting(self.effects, "on_range"):
            range_mm = hook(range_mm, params, stage)
        return range_mm

    def frame(self, prep: ToFPrepared, k: int, t_s: float) -> tuple[np.ndarray, ...]:
        """Frame ``k`` of the stack, taken at device time ``t_s``: (x, y, z, intensity, confidence)."""
        p = self.profile
        h, w = p.height, p.width
        drift, step = frame_offset_mm(self.effects, t_s), output_step_mm(self.effects)
        off_amp, off_range = prep.bank.offsets(prep.seed, prep.step_index, k)
        x, y, z, intensity = (np.empty((h, w), np.float32) for _ in range(4))
        confidence = np.empty((h, w), np.dtype(p.confidence_dtype))
        conf_scale = 65535.0 if p.confidence_dtype == "uint16" else 1.0
        tof_frame(prep.range_mm, prep.amplitude, self.geometry.tx, self.geometry.ty, prep.bank.samples,
                  off_amp, off_range, noise_constant_mm(p.modulation_mhz), p.modulation_contrast, prep.ambient,
                  drift, step, p.confidence_threshold_ratio * self.a_ref, p.saturation_ratio * self.a_ref,
                  conf_scale, x, y, z, intensity, confidence)
        return x, y, z, intensity, confidence
