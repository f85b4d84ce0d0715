"""target_misalignment: the target plate stands ``offset_mm`` behind the robot circle's centre.

The centre pixel then measures R + delta / cos(theta) at robot angle theta
(Thesis 2024, 5.4.2, Fig. 5-15 a): 95 mm more at 80 deg than at 0 deg for 20 mm.
"""

from __future__ import annotations

from pydantic import Field

from sim.effects.base import Effect, EffectParams, Observed


class Params(EffectParams):
    offset_mm: float = Field(20.0, ge=-200.0, le=200.0, description="target plane behind the circle centre, mm")


EFFECT = Effect(
    "target_misalignment",
    ("tof", "stereo"),
    Params,
    "Thesis 2024, 5.4.2, Fig. 5-15 (a)",
    observed=Observed("resimulated", fitted=("offset_mm",), steps="robot_plates", min_steps=3, probe=10.0,
                      procedure="remission_angle"),
    plate_offset_mm=lambda p: p.offset_mm,
)
