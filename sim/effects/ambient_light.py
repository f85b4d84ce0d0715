"""ambient_light: background light (sunlight, lamps) that the pixels collect besides the camera's own signal.

``level`` is the background in units of the reference signal, the camera's
own light returned by the 90 % wall at 2 m at the default exposure (ToF: the
amplitude A_ref; stereo: the projector's dot light on that wall). It carries
no range information but its shot noise:

* ToF (Li 2014, eq. 2-9): the background photo-electrons join B,
  sigma_r = k sqrt(2 A + B_ambient) / (c_d A) with
  B_ambient = (ambient_ratio + level) A_ref t_exp / t_default; the amplitude
  scatters by sqrt(B / 2), so more pixels fall below the confidence threshold;
* stereo (Konolige 2010): the background adds a uniform level to the IR image,
  level x the projector's light at 2 m, which lowers the local contrast
  std / mean of the matching window: pixels below ``texture_threshold`` fail,
  and the sub-pixel matching noise grows as the contrast falls,
  sigma_d' = sigma_d (m + b) / m with m the window's mean light without the
  background b.

The mean depth stays where it was; reconcile sees the effect in the noise and
validity families (and, for stereo, in the intensity image).
"""

from __future__ import annotations

from pydantic import Field

from sim.effects.base import Effect, EffectParams, Observed


class Params(EffectParams):
    level: float = Field(0.0, ge=0.0, le=50.0,
                         description="background light in units of the camera's signal from the 90 % wall at 2 m")


EFFECT = Effect(
    "ambient_light",
    ("tof", "stereo"),
    Params,
    "Li 2014 (eq. 2-9, ToF shot noise); Konolige 2010 (stereo matching contrast)",
    observed=Observed("resimulated", fitted=("level",), probe=1.0, solver_bounds={"level": (0.0, 50.0)},
                      families=("intensity", "noise", "validity")),
    background=lambda p: p.level,
)
