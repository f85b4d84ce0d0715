"""Active-stereo depth physics (first model; DESIGN "Simulation physics").

Disparity d = f_px b / z carries Gaussian matching noise of s pixels, so the
depth noise grows as sigma_z = z^2 s / (f_px b). The profile's
``noise_mm_at_2m`` fixes s. Depth outside [min_range, max_range] is invalid.
The intensity image is the left IR camera: reflectance * cos(theta) / r^2
scaled to 1000 at 2 m on the wall, with 1 % noise.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sim.profiles import CameraProfile
from sim.scene import WALL_REFLECTANCE, SceneHit

REFERENCE_RANGE_MM = 2000.0


@dataclass(frozen=True)
class StereoPrepared:
    z_mm: np.ndarray
    disparity_px: np.ndarray
    slopes: tuple[np.ndarray, np.ndarray]
    ir: np.ndarray
    in_range: np.ndarray


class StereoSensor:
    """Per-pixel active-stereo measurement model for one camera profile."""

    def __init__(self, profile: CameraProfile, fx: float) -> None:
        self.profile = profile
        self.focal_baseline = fx * profile.baseline_mm
        self.subpixel_noise_px = profile.noise_mm_at_2m * self.focal_baseline / REFERENCE_RANGE_MM**2

    def prepare(self, hit: SceneHit, rays: np.ndarray, exposure_us: float) -> StereoPrepared:
        p = self.profile
        z = hit.range_mm * rays[2]
        ir = (
            1000.0 * (exposure_us / p.exposure_us) * (hit.reflectance / WALL_REFLECTANCE)
            * hit.cos_incidence * (REFERENCE_RANGE_MM / hit.range_mm) ** 2
        )
        return StereoPrepared(
            z_mm=z,
            disparity_px=self.focal_baseline / z,
            slopes=(rays[0] / rays[2], rays[1] / rays[2]),
            ir=ir,
            in_range=(z >= p.min_range_mm) & (z <= p.max_range_mm),
        )

    def frame(self, prep: StereoPrepared, rng: np.random.Generator) -> tuple[np.ndarray, ...]:
        """One noisy frame: (x, y, z, intensity, confidence)."""
        noise = rng.standard_normal((2, *prep.z_mm.shape), dtype=np.float32)
        disparity = prep.disparity_px + self.subpixel_noise_px * noise[0]
        with np.errstate(divide="ignore"):
            z = self.focal_baseline / disparity
        valid = prep.in_range & (disparity > 0)
        z = np.where(valid, z, np.nan).astype(np.float32)
        x = (z * prep.slopes[0]).astype(np.float32)
        y = (z * prep.slopes[1]).astype(np.float32)
        intensity = (prep.ir * (1.0 + 0.01 * noise[1])).astype(np.float32)
        return x, y, z, intensity, valid.astype(np.float32)
