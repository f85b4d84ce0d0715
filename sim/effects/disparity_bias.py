"""disparity_bias: sub-pixel disparity bias periodic in the disparity (active stereo, "pixel locking").

d' = d + a sin(2 pi d / P + phi),   z' = f b / d',   d = f b / z

with d the true disparity in pixels of the camera's own sensor, f its focal
length (px), b the baseline (mm), P the period in pixels (1 for the sub-pixel
interpolation of a correlation peak; other periods where the matcher works on
a finer or coarser disparity grid, so reconcile fits it). Area-based matching finds the
correlation peak at integer disparities and interpolates the sub-pixel part
(parabola or equiangular line fit); the interpolated position is pulled
towards integer values, a bias that repeats every pixel of disparity and
vanishes at integer and half-integer disparities (phi = 0). Source: Shimizu &
Okutomi 2001 ("Precise sub-pixel estimation on area-based matching");
Szeliski & Scharstein 2004 (sampling the disparity space image); pixel locking
in correlation PIV (Westerweel 1997).
"""

from __future__ import annotations

import math

import numpy as np
from pydantic import Field

from sim.effects.base import Effect, EffectParams, Observed


class Params(EffectParams):
    amplitude_px: float = Field(0.05, ge=0.0, le=0.5, description="bias amplitude, px of disparity")
    phase_rad: float = Field(0.0, ge=-2 * math.pi, le=2 * math.pi)
    period_px: float = Field(1.0, gt=0.0, le=16.0, description="disparity per cycle, px")


def bias_px(disparity_px: np.ndarray, p: Params) -> np.ndarray:
    """The disparity bias at the true disparity ``disparity_px``."""
    return p.amplitude_px * np.sin(2 * math.pi * disparity_px / p.period_px + p.phase_rad)


def apply(z_mm: np.ndarray, focal_baseline: float, p: Params) -> np.ndarray:
    """Depth measured with the biased disparity; ``focal_baseline`` = f (px of the camera's own sensor) x b (mm)."""
    with np.errstate(invalid="ignore", divide="ignore"):
        d = focal_baseline / z_mm
        return focal_baseline / (d + bias_px(d, p))


EFFECT = Effect(
    "disparity_bias",
    ("stereo",),
    Params,
    "Shimizu & Okutomi 2001; Szeliski & Scharstein 2004",
    observed=Observed("periodic_disparity", fitted=("amplitude_px", "period_px", "phase_rad"),
                      solver_bounds={"phase_rad": (-4 * math.pi, 4 * math.pi)}),
    order=15,
    on_range=lambda values, p, at: apply(values, at.sensor.matching_focal_baseline, p),
    periodic_range=True,
)
