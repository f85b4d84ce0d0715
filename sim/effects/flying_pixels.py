"""flying_pixels: a pixel's depth comes from all the light it receives, mixed.

A CW-ToF pixel correlates the sum of every return reaching it; where a pixel
(or the optical blur around it) straddles a depth edge, the phasors of both
surfaces add and the measured range lies between them ("flying pixels").
With the effect on, depth is the phase of the pixel's summed phasor over its
sub-samples and the optical PSF; off, depth is the dominant surface's own
range. Source: Lindner & Kolb 2006; Giancola et al. 2018 (mixed pixels).
"""

from __future__ import annotations

from sim.effects.base import Effect, EffectParams, Observed


class Params(EffectParams):
    pass


EFFECT = Effect(
    "flying_pixels",
    ("tof",),
    Params,
    "Giancola et al. 2018 (mixed pixels); Lindner & Kolb 2006",
    observed=Observed(why_not="acts at depth edges, which the comparison leaves out"),
    mixes_returns=True,
    mixed_pixels=True,
)
