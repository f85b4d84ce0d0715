"""Rendering a scene into per-pixel light quantities, with supersampling at edges.

Every pixel is first sampled at the centres of its 2 x 2 sub-pixels. Pixels
holding a sub-pixel whose hit differs from a neighbour's (another surface, or
another reflectance) are edge pixels: they are re-cast with ``supersample`` x ``supersample`` sub-pixel rays, so that a pixel
straddling an edge integrates both sides over its 100 % fill-factor area. The
sub-pixel positions are the canonical multi-jittered pattern (Chiu, Shirley and
Wang 1994): one sample per cell of the s x s grid and, at the same time, s^2
distinct offsets along each axis, so a near-vertical or near-horizontal edge
covers a pixel in steps of 1/s^2, not 1/s (a regular grid's coarse steps put a
staircase into the edge-spread function and lift a slanted edge's SFR near
Nyquist).

Per pixel the renderer returns, averaged over its samples i:

* ``irradiance`` = mean(rho_i cos_i^m / (r_i / 1 m)^2) — light of the camera's
  own source returned to the pixel (A ~ rho cos theta / r^2), m the material's
  Lambertian exponent;
* ``phasor`` = mean(irradiance_i exp(j 4 pi f (r_i + b_i) / c)) — the CW-ToF
  correlation phasor (b_i: the material's sub-surface bias when that effect is on);
* ``range_dom``, ``z_dom``, ``cos_dom`` — range, camera-frame depth and
  incidence cosine of the dominant surface (the one returning most light into
  the pixel), and ``bias_dom``, its material's sub-surface bias, which
  ``range_dom`` includes;
* ``range_plain``, ``z_plain`` — the dominant surface's range and depth as
  plain means over its samples, not weighted by their light (what the mean
  over smaller pixels sampling the same footprint tends to);
* ``passive`` = mean(rho_i cos_i^m) — reflectance seen under ambient light.

The light quantities are also returned per sub-pixel (``*_fine``), for the
lens blur to act before the pixel integrates.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from dataclasses import dataclass

import numpy as np

from sim.aggregate import aggregate, sample_light
from sim.geometry import Pose
from sim.optics import CameraOptics
from sim.scenes.base import Hit, Scene, SphereSurface

C_MM_PER_S = 299_792_458_000.0


@dataclass
class Rendered:
    irradiance: np.ndarray
    phasor: np.ndarray | None
    range_dom: np.ndarray
    z_dom: np.ndarray
    cos_dom: np.ndarray
    surface_dom: np.ndarray
    bias_dom: np.ndarray  # the dominant surface's sub-surface bias (mm, in ``range_dom``; 0 where nothing is hit)
    range_plain: np.ndarray
    z_plain: np.ndarray
    passive: np.ndarray
    hit_fraction: np.ndarray
    edge: np.ndarray
    #: sub-pixels per pixel side of the ``*_fine`` light maps ((H k, W k); their k x k means are the maps above)
    oversample: int
    irradiance_fine: np.ndarray
    passive_fine: np.ndarray
    phasor_fine: np.ndarray | None

    @functools.cached_property
    def centre_distance_mm(self) -> float:
        """Median range of the central 5 x 5 pixels: what the lens is looking at (for defocus). Once per render:
        every prediction of a cached render asks for it."""
        h, w = self.range_dom.shape
        centre = self.range_dom[h // 2 - 2 : h // 2 + 3, w // 2 - 2 : w // 2 + 3]
        finite = centre[np.isfinite(centre)]
        return float(np.median(finite)) if finite.size else 1e9


@dataclass(frozen=True)
class RenderMove:
    """Renders of one scene along a small move of its surfaces, taken linearly between a render at the move's start
    and one further along it: ``at(t)`` is the render a fraction ``t`` of the way (``t`` outside [0, 1]: beyond
    them). Each light and geometric map changes linearly where both renders hold a finite value and is the
    start's elsewhere; what is discrete (the dominant surface, the edges, the sub-pixel count) is the start's.
    For a plane moved along its normal by micrometres the ranges change linearly with the move, the light (1 /
    r^2) and the phase (exp(j k r)) to second order in the move over the range."""

    start: Rendered
    change: dict[str, np.ndarray]

    @classmethod
    def between(cls, start: Rendered, further: Rendered) -> RenderMove:
        change = {}
        for field in dataclasses.fields(start):
            x, y = getattr(start, field.name), getattr(further, field.name)
            if isinstance(x, np.ndarray) and x.dtype.kind in "fc":
                with np.errstate(invalid="ignore"):
                    change[field.name] = np.where(np.isfinite(x) & np.isfinite(y), y - x, 0.0)
        return cls(start, change)

    def at(self, t: float) -> Rendered:
        return dataclasses.replace(self.start, **{k: getattr(self.start, k) + t * d for k, d in self.change.items()})


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
    out = {name: np.empty(n) for name in ("irradiance", "passive", "hit_fraction", "range_dom", "z_dom", "cos_dom",
                                                  "range_plain", "z_plain")}
    out["phasor"] = np.empty(n, dtype=complex)
    out["surface_dom"] = np.empty(n, dtype=np.int64)
    aggregate(rows(hit.t), rows(hit.cos), rows(hit.reflectance), rows(hit.surface, np.int64), rows(z_cam),
              np.asarray(props.bias_mm, float), np.asarray(props.lambert, float), wavenumber or 0.0, n_surfaces,
              out["irradiance"], out["passive"], out["hit_fraction"], out["phasor"], out["range_dom"],
              out["z_dom"], out["cos_dom"], out["surface_dom"], out["range_plain"], out["z_plain"])
    if wavenumber is None:
        del out["phasor"]
    return {name: values.reshape(shape) for name, values in out.items()}


def _sample_light(hit: Hit, props: SurfaceProperties, wavenumber: float | None) -> dict[str, np.ndarray]:
    """Irradiance, shading (``passive``) and phasor of every single sample (sim/aggregate.py)."""
    shape = hit.t.shape
    flat = lambda a, dtype=float: np.ascontiguousarray(a, dtype=dtype).ravel()  # noqa: E731
    out = {"irradiance": np.empty(hit.t.size), "passive": np.empty(hit.t.size), "phasor": np.empty(hit.t.size, complex)}
    sample_light(flat(hit.t), flat(hit.cos), flat(hit.reflectance), flat(hit.surface, np.int64),
                 np.asarray(props.bias_mm, float), np.asarray(props.lambert, float), wavenumber or 0.0,
                 out["irradiance"], out["passive"], out["phasor"])
    if wavenumber is None:
        del out["phasor"]
    return {name: values.reshape(shape) for name, values in out.items()}


def _edges(surface: np.ndarray, reflectance: np.ndarray) -> np.ndarray:
    """Samples whose hit differs from a 4-neighbour's on the sample grid (surface or reflectance).

    An edge crossing a pixel's footprint separates one of its samples from the
    nearest sample beyond the edge, so the pixels holding both are marked; no
    dilation is needed.
    """
    s, r = surface, reflectance
    edge = np.zeros(s.shape, dtype=bool)
    jump = 0.02 * np.maximum(np.abs(r).max(), 1e-9)
    for axis in (0, 1):
        ds = np.diff(s, axis=axis) != 0
        dr = np.abs(np.diff(r, axis=axis)) > jump
        d = ds | dr
        lo = [slice(None)] * 2
        hi = [slice(None)] * 2
        lo[axis], hi[axis] = slice(0, -1), slice(1, None)
        edge[tuple(lo)] |= d
        edge[tuple(hi)] |= d
    return edge


@functools.lru_cache(maxsize=4)
def _ring_directions(optics: CameraOptics, k: int) -> np.ndarray:
    """The rays (3, 2 (W k + 2) + 2 H k) of ``_bordered``'s ring on the border of an image of H x W pixels sampled
    k per pixel side: the top and bottom rows (corners included), then the left and right columns; read-only.
    Pixel (i, j) spans i +- 0.5, and its samples sit at (n + 0.5) / k - 0.5 of the fine index n. They depend on
    the optics alone, as ``sub_pixel_directions``."""
    h, w = optics.pinhole.height * k, optics.pinhole.width * k
    u = np.concatenate([[-0.5], (np.arange(w) + 0.5) / k - 0.5, [w / k - 0.5]])
    v = np.concatenate([[-0.5], (np.arange(h) + 0.5) / k - 0.5, [h / k - 0.5]])
    ring_u = np.concatenate([u, u, np.full(h, u[0]), np.full(h, u[-1])])  # top, bottom, left, right
    ring_v = np.concatenate([np.full(w + 2, v[0]), np.full(w + 2, v[-1]), v[1:-1], v[1:-1]])
    rays = optics.directions(ring_u, ring_v)
    rays.flags.writeable = False
    return rays


def _bordered(scene: Scene, pose: Pose, optics: CameraOptics, k: int, surface: np.ndarray,
              reflectance: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The fine sample grid's ``surface`` and ``reflectance`` (k samples per pixel side) inside a ring of samples
    cast on the image's border: at the border's corners and, along each side, level with every row or column of
    samples (``_ring_directions``)."""
    h, w = surface.shape
    origin, d_world = pose.rays(_ring_directions(optics, k))
    ring = scene.cast(origin, d_world)
    out = []
    for inner, outer in ((surface, ring.surface), (reflectance, ring.reflectance)):
        a = np.empty((h + 2, w + 2), dtype=np.result_type(inner, outer))
        a[1:-1, 1:-1] = inner
        a[0], a[-1] = outer[:w + 2], outer[w + 2:2 * w + 4]
        a[1:-1, 0], a[1:-1, -1] = outer[2 * w + 4:2 * w + 4 + h], outer[2 * w + 4 + h:]
        out.append(a)
    return out[0], out[1]


