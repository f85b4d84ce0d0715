"""The simulated cameras' noise law on the wall, as tests predict measured figures from it, derived here from the
physics alone (nothing of the simulator is imported; the camera's numbers come from the model's profile).

Wall: the 90 % matte white wall (``WALL``: remission, Lambert exponent m) facing the camera at distance D. A
pixel's pinhole ray has slopes t_x = (u - (W - 1) / 2) / f_x, t_y likewise, f = (W / 2) / tan(FOV / 2); it
meets the wall at the angle gamma from the axis, cos gamma = 1 / sqrt(1 + t_x^2 + t_y^2), range D / cos gamma,
and at incidence gamma.

ToF: the light a pixel collects relative to the 90 % wall at 2 m on the axis (where the profile states its
noise sigma_2) is a = (rho / 0.9) cos^m gamma (2000 cos gamma / D)^2. A 4-tap pixel's phase noise is the
shot noise of everything it integrates over the demodulated signal: signal ~ a, integrated charge ~ 2 a (the
correlation's mean and amplitude) plus the ambient light b (the profile's ``ambient_ratio``, in units of the
2 m signal), so sigma_r(a) / sigma_2 = sqrt((2 a + b) / (2 + b)) / a. Depth z = range cos gamma, so the
depth noise is sigma_r cos gamma.

Stereo: the disparity d = f B / z carries the profile's sub-pixel noise s = sigma_2 f B / 2000^2 (sigma_2
at 2 m and dz = z^2 / (f B) dd), growing with the incidence theta as s (1 + g theta^2 / (pi / 2 - theta)^2)
(``angle_noise_gain`` g); rounding to ``disparity_step_px`` q adds q^2 / 12; the left band the right camera
(B to the right) cannot see, columns u < f B / z - 1/2, is invalid.

Both: outside the measuring range invalid; the output rounded to the ``quantization`` step adds step^2 / 12.
"""

from __future__ import annotations

import math

import numpy as np

WALL = (0.90, 1.0)  # the wall's remission at the cameras' wavelengths and its Lambert exponent
REFERENCE_MM = 2000.0  # the distance of the profile's stated noise


def tof_sigma_mm(profile, a: np.ndarray) -> np.ndarray:
    """ToF range noise (mm) of pixels collecting ``a`` times the light of the 90 % wall at 2 m on the axis:
    sigma_2 sqrt((2 a + b) / (2 + b)) / a (the module's docstring)."""
    b = profile.ambient_ratio
    with np.errstate(divide="ignore", invalid="ignore"):
        return profile.noise_mm_at_2m * np.sqrt((2 * a + b) / (2 + b)) / a


def focal_baseline(profile) -> float:
    """f B: the pinhole focal length (px, from the horizontal FOV) times the baseline (mm)."""
    return profile.width / 2 / math.tan(math.radians(profile.fov_h_deg) / 2) * profile.baseline_mm


def wall_geometry(profile, distance_mm: float) -> tuple[np.ndarray, np.ndarray]:
    """(H, W) cos gamma of each pixel's ray and the (H, W) column index."""
    v, u = np.mgrid[0:profile.height, 0:profile.width].astype(float)
    tx = (u - (profile.width - 1) / 2) / (profile.width / 2 / math.tan(math.radians(profile.fov_h_deg) / 2))
    ty = (v - (profile.height - 1) / 2) / (profile.height / 2 / math.tan(math.radians(profile.fov_v_deg) / 2))
    return 1.0 / np.sqrt(1.0 + tx * tx + ty * ty), u


def wall_sigma_z(model, distance_mm: float) -> np.ndarray:
    """The model's per-pixel depth noise (mm, NaN invalid) on the wall (the module's docstring)."""
    p = model.profile()
    effects = model.effect_params()
    cos, u = wall_geometry(p, distance_mm)
    range_mm = distance_mm / cos
    valid = (range_mm >= p.min_range_mm) & (range_mm <= p.max_range_mm)
    if p.technology == "tof":
        rho, m = WALL
        a = rho / 0.9 * cos**m * (REFERENCE_MM * cos / distance_mm) ** 2
        sigma = tof_sigma_mm(p, a) * cos
    else:
        fb = focal_baseline(p)
        s = p.noise_mm_at_2m * fb / REFERENCE_MM**2
        theta = np.arccos(cos)
        sigma_d = s * (1 + p.angle_noise_gain * theta**2 / (math.pi / 2 - theta) ** 2)
        valid &= u >= fb / distance_mm - 0.5
        sigma = distance_mm**2 / fb * np.sqrt(sigma_d**2 + p.disparity_step_px**2 / 12)
    step = effects["quantization"].step_mm if "quantization" in effects else 0.0
    return np.where(valid, np.sqrt(sigma**2 + step**2 / 12), np.nan)
