"""defocus: thin-lens blur of a lens focused at infinity (Thesis 2024, 2.2, eq. 2-5, Fig. 2-5).

For a lens focused at infinity the circle of confusion of an object at
distance s is c(s) = f^2 / (F s), so with the hyperfocal distance H (where c
equals the acceptable circle c_H) the blur disc diameter in pixels is

    b(s) = coc_px * H / s.

The blur is a uniform disc (pillbox) convolved with the lens's in-focus PSF;
it acts on the light, i.e. on the intensity image and on the ToF phasor (so
depth edges blur too when ``flying_pixels`` is on). ``coc_px`` is the blur at
H; by default it is the disc that costs 10 % of the SFR area (the same
criterion labctl uses to find the hyperfocal distance, Thesis 2024, 5.1.2), computed for
the profile's lens PSF. s is the depth at the image centre.
"""

from __future__ import annotations

from pydantic import Field

from sim.effects.base import Effect, EffectParams, Observed


class Params(EffectParams):
    hyperfocal_mm: float = Field(ge=10.0, le=20000.0, description="hyperfocal distance, mm")
    coc_px: float | None = Field(None, gt=0.0, le=20.0, description="blur disc diameter at H, px")


def blur_diameter_px(distance_mm: float, p: Params, default_coc_px: float) -> float:
    """Disc diameter (pixels) at ``distance_mm``; ``default_coc_px`` stands for an unset ``coc_px``."""
    return (p.coc_px or default_coc_px) * p.hyperfocal_mm / max(distance_mm, 1.0)


EFFECT = Effect(
    "defocus",
    ("tof", "stereo"),
    Params,
    "Thesis 2024, 2.2, eq. 2-5 (Lange 2023); Hecht 2017",
    observed=Observed(why_not="acts at edges, which the comparison leaves out (see the slanted-edge evaluation)"),
    built_in=lambda profile: {"hyperfocal_mm": profile.hyperfocal_mm},
    blur_px=blur_diameter_px,
)
