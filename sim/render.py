"""Rendering a scene into per-pixel light quantities, with supersampling at edges.

Every pixel's centre ray is cast first. Pixels whose centre hit differs from a
neighbour's (another surface, or another reflectance) are edge pixels: they are
re-cast with ``supersample`` x ``supersample`` sub-pixel rays, so that a pixel
straddling an edge integrates both sides over its 100 % fill-factor area.

Per pixel the renderer returns, averaged over its samples i:

* ``irradiance`` = mean(rho_i cos_i^m / (r_i / 1 m)^2) — light of the camera's
  own source returned to the pixel (A ~ rho cos theta / r^2), m the material's
  Lambertian exponent;
* ``phasor`` = mean(irradiance_i exp(j 4 pi f (r_i + b_i) / c)) — the CW-ToF
  correlation phasor (b_i: the material's sub-surface bias when that effect is on);
* ``range_dom``, ``z_dom``, ``cos_dom`` — range, camera-frame depth and
  incidence cosine of the dominant surface (the one returning most light into
  the pixel);
* ``passive`` = mean(rho_i cos_i^m) — reflectance seen under ambient light.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from sim.aggregate import aggregate
from sim.geometry import Pose
from sim.optics import CameraOptics
from sim.scenes.base import Hit, Scene

C_MM_PER_S = 299_792_458_000.0


@dataclass
class Rendered:
    irradiance: np.ndarray
    phasor: np.ndarray | None
    range_dom: np.ndarray
    z_dom: np.ndarray
    cos_dom: np.ndarray
    surface_dom: np.ndarray
    passive: np.ndarray
    hit_fraction: np.ndarray
    edge: np.ndarray


@dataclass(frozen=True)
class SurfaceProperties:
    """Per-surface material properties used when aggregating samples (indexed by surface id)."""

    bias_mm: np.ndarray
    lambert: np.ndarray


def _aggregate(hit: Hit, z_cam: np.ndarray, props: SurfaceProperties, wavenumber: float | None,
               n_surfaces: int) -> dict[str, np.ndarray]:
    """Aggregate samples along the last axis into per-pixel quantities (sim/aggregate.py)."""
    shape = hit.t.shape[:-1]
    s = hit.t.shape[-1]

    def rows(a: np.ndarray, dtype: type = float) -> np.ndarray:
        return np.ascontiguousarray(a.reshape(-1, s), dtype=dtype)

    n = int(np.prod(shape))
    out = {name: np.empty(n) for name in ("irradiance", "passive", "hit_fraction", "range_dom", "z_dom", "cos_dom")}
    out["phasor"] = np.empty(n, dtype=complex)
    out["surface_dom"] = np.empty(n, dtype=np.int64)
    aggregate(rows(hit.t), rows(hit.cos), rows(hit.reflectance), rows(hit.surface, np.int64), rows(z_cam),
              np.asarray(props.bias_mm, float), np.asarray(props.lambert, float), wavenumber or 0.0, n_surfaces,
              out["irradiance"], out["passive"], out["hit_fraction"], out["phasor"], out["range_dom"],
              out["z_dom"], out["cos_dom"], out["surface_dom"])
    if wavenumber is None:
        del out["phasor"]
    return {name: values.reshape(shape) for name, values in out.items()}


def _edges(hit: Hit) -> np.ndarray:
    """Pixels whose centre sample differs from a 4-neighbour's (surface or reflectance).

    An edge crossing a pixel's footprint separates its centre from the centre
    of the neighbour beyond it, so both are marked; no dilation is needed.
    """
    s, r = hit.surface, hit.reflectance
    edge = np.zeros(s.shape, dtype=bool)
    for axis in (0, 1):
        ds = np.diff(s, axis=axis) != 0
        dr = np.abs(np.diff(r, axis=axis)) > 0.02 * np.maximum(np.abs(r).max(), 1e-9)
        d = ds | dr
        lo = [slice(None)] * 2
        hi = [slice(None)] * 2
        lo[axis], hi[axis] = slice(0, -1), slice(1, None)
        edge[tuple(lo)] |= d
        edge[tuple(hi)] |= d
    return edge


def render(scene: Scene, pose: Pose, optics: CameraOptics, props: SurfaceProperties,
           modulation_mhz: float | None = None, supersample: int = 4) -> Rendered:
    """Per-pixel light quantities of ``scene`` seen by a camera at ``pose`` through ``optics``."""
    wavenumber = 4 * math.pi * modulation_mhz * 1e6 / C_MM_PER_S if modulation_mhz else None
    n_surf = max(len(scene.surfaces), 1)
    u, v = optics.pixel_grid()
    d_cam = optics.directions(u, v)
    origin, d_world = pose.rays(d_cam)
    centre = scene.cast(origin, d_world)
    centre_z = np.where(np.isfinite(centre.t), centre.t * d_cam[2], 0.0)
    expand = lambda a: a[..., None]  # noqa: E731 - a sample axis of length 1
    maps = _aggregate(Hit(*(expand(getattr(centre, f)) for f in ("t", "cos", "reflectance", "surface"))),
                      expand(centre_z), props, wavenumber, n_surf)
    edge = _edges(centre) if supersample > 1 else np.zeros(u.shape, dtype=bool)
    if edge.any():
        offsets = (np.arange(supersample) + 0.5) / supersample - 0.5
        du, dv = np.meshgrid(offsets, offsets)
        eu = u[edge][:, None] + du.ravel()[None, :]
        ev = v[edge][:, None] + dv.ravel()[None, :]
        sub_d = optics.directions(eu, ev)
        sub_o, sub_w = pose.rays(sub_d)
        sub = scene.cast(sub_o, sub_w)
        sub_z = np.where(np.isfinite(sub.t), sub.t * sub_d[2], 0.0)
        fine = _aggregate(sub, sub_z, props, wavenumber, n_surf)
        for key, values in fine.items():
            maps[key][edge] = values
    return Rendered(
        irradiance=maps["irradiance"],
        phasor=maps.get("phasor"),
        range_dom=maps["range_dom"],
        z_dom=maps["z_dom"],
        cos_dom=maps["cos_dom"],
        surface_dom=maps["surface_dom"],
        passive=maps["passive"],
        hit_fraction=maps["hit_fraction"],
        edge=edge,
    )


def centre_distance_mm(rendered: Rendered) -> float:
    """Median range of the central 5 x 5 pixels: what the lens is looking at (for defocus)."""
    h, w = rendered.range_dom.shape
    centre = rendered.range_dom[h // 2 - 2 : h // 2 + 3, w // 2 - 2 : w // 2 + 3]
    finite = centre[np.isfinite(centre)]
    return float(np.median(finite)) if finite.size else 1e9
