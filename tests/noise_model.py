"""The simulated cameras' noise law on the wall, as tests predict measured figures from it."""

from __future__ import annotations

import numpy as np

from sim.geometry import Pose
from sim.scenes.targets import build_scene
from sim.stereo import StereoSensor
from sim.tof import ToFSensor, range_noise_mm


def wall_sigma_z(model, distance_mm: float) -> np.ndarray:
    """The model's per-pixel depth noise (mm, NaN invalid) on the wall: eq. 2-9 for ToF along the ray, the
    disparity noise z^2 / (f B) sigma_d for stereo, plus the output quantization's step^2 / 12."""
    p, effects = model.profile(), model.effect_params()
    scene = build_scene("wall", {}, p.wavelength_nm, distance_mm)
    if p.technology == "tof":
        sensor = ToFSensor(p, effects)
        range_mm, amplitude, ambient = sensor.expected(sensor.render_scene(scene, Pose.at_origin()), p.exposure_us)
        tx, ty = sensor.geometry.tx, sensor.geometry.ty
        sigma = range_noise_mm(p, amplitude, ambient) / np.sqrt(1 + tx**2 + ty**2)
        sigma = np.where(np.isfinite(range_mm), sigma, np.nan)
    else:
        sensor = StereoSensor(p, effects)
        z, valid, _, sigma_disp = sensor.expected(sensor.render_scene(scene, Pose.at_origin()), p.exposure_us)
        disparity = np.sqrt(sigma_disp**2 + p.disparity_step_px**2 / 12)
        sigma = np.where(valid, z**2 / sensor.focal_baseline * disparity, np.nan)
    step = effects["quantization"].step_mm if "quantization" in effects else 0.0
    return np.sqrt(sigma**2 + step**2 / 12)
