"""multipath: single-bounce interreflection adds a delayed return to every pixel.

P' = P + strength * mean_scene(P) * exp(j 4 pi f extra_path_mm / c): a fraction
of the light returned by the whole scene reaches each pixel again after an
extra path. The phase of the sum shifts the range, most where the pixel's own
return is weak. mean_scene is the mean over the image of every return, each
surface at its own range (the blurred phasor of all sub-pixel returns), not of
each pixel's dominant surface alone: a pixel on a plate's outline returns light
from the plate and from the wall behind it, and both reach the others again.
Source: Fuchs 2010 (multipath interference in ToF), reduced to a single bounce.
"""

from __future__ import annotations

import numpy as np
from pydantic import Field

from sim.effects.base import Effect, EffectParams, Observed, PhasorStage


class Params(EffectParams):
    strength: float = Field(0.05, ge=0.0, le=1.0, description="indirect / mean direct light")
    extra_path_mm: float = Field(500.0, gt=0.0, le=10000.0, description="extra path of the indirect light, mm")


def add_return(phasor: np.ndarray, p: Params, stage: PhasorStage) -> np.ndarray:
    """The pixel phasors plus the indirect return: ``strength`` x the scene's mean return (``stage.scene_mean``),
    delayed by ``extra_path_mm`` (``stage.sensor.wavenumber`` = 4 pi f_mod / c per mm)."""
    return phasor + p.strength * stage.scene_mean * np.exp(1j * stage.sensor.wavenumber * p.extra_path_mm)


EFFECT = Effect(
    "multipath",
    ("tof",),
    Params,
    "Fuchs 2010; Jimenez et al. 2014",
    observed=Observed("mean_phasor", fitted=("strength", "extra_path_mm"), solver_bounds={"extra_path_mm": (1.0, 10000.0)},
                      procedure="depth_sweep",
                      capture=lambda _, __: "the same scene at more distances (the extra path's phase turns with the "
                                            "modulation wavelength)"),
    mixes_returns=True,
    phasor=add_return,
)