def _unsampled_spheres(scene: Scene, pose: Pose, optics: CameraOptics, surface: np.ndarray) -> np.ndarray:
    """The pixels (H, W) that hold the centre of a sphere none of the samples (``surface``: each sample's surface
    index, (H, W, k^2)) hit. A sphere narrower than the samples' spacing can fall between them: a ball bar's 50 mm
    sphere 2 m away is 2 px across on a 160 px wide grid sampled every 2 px. The ray through its centre always
    meets it, so the pixel that ray crosses is an edge pixel, which the supersampling resolves."""
    h, w = surface.shape[:2]
    edge = np.zeros((h, w), dtype=bool)
    p = optics.pinhole
    for index, sphere in enumerate(scene.surfaces):
        if not isinstance(sphere, SphereSurface) or (surface == index).any():
            continue
        x, y, z = pose.to_camera(np.asarray(sphere.centre, float))
        if z <= 0:
            continue
        u, v = optics.distort(np.array(p.cx + p.fx * x / z), np.array(p.cy + p.fy * y / z))
        col, row = int(np.round(u)), int(np.round(v))
        if 0 <= row < h and 0 <= col < w:
            edge[row, col] = True
    return edge


def multi_jittered_offsets(s: int) -> tuple[np.ndarray, np.ndarray]:
    """Sub-pixel offsets (px, within +-0.5) of the canonical multi-jittered pattern of s x s samples.

    Sample (i, j) sits in cell (i, j) of the s x s grid at x = (i + (j + 1/2) / s) / s,
    y = (j + (i + 1/2) / s) / s: every x and every y offset is distinct.
    """
    i, j = np.meshgrid(np.arange(s), np.arange(s), indexing="ij")
    du = (i + (j + 0.5) / s) / s - 0.5
    dv = (j + (i + 0.5) / s) / s - 0.5
    return du.ravel(), dv.ravel()


