"""Continuous-wave Time-of-Flight sensor physics (thesis 2.3.1).

Amplitude: A = A_ref * (rho / 0.9) * cos(theta) * (2000 mm / r)^2 * (t_exp / t_exp,default),
where A_ref (photo-electrons) is fixed by the profile's noise at 2 m through
eq. 2-9 (Li 2014):

    sigma_r = c / (4 sqrt(2) pi f_mod) * sqrt(A + B) / (c_d A)

with offset B = A + B_ambient (the signal's own DC part plus ambient light,
B_ambient = ambient_ratio * A_ref * t_exp/t_exp,default). Pixels whose
amplitude lies below the confidence threshold or above saturation are invalid
(NaN). Range noise acts along the ray; x, y, z follow from the noisy range.
Phase unwrapping is assumed perfect (multi-frequency cameras).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from sim.profiles import CameraProfile
from sim.scene import WALL_REFLECTANCE, SceneHit

C_MM_PER_S = 299_792_458_000.0
REFERENCE_RANGE_MM = 2000.0


def noise_constant_mm(modulation_mhz: float) -> float:
    """c / (4 sqrt(2) pi f_mod) in mm: the prefactor of eq. 2-9."""
    return C_MM_PER_S / (4.0 * math.sqrt(2.0) * math.pi * modulation_mhz * 1e6)


def range_noise_mm(profile: CameraProfile, amplitude: np.ndarray, ambient: float) -> np.ndarray:
    """Eq. 2-9: sigma = k sqrt(A + B) / (c_d A) with B = A + ambient."""
    k = noise_constant_mm(profile.modulation_mhz)
    return k * np.sqrt(2.0 * amplitude + ambient) / (profile.modulation_contrast * amplitude)


def reference_amplitude(profile: CameraProfile) -> float:
    """A_ref such that eq. 2-9 gives ``noise_mm_at_2m`` at 2 m on the 90 % wall (centre pixel).

    With B = A + r_a A: sigma = k sqrt(2 + r_a) / (c_d sqrt(A)), solved for A.
    """
    k = noise_constant_mm(profile.modulation_mhz)
    return (k * math.sqrt(2.0 + profile.ambient_ratio) / (profile.modulation_contrast * profile.noise_mm_at_2m)) ** 2


@dataclass(frozen=True)
class ToFPrepared:
    """Noise-free quantities of one pose, reused for every frame of a stack."""

    range_mm: np.ndarray
    rays: np.ndarray
    amplitude: np.ndarray
    amplitude_sigma: np.ndarray
    range_sigma: np.ndarray
    in_range: np.ndarray
    threshold: float
    saturation: float


class ToFSensor:
    """Per-pixel CW-ToF measurement model for one camera profile."""

    def __init__(self, profile: CameraProfile) -> None:
        self.profile = profile
        self.a_ref = reference_amplitude(profile)

    def prepare(self, hit: SceneHit, rays: np.ndarray, exposure_us: float) -> ToFPrepared:
        """Amplitude and noise maps for a scene seen with ``exposure_us``."""
        p = self.profile
        gain = exposure_us / p.exposure_us
        with np.errstate(divide="ignore", invalid="ignore"):
            amplitude = (
                self.a_ref * gain * (hit.reflectance / WALL_REFLECTANCE) * hit.cos_incidence
                * (REFERENCE_RANGE_MM / hit.range_mm) ** 2
            )
        amplitude = np.nan_to_num(amplitude, nan=0.0, posinf=0.0)
        ambient = p.ambient_ratio * self.a_ref * gain
        safe = np.maximum(amplitude, 1e-9)
        return ToFPrepared(
            range_mm=hit.range_mm,
            rays=rays,
            amplitude=amplitude,
            amplitude_sigma=np.sqrt((2.0 * amplitude + ambient) / 2.0),
            range_sigma=range_noise_mm(p, safe, ambient),
            in_range=(hit.range_mm >= p.min_range_mm) & (hit.range_mm <= p.max_range_mm),
            threshold=p.confidence_threshold_ratio * self.a_ref,
            saturation=p.saturation_ratio * self.a_ref,
        )

    def frame(self, prep: ToFPrepared, rng: np.random.Generator) -> tuple[np.ndarray, ...]:
        """One noisy frame: (x, y, z, intensity, confidence)."""
        p = self.profile
        shape = prep.range_mm.shape
        noise = rng.standard_normal((2, *shape), dtype=np.float32)
        amplitude = prep.amplitude + prep.amplitude_sigma * noise[0]
        valid = prep.in_range & (amplitude >= prep.threshold) & (amplitude <= prep.saturation)
        rng_mm = prep.range_mm + prep.range_sigma * noise[1]
        xyz = (rng_mm * prep.rays).astype(np.float32)
        if p.z_quantization_mm > 0:
            xyz = np.round(xyz / p.z_quantization_mm) * p.z_quantization_mm
        xyz[:, ~valid] = np.nan
        intensity = np.maximum(amplitude, 0.0).astype(np.float32)
        conf = np.clip(amplitude / prep.saturation, 0.0, 1.0)
        if p.confidence_dtype == "uint16":
            confidence = np.round(conf * 65535).astype(np.uint16)
        else:
            confidence = conf.astype(np.float32)
        return xyz[0], xyz[1], xyz[2], intensity, confidence
