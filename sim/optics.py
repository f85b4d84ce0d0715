"""Pinhole camera geometry shared by every simulated sensor.

Pixel centres sit at integer (u, v); the principal point is the image centre
((W-1)/2, (H-1)/2); the focal lengths follow from the FOV as
f_x = (W/2) / tan(FOV_h/2) and f_y = (H/2) / tan(FOV_v/2) (SPEC §5), so a
FOV ratio that differs from W/H gives non-square pixels (pixel aspect ratio).
Back-projection follows thesis eq. 2-2/2-3: x = z (u - c_x)/f_x, y = z (v - c_y)/f_y.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np


@dataclass(frozen=True)
class Pinhole:
    width: int
    height: int
    fov_h_deg: float
    fov_v_deg: float

    @property
    def fx(self) -> float:
        return (self.width / 2) / math.tan(math.radians(self.fov_h_deg) / 2)

    @property
    def fy(self) -> float:
        return (self.height / 2) / math.tan(math.radians(self.fov_v_deg) / 2)

    @property
    def cx(self) -> float:
        return (self.width - 1) / 2

    @property
    def cy(self) -> float:
        return (self.height - 1) / 2

    @cached_property
    def slopes(self) -> tuple[np.ndarray, np.ndarray]:
        """(x/z per column as (1, W), y/z per row as (H, 1)), float64."""
        tx = (np.arange(self.width) - self.cx) / self.fx
        ty = (np.arange(self.height) - self.cy) / self.fy
        return tx[None, :], ty[:, None]

    @cached_property
    def unit_rays(self) -> np.ndarray:
        """(3, H, W) float64 unit direction of every pixel's ray (camera frame, z forward)."""
        tx, ty = self.slopes
        tx, ty = np.broadcast_arrays(tx, ty)
        norm = np.sqrt(1.0 + tx**2 + ty**2)
        return np.stack([tx / norm, ty / norm, 1.0 / norm])
