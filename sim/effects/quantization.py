"""quantization: coordinates stored in steps of ``step_mm`` (e.g. integer millimetres).

x, y, z are rounded to the nearest multiple of the step. Source: the
AM-T100 stores integer mm (Thesis 2024, Table 6-1); RealSense z16 depth in 1 mm units.
"""

from __future__ import annotations

from pydantic import Field

from sim.effects.base import Effect, EffectParams, Observed


class Params(EffectParams):
    step_mm: float = Field(1.0, gt=0.0, le=50.0, description="quantization step, mm")


EFFECT = Effect(
    "quantization",
    ("tof", "stereo"),
    Params,
    "Thesis 2024, Table 6-1 (AM-T100 integer mm); librealsense z16 depth units",
    observed=Observed(why_not="does not move the mean of a noisy stack"),
    step_mm=lambda p: p.step_mm,
    built_in=lambda profile: {"step_mm": profile.output_step_mm} if profile.output_step_mm > 0 else None,
)
