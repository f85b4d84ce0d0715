"""range_scale: a proportional range error, r' = r (1 + scale).

Source: a mis-set modulation frequency or clock scales all phase-derived
distances (Lindner & Kolb 2006); ``scale`` is relative (0.01 = 1 %).
"""

from __future__ import annotations

import numpy as np
from pydantic import Field

from sim.effects.base import Effect, EffectParams, Observed


class Params(EffectParams):
    scale: float = Field(0.0, ge=-0.1, le=0.1, description="relative, 0.01 = 1 %")


def apply(range_mm: np.ndarray, p: Params) -> np.ndarray:
    return range_mm * (1.0 + p.scale)


EFFECT = Effect(
    "range_scale",
    ("tof", "stereo"),
    Params,
    "Lindner & Kolb 2006",
    observed=Observed("proportional_range", fitted=("scale",), procedure="depth_sweep"),
    order=30,
    on_range=lambda values, p, _: apply(values, p),
)
