"""material_bias: sub-surface scattering lengthens the measured range.

Light entering translucent materials (PTFE, skin, gelatine, silicone) leaves
them displaced and late, so a ToF camera measures r + scale * b(material),
b from the material table (sim/materials.py). Source: the material table's
references; Thesis 2024, 5.4 / 6.5.
"""

from __future__ import annotations

from pydantic import Field

from sim.effects.base import Effect, EffectParams, Observed


class Params(EffectParams):
    scale: float = Field(1.0, ge=0.0, le=10.0, description="multiplies every material's sub-surface bias")


EFFECT = Effect(
    "material_bias",
    ("tof",),
    Params,
    "sim/materials.py references; Thesis 2024, 6.5",
    observed=Observed("resimulated", fitted=("scale",), steps="translucent", procedure="remission_angle"),
    subsurface_scale=lambda p: p.scale,
)
