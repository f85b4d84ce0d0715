"""range_offset: a constant range error, r' = r + offset_mm.

Source: every ToF camera calibration models a constant distance offset
(Lindner & Kolb 2006; Thesis 2024, 4.1.2 measures it as the camera-laser offset).
"""

from __future__ import annotations

import numpy as np
from pydantic import Field

from sim.effects.base import EffectParams

NAME = "range_offset"
TECHNOLOGIES = ("tof", "stereo")
SOURCE = "Lindner & Kolb 2006, ToF distance calibration; Thesis 2024, 4.1.2"


class Params(EffectParams):
    offset_mm: float = Field(0.0, ge=-200.0, le=200.0, description="added to every range, mm")


def apply(range_mm: np.ndarray, p: Params) -> np.ndarray:
    return range_mm + p.offset_mm
