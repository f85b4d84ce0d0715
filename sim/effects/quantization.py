"""quantization: coordinates stored in steps of ``step_mm`` (e.g. integer millimetres).

x, y, z are rounded to the nearest multiple of the step. Source: SPEC (the
AM-T100 stores integer mm); RealSense z16 depth in 1 mm units.
"""

from __future__ import annotations

from pydantic import Field

from sim.effects.base import EffectParams

NAME = "quantization"
TECHNOLOGIES = ("tof", "stereo")
SOURCE = "SPEC lab hardware (AM-T100 integer mm); librealsense z16 depth units"


class Params(EffectParams):
    step_mm: float = Field(1.0, gt=0.0, le=50.0, description="quantization step, mm")
