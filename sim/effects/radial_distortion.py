"""radial_distortion: Brown radial lens distortion (Thesis 2024, eq. 5-5, ISO 17850).

A point whose undistorted image lies at r_u pixels from the principal point
appears at r_d = r_u (1 + k1 (r_u / R)^2), R = half the image diagonal in
pixels; k1 < 0 is barrel, k1 > 0 pincushion distortion. It moves features in
the intensity image; with ``cloud = true`` the camera does not correct it in
the point cloud either (x, y are computed from the distorted pixel position),
with ``cloud = false`` the point cloud is corrected.

Barrel distortion is bounded by the image corner: r_d(r_u) rises only up to
r_u = R / sqrt(-3 k1), where it reaches r_d = (2/3) R / sqrt(-3 k1), so the
corner (r_d = R) still sees a ray only while k1 >= -4/27 = -0.148; beyond,
the outer pixels would see no scene at all (a fold-over no lens has).
``K1_MIN`` stays a little inside, where the corner's magnification
dr_u / dr_d is still finite (about 6).
"""

from __future__ import annotations

from pydantic import Field

from sim.effects.base import Corners, Effect, EffectParams, Observed, valid_range

K1_MIN = -0.145  # inside -4/27, the fold at the image corner (module docstring)


class Params(EffectParams):
    k1: float = Field(0.0, ge=K1_MIN, le=0.5, description="relative radial coefficient at the image corner")
    cloud: bool = Field(True, description="the point cloud carries the distortion too")


EFFECT = Effect(
    "radial_distortion",
    ("tof", "stereo"),
    Params,
    "Brown 1966; Jaehne 2012 p. 97 (Thesis 2024, eq. 5-5); ISO 17850:2015",
    observed=Observed("resimulated", fitted=("k1",), fixed={"cloud": True}, probe=0.02,
                      corners=Corners(("k1",), valid_range(Params, "k1")[:1], valid_range(Params, "k1")[1:],
                                      start=lambda _: (0.0,), params=lambda x: {"k1": float(x[0])},
                                      variants=({"cloud": True}, {"cloud": False})),
                      procedure="checkerboard"),
    lens_distortion=lambda p: (p.k1, p.cloud),
)
