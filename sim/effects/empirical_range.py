"""empirical_range: a smooth range correction over distance fitted by ``labctl reconcile``, not a physical law.

Delta r(r) = piecewise-linear interpolation of ``correction_mm`` at the knots
``range_mm`` (held constant beyond the first and last knot). ToF: added to
the range along the ray; stereo: to z. It is what reconcile adds to a model
when a residual follows the distance but no library effect explains it
(docs/reconcile.md): it closes the gap without claiming a cause.
"""

from __future__ import annotations

import numpy as np
from pydantic import Field, model_validator

from sim.effects.base import Effect, EffectParams


class Params(EffectParams):
    range_mm: list[float] = Field(default_factory=lambda: [0.0, 10000.0], description="knots, increasing, mm")
    correction_mm: list[float] = Field(default_factory=lambda: [0.0, 0.0], description="correction at each knot, mm")

    @model_validator(mode="after")
    def _table(self) -> Params:
        if len(self.range_mm) < 2 or len(self.range_mm) != len(self.correction_mm):
            raise ValueError("range_mm and correction_mm need the same length, at least 2")
        if np.any(np.diff(self.range_mm) <= 0):
            raise ValueError("range_mm must increase")
        if not np.all(np.isfinite(self.correction_mm)) or np.max(np.abs(self.correction_mm)) > 1000.0:
            raise ValueError("correction_mm must be finite and within +-1000 mm")
        return self


def apply(range_mm: np.ndarray, p: Params) -> np.ndarray:
    return range_mm + np.interp(range_mm, p.range_mm, p.correction_mm)


EFFECT = Effect(
    "empirical_range",
    ("tof", "stereo"),
    Params,
    "fitted by labctl reconcile (empirical, no physical source)",
    order=90,
    on_range=lambda values, p, _: apply(values, p),
)
