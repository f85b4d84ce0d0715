"""range_offset: a constant range error, r' = r + offset_mm.

Source: every ToF camera calibration models a constant distance offset
(Lindner & Kolb 2006; Thesis 2024, 4.1.2 measures it as the camera-laser offset).
"""

from __future__ import annotations

import numpy as np
from pydantic import Field

from sim.effects.base import Effect, EffectParams, Observed


class Params(EffectParams):
    offset_mm: float = Field(0.0, ge=-200.0, le=200.0, description="added to every range, mm")


def apply(range_mm: np.ndarray, p: Params) -> np.ndarray:
    return range_mm + p.offset_mm


EFFECT = Effect(
    "range_offset",
    ("tof", "stereo"),
    Params,
    "Lindner & Kolb 2006, ToF distance calibration; Thesis 2024, 4.1.2",
    observed=Observed(why_not="absorbed by the offset calibration and the per-group offsets"),
    order=40,
    on_range=lambda values, p, _: apply(values, p),
)
