"""multipath: single-bounce interreflection adds a delayed return to every pixel.

P' = P + strength * mean_scene(P) * exp(j 4 pi f extra_path_mm / c): a fraction
of the light returned by the whole scene reaches each pixel again after an
extra path. The phase of the sum shifts the range, most where the pixel's own
return is weak. Source: Fuchs 2010 (multipath interference in ToF), reduced to a
single bounce.
"""

from __future__ import annotations

from pydantic import Field

from sim.effects.base import EffectParams

NAME = "multipath"
TECHNOLOGIES = ("tof",)
SOURCE = "Fuchs 2010; Jimenez et al. 2014"


class Params(EffectParams):
    strength: float = Field(0.05, ge=0.0, le=1.0, description="indirect / mean direct light")
    extra_path_mm: float = Field(500.0, gt=0.0, le=10000.0, description="extra path of the indirect light, mm")
