"""stereo_calibration_drift: the stereo calibration no longer matches the rig (active stereo).

z' = f b (1 + e) / (d + delta),   d = f b / z,

with d the true disparity in pixels of the camera's own sensor, f its focal
length (px), b the baseline (mm). A mechanical or thermal shift of one
imager after calibration moves the rectified image rows and columns: the
matched disparity is off by a constant ``disparity_offset_px`` delta, which
to first order changes the depth by -z^2 delta / (f b), an error growing as
the square of the distance; a wrong baseline (or focal length) in the stored
calibration scales every depth by 1 + ``baseline_error`` e, the form of
``range_scale``: reconcile fits the offset and leaves a scale to that effect.
Source: Gallup et al. 2008 (depth error of stereo = z^2 / (f b) x disparity
error); Dang, Hoffmann & Stiller 2009 (continuous stereo self-calibration:
drift of the relative orientation after calibration); Grunnet-Jepsen et al.,
Intel RealSense self-calibration for D400 series depth cameras (white paper:
on-chip calibration and the tare of the absolute depth).
"""

from __future__ import annotations

import numpy as np
from pydantic import Field

from sim.effects.base import Effect, EffectParams, Observed


class Params(EffectParams):
    disparity_offset_px: float = Field(0.1, ge=-5.0, le=5.0, description="added to every disparity, px")
    baseline_error: float = Field(0.0, ge=-0.1, le=0.1, description="relative error of f b, 0.01 = 1 %")


def apply(z_mm: np.ndarray, focal_baseline: float, p: Params) -> np.ndarray:
    """Depth from the offset disparity with the drifted calibration; ``focal_baseline`` = f (px of the
    camera's own sensor) x b (mm)."""
    with np.errstate(invalid="ignore", divide="ignore"):
        return focal_baseline * (1.0 + p.baseline_error) / (focal_baseline / z_mm + p.disparity_offset_px)


EFFECT = Effect(
    "stereo_calibration_drift",
    ("stereo",),
    Params,
    "Gallup et al. 2008; Dang et al. 2009; Intel RealSense D400 self-calibration (Grunnet-Jepsen et al.)",
    observed=Observed("disparity_offset", fitted=("disparity_offset_px",), fixed={"baseline_error": 0.0}),
    order=16,
    on_range=lambda values, p, at: apply(values, at.sensor.matching_focal_baseline, p),
)
