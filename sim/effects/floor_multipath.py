"""floor_multipath: a second surface of known geometry (floor, ceiling or side wall) adds a bounce (CW-ToF).

A plane parallel to the optical axis at ``distance_mm`` from it (below it for
``floor``, above for ``ceiling``, left or right for the walls) reflects part
of the emitted light onto the target point P a pixel sees. Mirror-image
model (single specular bounce): the light path camera -> plane -> P has the
length R' = |C' P|, C' the camera mirrored in the plane, and returns along
P -> camera like the direct light, so the pixel's correlation phasor is

    A e^{j k r} + A q e^{j k (r + R') / 2},   q = reflectance (r / R')^3,

with r = |C P| the direct range and k = 4 pi f_mod / c (phase per mm of range).
The target is taken as facing the camera (normal along the optical axis, as
walls and charts of a depth sweep are): its irradiance goes as
cos(incidence) / distance^2, z / r^3 directly and reflectance z / R'^3 via the
plane, hence q. The measured range is the phase of the sum:

    r_meas = r + arg(1 + q e^{j k (R' - r) / 2}) / k,

independent of the target's own reflectance; it varies with the pixel (the
height of P above the plane) and the distance. Points beyond the plane (on the
far side from the camera) get no bounce. The few % change of the amplitude
(|1 + q e^{j k (R' - r) / 2}|) is not modelled. Source: Fuchs 2010 and
Jimenez et al. 2014 (multipath interference as a phasor sum of returns);
Freedman et al. 2014 (SRA: sparse two-return model); the mirror-image
construction of a planar specular bounce.
"""

from __future__ import annotations

from typing import Literal

import numpy as np
from pydantic import Field

from sim.effects.base import Effect, EffectParams, Observed, RangeStage

#: camera-frame axis (0 = x to the right, 1 = y down) and side of each plane
PLANES = {"floor": (1, 1.0), "ceiling": (1, -1.0), "left": (0, -1.0), "right": (0, 1.0)}


class Params(EffectParams):
    plane: Literal["floor", "ceiling", "left", "right"] = "floor"
    distance_mm: float = Field(300.0, gt=0.0, le=10000.0, description="plane's distance from the optical axis, mm")
    reflectance: float = Field(0.3, ge=0.0, le=1.0, description="specular reflectance of the plane")


def bounce(x: np.ndarray, y: np.ndarray, z: np.ndarray, plane: str,
           distance_mm: float) -> tuple[np.ndarray, np.ndarray]:
    """(q / reflectance, half the extra path (R' - r) / 2 in mm) of points (x, y, z) in the camera frame.

    Both are 0 where the point lies beyond the plane.
    """
    axis, side = PLANES[plane]
    coord = (x, y)[axis]
    r = np.sqrt(x * x + y * y + z * z)
    mirrored = 2.0 * side * distance_mm - coord  # the coordinate of P seen from the mirrored camera
    other = y if axis == 0 else x
    r_mirror = np.sqrt(mirrored * mirrored + other * other + z * z)
    before = side * coord < distance_mm
    with np.errstate(invalid="ignore", divide="ignore"):
        ratio = np.where(before, (r / r_mirror) ** 3, 0.0)
    return ratio, np.where(before, (r_mirror - r) / 2.0, 0.0)


def error_mm(x: np.ndarray, y: np.ndarray, z: np.ndarray, wavenumber: float, p: Params) -> np.ndarray:
    """Range error of the points (x, y, z) (camera frame, mm); ``wavenumber`` = 4 pi f_mod / c per mm."""
    ratio, half_extra = bounce(x, y, z, p.plane, p.distance_mm)
    return np.angle(1.0 + p.reflectance * ratio * np.exp(1j * wavenumber * half_extra)) / wavenumber


def acting_on_range(range_mm: np.ndarray, p: Params, at: RangeStage) -> np.ndarray:
    """``range_mm`` plus the bounce's error at the points it puts along the sensor's true rays."""
    optics, wavenumber = at.sensor.geometry.optics, at.sensor.wavenumber
    x, y, z = optics.directions(*optics.pixel_grid()) * range_mm
    return range_mm + error_mm(x, y, z, wavenumber, p)


EFFECT = Effect(
    "floor_multipath",
    ("tof",),
    Params,
    "Fuchs 2010; Jimenez et al. 2014; Freedman et al. 2014 (mirror-image single bounce)",
    observed=Observed("plane_bounce", fitted=("plane", "distance_mm", "reflectance"),
                      solver_bounds={"distance_mm": (1.0, 10000.0)}, formula=bounce),
    order=10,
    on_range=acting_on_range,
)