def _to_fine(a: np.ndarray, k: int) -> np.ndarray:
    """(H, W, k*k) samples ordered (row-in-pixel, column-in-pixel) -> (H k, W k) image."""
    h, w = a.shape[:2]
    return a.reshape(h, w, k, k).transpose(0, 2, 1, 3).reshape(h * k, w * k)


def _quadrant_order(s: int, k: int) -> np.ndarray:
    """Indices that sort the s x s multi-jittered samples into the k x k sub-pixels (row-major), s^2/k^2 each."""
    i, j = np.meshgrid(np.arange(s), np.arange(s), indexing="ij")  # i: column cell (u), j: row cell (v)
    quadrant = (j // (s // k)) * k + i // (s // k)
    return np.argsort(quadrant.ravel(), kind="stable")


@functools.lru_cache(maxsize=8)
def _edge_offsets(s: int, k: int) -> tuple[np.ndarray, np.ndarray]:
    """The s x s multi-jittered offsets (u, v) sorted into the k x k sub-pixels (``_quadrant_order``), read-only:
    the same for every edge pixel of every render."""
    du, dv = multi_jittered_offsets(s)
    order = _quadrant_order(s, k)
    du, dv = du[order], dv[order]
    du.flags.writeable = dv.flags.writeable = False
    return du, dv


@functools.lru_cache(maxsize=8)
def _pixel_centres(optics: CameraOptics) -> tuple[np.ndarray, np.ndarray]:
    """``optics.pixel_grid()``, read-only and once per optics (every render of a run's camera)."""
    u, v = optics.pixel_grid()
    u.flags.writeable = v.flags.writeable = False
    return u, v


@functools.lru_cache(maxsize=4)
def sub_pixel_directions(optics: CameraOptics, k: int) -> np.ndarray:
    """The rays (3, H, W, k*k) through the centres of every pixel's k x k sub-pixels (row-major), read-only.

    They depend on the optics alone, so the steps of a run (one camera) compute them once: at 640 x 480 and
    k = 2 they are 1.2 million rays, and the lens distortion is inverted by Newton's method for each.
    """
    u, v = optics.pixel_grid()
    centres = (np.arange(k) + 0.5) / k - 0.5
    dv0, du0 = (a.ravel() for a in np.meshgrid(centres, centres, indexing="ij"))  # row-major sub-pixels
    rays = optics.directions(u[..., None] + du0, v[..., None] + dv0)
    rays.flags.writeable = False
    return rays


#: sub-pixels per pixel side at which every pixel is sampled (``render``)
OVERSAMPLE = 2


def render(scene: Scene, pose: Pose, optics: CameraOptics, props: SurfaceProperties,
           modulation_mhz: float | None = None, supersample: int = 4, oversample: int = OVERSAMPLE,
           border: bool = False) -> Rendered:
    """Per-pixel light quantities of ``scene`` seen by a camera at ``pose`` through ``optics``.

    Every pixel is sampled at the centres of its ``oversample`` x ``oversample``
    sub-pixels; pixels with an edge among those samples or next to them are
    re-cast with the ``supersample`` x ``supersample`` multi-jittered pattern.
    A sphere that falls between the samples is found by the ray through its
    centre (``_unsampled_spheres``). The outer samples lie half a sub-pixel inside the image: with ``border`` an
    edge in that margin is found too, against a ring of samples on the image's
    border (``_bordered``; for a coarse grid whose margin is wide, such as the
    reconcile's bins).
    Besides the per-pixel maps, the light (irradiance, passive, phasor) is
    returned per sub-pixel, so that the lens blur can act before the pixel
    integrates (``SensorOptics.blur``): blurring pixel values instead would
    fold the scene's detail above Nyquist back into the image.
    """
    if supersample > 1 and supersample % oversample:
        raise ValueError(f"supersample {supersample} must be a multiple of oversample {oversample}")
    k = oversample
    wavenumber = 4 * math.pi * modulation_mhz * 1e6 / C_MM_PER_S if modulation_mhz else None
    n_surf = max(len(scene.surfaces), 1)
    u, v = _pixel_centres(optics)
    d_cam = sub_pixel_directions(optics, k)
    origin, d_world = pose.rays(d_cam)
    hit = scene.cast(origin, d_world)
    hit_z = np.where(np.isfinite(hit.t), hit.t * d_cam[2], 0.0)
    maps = _aggregate(hit, hit_z, props, wavenumber, n_surf)
    light = {key: _to_fine(values, k) for key, values in _sample_light(hit, props, wavenumber).items()}
    h, w = u.shape
    if supersample > 1:
        surface, reflectance = _to_fine(hit.surface, k), _to_fine(hit.reflectance, k)
        if border:
            fine = _edges(*_bordered(scene, pose, optics, k, surface, reflectance))[1:-1, 1:-1]
        else:
            fine = _edges(surface, reflectance)
        edge = fine.reshape(h, k, w, k).any(axis=(1, 3)) | _unsampled_spheres(scene, pose, optics, hit.surface)
    else:
        edge = np.zeros(u.shape, dtype=bool)
    if edge.any():
        du, dv = _edge_offsets(supersample, k)
        eu = u[edge][:, None] + du[None, :]
        ev = v[edge][:, None] + dv[None, :]
        sub_d = optics.directions(eu, ev)
        sub_o, sub_w = pose.rays(sub_d)
        sub = scene.cast(sub_o, sub_w)
        sub_z = np.where(np.isfinite(sub.t), sub.t * sub_d[2], 0.0)
        for key, values in _aggregate(sub, sub_z, props, wavenumber, n_surf).items():
            maps[key][edge] = values
        n, per = len(eu), (supersample // k) ** 2
        quads = _aggregate(Hit(*(getattr(sub, f).reshape(n, k * k, per) for f in ("t", "cos", "reflectance", "surface"))),
                           sub_z.reshape(n, k * k, per), props, wavenumber, n_surf)
        rows, cols = np.nonzero(edge)
        for key in light:
            block = light[key].reshape(h, k, w, k).transpose(0, 2, 1, 3)  # a view: (H, W, k, k)
            block[rows, cols] = quads[key].reshape(n, k, k)
    return Rendered(
        irradiance=maps["irradiance"],
        phasor=maps.get("phasor"),
        range_dom=maps["range_dom"],
        z_dom=maps["z_dom"],
        cos_dom=maps["cos_dom"],
        surface_dom=maps["surface_dom"],
        bias_dom=np.where(maps["surface_dom"] >= 0, props.bias_mm[np.maximum(maps["surface_dom"], 0)], 0.0),
        range_plain=maps["range_plain"],
        z_plain=maps["z_plain"],
        passive=maps["passive"],
        hit_fraction=maps["hit_fraction"],
        edge=edge,
        oversample=k,
        irradiance_fine=light["irradiance"],
        passive_fine=light["passive"],
        phasor_fine=light.get("phasor"),
    )
