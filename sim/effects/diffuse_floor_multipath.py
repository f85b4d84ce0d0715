"""diffuse_floor_multipath: a matte second surface (floor, ceiling or side wall) adds a diffuse bounce (CW-ToF).

A plane parallel to the optical axis at ``distance_mm`` D from it (the planes
of ``floor_multipath``) is a Lambertian reflector of ``albedo`` rho. The
camera's emitter (taken as uniform over the camera's field of view) lights
the part of the plane inside its cone; every lit patch F re-emits with radiance
rho E_F / pi towards the target point P a pixel sees, and that light returns
along P -> camera like the direct light. With the target facing the camera
(normal along the optical axis) and h = D - (P's coordinate towards the plane)
the height of P above the plane, the pixel's phasor is the direct one times

    1 + m,   m = rho / pi  r^3 / z  Int  D h (z - w) / (|CF|^3 |FP|^4)
                 exp(j k (|CF| + |FP| - r) / 2) dA,

integrated over the lit patches F (depth w < z, inside the emitter's cone),
with r = |CP|, k = 4 pi f_mod / c: D / |CF|^3 is the emitter's irradiance of
the patch (per unit of the emitter's intensity), h / |FP| and (z - w) / |FP|
the cosines at F and at P, and z / r^3 the direct irradiance of P. The
measured range is r + arg(1 + m) / k; points beyond the plane get no bounce.
The integral is a product Gauss-Legendre rule (``NODES`` x 2 ``NODES`` / 2
nodes) in coordinates that crowd the nodes towards P's foot on the plane,
where the kernel peaks. Source: Fuchs 2010 and Jimenez et al. 2014 (diffuse
multipath as the sum over Lambertian scene patches of the light they
re-emit); the radiometry of a Lambertian reflector (radiance rho E / pi).
"""

from __future__ import annotations

import functools
import math
from typing import Any, Literal

import numpy as np
from numba import njit, prange
from pydantic import Field

from sim.effects.base import Effect, EffectParams, Observed, RangeStage
from sim.effects.floor_multipath import PLANES

NODES = 16  # Gauss-Legendre nodes across the depth of the lit patches (and as many across their width)


@functools.cache
def _rule(nodes: int) -> tuple[np.ndarray, np.ndarray]:
    """Gauss-Legendre nodes and weights on [0, 1]."""
    s, w = np.polynomial.legendre.leggauss(nodes)
    return (s + 1.0) / 2.0, w / 2.0


class Params(EffectParams):
    plane: Literal["floor", "ceiling", "left", "right"] = "floor"
    distance_mm: float = Field(300.0, gt=0.0, le=10000.0, description="plane's distance from the optical axis, mm")
    albedo: float = Field(0.3, ge=0.0, le=1.0, description="Lambertian albedo of the plane")


