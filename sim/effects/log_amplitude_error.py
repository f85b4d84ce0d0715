"""log_amplitude_error: range error as a smooth curve over the logarithm of the returned light (CW-ToF).

Delta r = c_1 x + c_2 x^2 + T(x),   x = log10(A / A_ref),

with A the pixel's returned light (before vignetting, as
``intensity_related_error``) and A_ref the amplitude of the 90 % wall at 2 m
(image centre, default exposure): ``per_decade_mm`` c_1 is the error per
decade of signal, ``per_decade_squared_mm`` c_2 bends the curve, and T is an
optional lookup table over x (``table_log10_ratio`` knots, increasing, and
``table_error_mm``), linear between knots and held beyond the ends, as a
vendor's per-camera calibration stores it. At A = A_ref the polynomial is 0
(a constant error is ``range_offset``). Pixels with no light get no error.
Source: Lindner et al. 2010 (the intensity-related error of PMD cameras
calibrated as a smooth function of the amplitude), Kahlmann et al. 2006
(distance corrections stored as lookup tables over the measured quantity),
Lindner & Kolb 2007 (the error grows as the signal falls).
"""

from __future__ import annotations

import numpy as np
from pydantic import Field, model_validator

from sim.effects.base import Effect, EffectParams, Observed


class Params(EffectParams):
    per_decade_mm: float = Field(-1.5, ge=-50.0, le=50.0, description="range error per decade of light, mm")
    per_decade_squared_mm: float = Field(0.0, ge=-50.0, le=50.0, description="curvature, mm per decade squared")
    table_log10_ratio: list[float] = Field(default_factory=list, description="lookup knots, log10(A / A_ref)")
    table_error_mm: list[float] = Field(default_factory=list, description="lookup error at each knot, mm")

    @model_validator(mode="after")
    def _table(self) -> Params:
        knots = self.table_log10_ratio
        if len(knots) != len(self.table_error_mm):
            raise ValueError("table_log10_ratio and table_error_mm must have the same length")
        if any(b <= a for a, b in zip(knots, knots[1:])):
            raise ValueError("table_log10_ratio must increase")
        return self

def error_mm(amplitude: np.ndarray, reference_amplitude: float, p: Params) -> np.ndarray:
    """The range error of pixels with returned light ``amplitude`` (0 where there is none)."""
    lit = amplitude > 0
    x = np.log10(np.where(lit, amplitude, reference_amplitude) / reference_amplitude)
    error = p.per_decade_mm * x + p.per_decade_squared_mm * x * x
    if p.table_log10_ratio:
        error = error + np.interp(x, p.table_log10_ratio, p.table_error_mm)
    return np.where(lit, error, 0.0)

EFFECT = Effect(
    "log_amplitude_error",
    ("tof",),
    Params,
    "Lindner et al. 2010; Kahlmann et al. 2006; Lindner & Kolb 2007",
    observed=Observed("log_light_polynomial", fitted=("per_decade_mm", "per_decade_squared_mm")),
    order=51,
    on_range=lambda values, p, at: values + error_mm(at.light, at.sensor.a_ref, p),
)
