"""The camera model that measurements and simulation share: pinhole, angular resolution, pixel aspect ratio.

Pixel centres sit at integer (u, v); the principal point is the image centre
((W-1)/2, (H-1)/2); the focal lengths follow from the FOV as
f_x = (W/2) / tan(FOV_h/2) and f_y = (H/2) / tan(FOV_v/2) (Thesis 2024, 5.2), so a
FOV ratio that differs from W/H gives non-square pixels (pixel aspect ratio).
Back-projection follows Thesis 2024, eq. 2-2/2-3: x = z (u - c_x)/f_x, y = z (v - c_y)/f_y.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np


@dataclass(frozen=True)
class Pinhole:
    """Pinhole camera of ``width`` x ``height`` pixels and the given FOV in degrees (Thesis 2024, 5.2, eq. 2-2/2-3).

    A 90 deg FOV over 640 x 480 pixels: f_x = 320 / tan(45 deg) = 320, f_y = 240 / tan(45 deg) = 240,
    principal point at ((640 - 1) / 2, (480 - 1) / 2).

    >>> cam = Pinhole(640, 480, 90.0, 90.0)
    >>> round(cam.fx, 9), round(cam.fy, 9), cam.cx, cam.cy
    (320.0, 240.0, 319.5, 239.5)

    Ray slopes: two pixels over 90 deg give f = 1 / tan(45 deg) = 1 and c = 0.5, so slopes of -0.5 and +0.5.

    >>> tx, ty = Pinhole(2, 2, 90.0, 90.0).slopes
    >>> tx.round(9).tolist(), ty.round(9).tolist()
    ([[-0.5, 0.5]], [[-0.5], [0.5]])

    Unit rays: the centre pixel of three over 90 deg looks along the axis; the corner pixel, at slopes
    (-2/3, -2/3), along (-2/3, -2/3, 1) / sqrt(17/9) = (-2, -2, 3) / sqrt(17).

    >>> rays = Pinhole(3, 3, 90.0, 90.0).unit_rays
    >>> rays.shape, rays[:, 1, 1].round(9).tolist()
    ((3, 3, 3), [0.0, 0.0, 1.0])
    >>> bool(np.allclose(rays[:, 0, 0], np.array([-2.0, -2.0, 3.0]) / math.sqrt(17)))
    True
    """

    width: int
    height: int
    fov_h_deg: float
    fov_v_deg: float

    @property
    def fx(self) -> float:
        """Horizontal focal length in pixels, (W/2) / tan(FOV_h/2)."""
        return (self.width / 2) / math.tan(math.radians(self.fov_h_deg) / 2)

    @property
    def fy(self) -> float:
        """Vertical focal length in pixels, (H/2) / tan(FOV_v/2)."""
        return (self.height / 2) / math.tan(math.radians(self.fov_v_deg) / 2)

    @property
    def cx(self) -> float:
        """Principal point column, (W-1)/2."""
        return (self.width - 1) / 2

    @property
    def cy(self) -> float:
        """Principal point row, (H-1)/2."""
        return (self.height - 1) / 2

    @cached_property
    def slopes(self) -> tuple[np.ndarray, np.ndarray]:
        """(x/z per column as (1, W), y/z per row as (H, 1)), float64: (u - c_x)/f_x and (v - c_y)/f_y (eq. 2-2/2-3;
        example in the class docstring)."""
        tx = (np.arange(self.width) - self.cx) / self.fx
        ty = (np.arange(self.height) - self.cy) / self.fy
        return tx[None, :], ty[:, None]

    @cached_property
    def unit_rays(self) -> np.ndarray:
        """(3, H, W) float64 unit direction of every pixel's ray (camera frame, z forward): (tx, ty, 1) / |(tx, ty, 1)|
        (example in the class docstring)."""
        tx, ty = self.slopes
        tx, ty = np.broadcast_arrays(tx, ty)
        norm = np.sqrt(1.0 + tx**2 + ty**2)
        return np.stack([tx / norm, ty / norm, 1.0 / norm])


def sensor_angular_resolution_deg(fov_deg: float, pixels: int) -> float:
    """Angle covered by one pixel (Thesis 2024, eq. 5-1): FOV / number of pixels.

    >>> sensor_angular_resolution_deg(64.0, 640)
    0.1
    """
    return fov_deg / pixels


def pixel_aspect_distortion_pct(fov_h_deg: float, fov_v_deg: float, width: int, height: int) -> float:
    """Distortion due to the pixel aspect ratio (Thesis 2024, Table 6-5 row 1), normalized to the width.

    (angular pixel height / angular pixel width - 1) in percent. 64 deg over 640 pixels is 0.1 deg per column,
    44 deg over 400 pixels 0.11 deg per row: 0.11 / 0.1 - 1 = 10 %.

    >>> round(pixel_aspect_distortion_pct(64.0, 44.0, 640, 400), 9)
    10.0
    """
    return 100.0 * (
        sensor_angular_resolution_deg(fov_v_deg, height) / sensor_angular_resolution_deg(fov_h_deg, width) - 1.0
    )
