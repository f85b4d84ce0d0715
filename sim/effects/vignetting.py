"""vignetting: light falls off towards the image corners, A' = A cos(alpha)^exponent.

alpha is the angle between a pixel's ray and the optical axis; exponent 4 is
the natural cos^4 law of a lens (relative illumination), larger values add the
falloff of the illumination beam. Source: Hecht 2017 (cos^4 law); Thesis 2024, 5.1.2
("corner pixels are usually illuminated less than those in the center").
"""

from __future__ import annotations

import numpy as np
from pydantic import Field

from sim.effects.base import Effect, EffectParams, Observed


class Params(EffectParams):
    exponent: float = Field(4.0, ge=0.0, le=20.0, description="power of cos(alpha)")


def factor(cos_alpha: np.ndarray, p: Params) -> np.ndarray:
    return np.power(cos_alpha, p.exponent)


EFFECT = Effect(
    "vignetting",
    ("tof", "stereo"),
    Params,
    "Hecht 2017 (cos^4 law); Thesis 2024, 5.1.2",
    observed=Observed("log_cos_alpha", fitted=("exponent",)),
    shading=factor,
)
