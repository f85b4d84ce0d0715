"""wiggling: systematic range error periodic in distance (CW-ToF).

Delta r = a sin(2 pi r / P + phi) + sum_k a_k sin(2 pi r / P_k + phi_k).

With 4-tap sampling, the harmonics of a non-sinusoidal modulation alias to
a period of c / (8 f_mod): 375 mm at 100 MHz, 2.5 m at 15 MHz. Source: Lindner
& Kolb 2006; Giancola et al. 2018; Thesis 2024, 4.2.2 (the circular patterns of Fig. 4-4).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np
from pydantic import Field

from sim.effects.base import Effect, EffectParams, Observed, RunHoldings


class Harmonic(EffectParams):
    amplitude_mm: float = Field(ge=0.0, le=100.0)
    period_mm: float = Field(gt=10.0, le=20000.0)
    phase_rad: float = Field(0.0, ge=-2 * math.pi, le=2 * math.pi)


class Params(EffectParams):
    amplitude_mm: float = Field(4.0, ge=0.0, le=100.0, description="mm")
    period_mm: float = Field(1500.0, gt=10.0, le=20000.0, description="mm of range per cycle")
    phase_rad: float = Field(0.0, ge=-2 * math.pi, le=2 * math.pi)
    harmonics: list[Harmonic] = Field(default_factory=list, description="further terms")


def error_mm(range_mm: np.ndarray, p: Params) -> np.ndarray:
    """The range error at ``range_mm``."""
    terms = [(p.amplitude_mm, p.period_mm, p.phase_rad)]
    terms += [(h.amplitude_mm, h.period_mm, h.phase_rad) for h in p.harmonics]
    return sum(a * np.sin(2 * math.pi * range_mm / period + phase) for a, period, phase in terms)


def apply(range_mm: np.ndarray, p: Params) -> np.ndarray:
    return range_mm + error_mm(range_mm, p)


def capture(params: Mapping[str, Any], _: RunHoldings) -> str:
    """The depth sweep that determines the wiggling's period."""
    period = float(params.get("period_mm", 1000.0))
    return f"a depth sweep with steps below a quarter of the period ({period / 4:.0f} mm) over at least two periods"


EFFECT = Effect(
    "wiggling",
    ("tof",),
    Params,
    "Lindner & Kolb 2006; Giancola et al. 2018; Thesis 2024, 4.2.2",
    observed=Observed("periodic_range", fitted=("amplitude_mm", "period_mm", "phase_rad"),
                      solver_bounds={"phase_rad": (-4 * math.pi, 4 * math.pi)}, procedure="depth_sweep",
                      capture=capture),
    order=20,
    on_range=lambda values, p, _: apply(values, p),
    periodic_range=True,
)
