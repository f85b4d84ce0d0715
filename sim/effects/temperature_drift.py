"""temperature_drift: warm-up drift of the range, Delta r(t) = delta_mm exp(-t / tau_s).

t is the device time of the frame (seconds since the camera started). A
camera reaches its steady state after a few tau; the steady offset itself is
``range_offset``. Source: DESIGN "Simulation physics"; self-heating is a
known ToF error (thesis Table 3-2; Chiabrando et al. 2009).
"""

from __future__ import annotations

import math

from pydantic import Field

from sim.effects.base import EffectParams

NAME = "temperature_drift"
TECHNOLOGIES = ("tof", "stereo")
SOURCE = "Chiabrando et al. 2009; thesis Table 3-2 (self-heating)"


class Params(EffectParams):
    delta_mm: float = Field(5.0, ge=-100.0, le=100.0, description="range error at t = 0, mm")
    tau_s: float = Field(600.0, gt=0.0, le=86400.0, description="time constant, s")


def offset_mm(t_s: float, p: Params) -> float:
    """Range error of a frame taken ``t_s`` seconds after start."""
    return p.delta_mm * math.exp(-max(t_s, 0.0) / p.tau_s)
