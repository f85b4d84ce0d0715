"""Camera optics of the simulated sensors: true optics with radial distortion, blur, depth of field.

The pinhole these optics start from, with its pixel and principal-point conventions, is the camera model that
the metrics share (metrics/optics.py).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from metrics.optics import Pinhole


@dataclass(frozen=True)
class CameraOptics:
    """The camera's true optics: pinhole of the true FOV plus Brown radial distortion.

    Distortion (Thesis 2024, eq. 5-5; effect ``radial_distortion`` of docs/simulation.md): a scene point whose
    undistorted image lies at radius r_u from the principal point appears at
    r_d = r_u (1 + k1 (r_u / R)^2), R = half the image diagonal in pixels.
    ``directions`` maps (distorted) pixel positions to the rays they see.
    """

    pinhole: Pinhole
    k1: float = 0.0

    @property
    def half_diagonal_px(self) -> float:
        return math.hypot(self.pinhole.width, self.pinhole.height) / 2

    def undistort(self, u: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Undistorted pixel positions of distorted ones (Newton on r_d = r_u (1 + k1 (r_u/R)^2))."""
        if self.k1 == 0.0:
            return u, v
        p = self.pinhole
        du, dv = u - p.cx, v - p.cy
        r_d = np.hypot(du, dv)
        big_r = self.half_diagonal_px
        r_u = r_d.copy()
        for _ in range(20):
            f = r_u * (1 + self.k1 * (r_u / big_r) ** 2) - r_d
            df = 1 + 3 * self.k1 * (r_u / big_r) ** 2
            step = f / df
            if not step.any():  # converged to the last bit: further steps would change nothing
                break
            r_u = r_u - step
        scale = np.where(r_d > 0, r_u / np.where(r_d > 0, r_d, 1.0), 1.0)
        return p.cx + du * scale, p.cy + dv * scale

    def distort(self, u: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Where undistorted pixel positions appear in the image."""
        p = self.pinhole
        du, dv = u - p.cx, v - p.cy
        scale = 1 + self.k1 * (np.hypot(du, dv) / self.half_diagonal_px) ** 2
        return p.cx + du * scale, p.cy + dv * scale

    def directions(self, u: np.ndarray, v: np.ndarray) -> np.ndarray:
        """Unit camera-frame rays (3, ...) seen at (distorted) pixel positions (u, v)."""
        uu, vv = self.undistort(np.asarray(u, float), np.asarray(v, float))
        p = self.pinhole
        sx, sy = (uu - p.cx) / p.fx, (vv - p.cy) / p.fy
        rays = np.empty((3, *sx.shape))
        np.divide(1.0, np.sqrt(1.0 + sx * sx + sy * sy), out=rays[2])
        np.multiply(sx, rays[2], out=rays[0])
        np.multiply(sy, rays[2], out=rays[1])
        return rays

    def pixel_grid(self) -> tuple[np.ndarray, np.ndarray]:
        """(u, v) of every pixel centre, (H, W) each."""
        p = self.pinhole
        return np.meshgrid(np.arange(p.width, dtype=float), np.arange(p.height, dtype=float))


def lateral_resolution_mm(angular_deg: float, distance_mm: float) -> float:
    """Lateral size seen by ``angular_deg`` at ``distance_mm`` (Thesis 2024, eq. 5-2)."""
    return 2.0 * distance_mm * math.tan(math.radians(angular_deg) / 2.0)


def depth_of_field_mm(focal_mm: float, focus_mm: float, coc_mm: float, f_number: float) -> tuple[float, float]:
    """Near and far limits of acceptable sharpness (Thesis 2024, eq. 2-5, Lange 2023).

    g_near = f^2 g / (f^2 + Z F (g - f)),  g_far = f^2 g / (f^2 - Z F (g - f)),
    with focal length f, focus distance g, circle of confusion Z, f-number F;
    g_far is infinite beyond the hyperfocal distance.
    """
    f2 = focal_mm**2
    spread = coc_mm * f_number * (focus_mm - focal_mm)
    near = f2 * focus_mm / (f2 + spread)
    far = f2 * focus_mm / (f2 - spread) if f2 > spread else math.inf
    return near, far


def hyperfocal_mm(focal_mm: float, coc_mm: float, f_number: float) -> float:
    """Hyperfocal distance H = f^2 / (F Z) + f: focused at H, everything beyond H/2 is sharp."""
    return focal_mm**2 / (f_number * coc_mm) + focal_mm


def gaussian_kernel(sigma_px: float, radius_px: int | None = None) -> np.ndarray:
    """Normalized 2-D Gaussian kernel."""
    radius = radius_px if radius_px is not None else max(1, math.ceil(4 * sigma_px))
    x = np.arange(-radius, radius + 1)
    g = np.exp(-0.5 * (x / max(sigma_px, 1e-9)) ** 2)
    k = np.outer(g, g)
    return k / k.sum()


def pillbox_kernel(diameter_px: float, supersample: int = 8) -> np.ndarray:
    """Normalized uniform disc of ``diameter_px`` (defocus blur of a thin lens), area-weighted per pixel."""
    radius = diameter_px / 2.0
    size = math.ceil(radius + 0.5)
    offsets = (np.arange(supersample) + 0.5) / supersample - 0.5
    x = np.arange(-size, size + 1)
    xs = (x[:, None] + offsets[None, :]).ravel()
    inside = (xs[:, None] ** 2 + xs[None, :] ** 2) <= radius**2
    k = inside.reshape(len(x), supersample, len(x), supersample).mean(axis=(1, 3))
    if k.sum() == 0:
        k[size, size] = 1.0
    return k / k.sum()
