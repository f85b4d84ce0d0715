"""intensity_related_error: range error growing as the returned light falls.

Delta r = error_at_reference_mm * A_ref / A, with A the pixel's amplitude and
A_ref the amplitude of the 90 % wall at 2 m (image centre, default exposure).
Source: Lindner & Kolb 2007 (intensity-related distance error of PMD
cameras: the error grows about as 1/A).
"""

from __future__ import annotations

import numpy as np
from pydantic import Field

from sim.effects.base import Effect, EffectParams, Observed


class Params(EffectParams):
    error_at_reference_mm: float = Field(1.0, ge=-50.0, le=50.0, description="error at A = A_ref, mm")


def error_mm(amplitude: np.ndarray, reference_amplitude: float, p: Params) -> np.ndarray:
    with np.errstate(divide="ignore"):
        return np.where(amplitude > 0, p.error_at_reference_mm * reference_amplitude / amplitude, 0.0)


EFFECT = Effect(
    "intensity_related_error",
    ("tof",),
    Params,
    "Lindner & Kolb 2007",
    observed=Observed("inverse_light", fitted=("error_at_reference_mm",), procedure="depth_sweep"),
    order=50,
    on_range=lambda values, p, at: values + error_mm(at.light, at.sensor.a_ref, p),
)