def bounce_phasor(x: np.ndarray, y: np.ndarray, z: np.ndarray, plane: str, distance_mm: float,
                  sensor: Any, nodes: int = NODES, imag_only: bool = False) -> np.ndarray:
    """m / rho of the points (x, y, z) (camera frame, mm): the diffuse bounce's phasor relative to the direct
    light per unit albedo (0 where the point lies beyond the plane or before its lit part). ``sensor`` gives
    the field of view (``profile``) and the phase per mm of range (``wavenumber``); ``nodes`` the rule's size
    across the depth of the lit patches (a smaller rule is faster and less exact close to the plane).
    ``imag_only``: the imaginary part alone, bit for bit the same, the real part left 0, at about two thirds of
    the cost (the depth signature of reconcile's candidate needs only Im(m))."""
    axis, side = PLANES[plane]
    p = sensor.profile
    across, lateral = (p.fov_h_deg, p.fov_v_deg) if axis == 0 else (p.fov_v_deg, p.fov_h_deg)
    d = float(distance_mm)
    w0 = d / math.tan(math.radians(across) / 2)  # the depth where the emitter's cone reaches the plane
    tan_lateral = math.tan(math.radians(lateral) / 2)
    x, y, z = (np.nan_to_num(np.asarray(v, float)) for v in (x, y, z))
    shape = np.broadcast_shapes(x.shape, y.shape, z.shape)
    x, y, z = (np.ascontiguousarray(np.broadcast_to(v, shape)).ravel() for v in (x, y, z))
    h = d - side * (x, y)[axis]
    b = y if axis == 0 else x
    total = _bounce(h, b, x * x + y * y + z * z, z, d, w0, tan_lateral, sensor.wavenumber, *_rule(nodes),
                    *_rule(nodes // 2), imag_only)
    return total.reshape(shape)


@njit(parallel=True, cache=True, nogil=True)
def _bounce(h: np.ndarray, b: np.ndarray, r2: np.ndarray, z: np.ndarray, d: float, w0: float, tan_lateral: float,
            k: float, s_nodes: np.ndarray, s_weights: np.ndarray, t_nodes: np.ndarray, t_weights: np.ndarray,
            imag_only: bool) -> np.ndarray:  # pragma: no cover (compiled)
    """m / rho per point: the product rule of the module docstring, point by point (compiled: the grid search
    of the reconcile candidate evaluates it for every bin of every step at every trial plane; each point on its
    own, so the same on any number of threads). ``imag_only``: the sines alone, summed in the same order (the
    imaginary part of a sum of kernel x (cos + j sin) is the sum of kernel x sin), the real part left 0."""
    out = np.zeros(z.size, np.complex128)
    for i in prange(z.size):
        if not (h[i] > 0.0 and z[i] > w0):
            continue
        r = math.sqrt(r2[i])
        depth = z[i] - w0
        total = 0j
        total_imag = 0.0
        for s, ws in zip(s_nodes, s_weights):
            gap = depth * s * s  # z - w, crowded towards P's foot
            w = z[i] - gap
            half = w * tan_lateral
            c = min(max(b[i], -half), half)
            for sign, length in ((-1.0, c + half), (1.0, half - c)):
                for t, wt in zip(t_nodes, t_weights):
                    beta = c + sign * length * t * t
                    cf = math.sqrt(d * d + beta * beta + w * w)
                    fp2 = h[i] * h[i] + (beta - b[i]) ** 2 + gap * gap
                    phase = 0.5 * k * (cf + math.sqrt(fp2) - r)
                    kernel = d * h[i] * gap / (cf**3 * fp2 * fp2) * (ws * 2.0 * depth * s) * (wt * 2.0 * length * t)
                    if imag_only:
                        total_imag += kernel * math.sin(phase)
                    else:
                        total += kernel * complex(math.cos(phase), math.sin(phase))
        if imag_only:
            out[i] = complex(0.0, total_imag * r**3 / (math.pi * z[i]))
        else:
            out[i] = total * r**3 / (math.pi * z[i])
    return out


def acting_on_range(range_mm: np.ndarray, p: Params, at: RangeStage) -> np.ndarray:
    """``range_mm`` plus the bounce's error at the points it puts along the sensor's true rays."""
    optics, k = at.sensor.geometry.optics, at.sensor.wavenumber
    x, y, z = optics.directions(*optics.pixel_grid()) * range_mm
    m = p.albedo * bounce_phasor(x, y, z, p.plane, p.distance_mm, at.sensor)
    return range_mm + np.angle(1.0 + m) / k


EFFECT = Effect(
    "diffuse_floor_multipath",
    ("tof",),
    Params,
    "Fuchs 2010; Jimenez et al. 2014 (Lambertian patches' re-emitted light)",
    observed=Observed("plane_phasor", fitted=("plane", "distance_mm", "albedo"),
                      solver_bounds={"distance_mm": (1.0, 10000.0)}, formula=bounce_phasor),
    order=11,
    on_range=acting_on_range,
)
