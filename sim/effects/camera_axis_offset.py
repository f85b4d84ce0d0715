"""camera_axis_offset: the camera's optical axis passes the robot axis ``offset_mm`` to the side.

The centre pixel then measures R - e tan(theta) at robot angle theta (sign by
side; Thesis 2024, 5.4.2, Fig. 5-15 b): 113 mm less at 80 deg for 20 mm.
"""

from __future__ import annotations

from pydantic import Field

from sim.effects.base import Effect, EffectParams, Observed


class Params(EffectParams):
    offset_mm: float = Field(20.0, ge=-200.0, le=200.0, description="optical axis beside the robot axis, mm")


EFFECT = Effect(
    "camera_axis_offset",
    ("tof", "stereo"),
    Params,
    "Thesis 2024, 5.4.2, Fig. 5-15 (b)",
    observed=Observed("resimulated", fitted=("offset_mm",), steps="robot_plates", min_steps=3, probe=10.0,
                      procedure="remission_angle"),
    axis_offset_mm=lambda p: p.offset_mm,
)
