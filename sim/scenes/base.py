"""Scene primitives and ray casting.

A scene is a list of surfaces in the world frame. Each surface answers, for a
bundle of rays leaving one point (the camera centre), the distance t to its
front side (inf where missed), the
cosine of the incidence angle, the NIR reflectance (a texture over in-plane
coordinates u, v in mm) and its material. The nearest hit wins. Everything is
vectorized over rays; a ray bundle has shape (3, ...).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from sim.scenes.cast import cast_planes
from sim.scenes.patterns import Shape, Texture, Uniform


@dataclass
class Hit:
    """Per-ray result of casting into a scene (arrays of the ray bundle's shape)."""

    t: np.ndarray
    cos: np.ndarray
    reflectance: np.ndarray
    surface: np.ndarray  # index into Scene.surfaces, -1 where nothing was hit

    @staticmethod
    def empty(shape: tuple[int, ...]) -> Hit:
        return Hit(
            t=np.full(shape, np.inf),
            cos=np.zeros(shape),
            reflectance=np.zeros(shape),
            surface=np.full(shape, -1, dtype=np.int16),
        )


def uniform(value: float) -> Uniform:
    """A texture of constant reflectance."""
    return Uniform(value)


@dataclass(frozen=True)
class PlaneSurface:
    """A planar surface: point ``origin``, orthonormal in-plane axes ``u_axis`` and ``v_axis``.

    The front side faces along ``-(u x v)``, i.e. towards a camera looking
    along ``u x v``. ``shape(u, v)`` says where the surface exists (None:
    everywhere), ``texture(u, v)`` gives its reflectance.
    """

    origin: np.ndarray
    u_axis: np.ndarray
    v_axis: np.ndarray
    texture: Texture
    material: str
    shape: Shape | None = None

    @cached_property
    def normal(self) -> np.ndarray:
        """Unit normal pointing towards the side the surface is seen from (read-only; computed once: every cast
        of a render asks for it). The cross product written out: ``np.cross`` costs 40 us for two 3-vectors, and a
        render's scene is new at every step."""
        (a0, a1, a2), (b0, b1, b2) = (float(x) for x in self.u_axis), (float(x) for x in self.v_axis)
        n = np.array([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0])
        normal = -n / math.sqrt(n @ n)
        normal.flags.writeable = False
        return normal

    def intersect(self, origins: np.ndarray, dirs: np.ndarray) -> tuple[np.ndarray, ...]:
        """(t, cos, reflectance) per ray; t = inf where the ray misses the front side or the shape.

        All rays of a bundle start at one point (a camera centre), so
        n.(p0 - o) and the origin's in-plane coordinates are scalars:
        t = n.(p0 - o) / n.d, u = U.(o - p0) + t U.d, v likewise.
        """
        o = np.asarray(origins, float).reshape(3)
        rel0 = o - self.origin
        denom = _dot(self.normal, dirs)
        reach = float(-self.normal @ rel0)
        with np.errstate(divide="ignore", invalid="ignore"):
            t = reach / denom
        t = np.where((denom < -1e-12) & (t > 0), t, np.inf)
        finite = np.isfinite(t)
        tt = np.where(finite, t, 0.0)
        u = float(self.u_axis @ rel0) + tt * _dot(self.u_axis, dirs)
        v = float(self.v_axis @ rel0) + tt * _dot(self.v_axis, dirs)
        if self.shape is not None:
            t = np.where(self.shape(u, v), t, np.inf)
            finite = np.isfinite(t)
        reflectance = np.where(finite, self.texture(u, v), 0.0)
        return t, np.where(finite, -denom, 0.0), reflectance


def _dot(axis: np.ndarray, dirs: np.ndarray) -> np.ndarray:
    """axis . d for every ray of a (3, ...) bundle."""
    return axis[0] * dirs[0] + axis[1] * dirs[1] + axis[2] * dirs[2]


@dataclass(frozen=True)
class HeightFieldSurface:
    """A relief in front of a base plane: points base + u U + v V + h(u, v) N, N towards the viewer.

    ``height(u, v) -> (h, inside)`` gives how far the surface rises and where it
    exists; ``half_extent_mm`` bounds where it can be (|u|, |v|). Intersection
    by fixed-point iteration on the ray parameter, t = (w0 - h(u(t), v(t))) / -(N.d),
    until it moves by less than ``tolerance_mm``; it converges for the
    near-frontal views of the lab (|grad h| tan(view angle) < 1).
    """

    base: PlaneSurface
    height: Callable[[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]
    half_extent_mm: tuple[float, float]
    iterations: int = 60
    tolerance_mm: float = 1e-3

    @property
    def material(self) -> str:
        return self.base.material

    def intersect(self, origins: np.ndarray, dirs: np.ndarray) -> tuple[np.ndarray, ...]:
        b = self.base
        o = np.asarray(origins, float).reshape(3)
        rel0 = o - b.origin
        n = b.normal
        w0, u0, v0 = float(n @ rel0), float(b.u_axis @ rel0), float(b.v_axis @ rel0)
        denom = _dot(n, dirs)
        du, dv = _dot(b.u_axis, dirs), _dot(b.v_axis, dirs)
        with np.errstate(divide="ignore", invalid="ignore"):
            t_base = np.where(denom < -1e-12, w0 / -denom, np.inf)
        finite = np.isfinite(t_base)
        tb = np.where(finite, t_base, 0.0)
        near = finite & (np.abs(u0 + tb * du) <= self.half_extent_mm[0]) & (np.abs(v0 + tb * dv) <= self.half_extent_mm[1])
        t = np.full(dirs.shape[1:], np.inf)
        cos = np.zeros(dirs.shape[1:])
        reflectance = np.zeros(dirs.shape[1:])
        if not near.any():
            return t, cos, reflectance
        den, dun, dvn = denom[near], du[near], dv[near]
        tn = t_base[near]
        for _ in range(self.iterations):
            h, _ = self.height(u0 + tn * dun, v0 + tn * dvn)
            t_new = (w0 - h) / -den
            done = np.max(np.abs(t_new - tn)) < self.tolerance_mm
            tn = t_new
            if done:
                break
        un, vn = u0 + tn * dun, v0 + tn * dvn
        _, inside = self.height(un, vn)
        normal = self._surface_normal(un, vn)
        dn = dirs[:, near]
        t[near] = np.where(inside & (tn > 0), tn, np.inf)
        cos[near] = np.where(inside, np.clip(-(normal * dn).sum(0), 0.0, 1.0), 0.0)
        reflectance[near] = np.where(inside, b.texture(un, vn), 0.0)
        return t, cos, reflectance

    def _surface_normal(self, u: np.ndarray, v: np.ndarray, step: float = 0.25) -> np.ndarray:
        """World-frame unit normal of the relief (towards the viewer), by central differences."""
        hu = (self.height(u + step, v)[0] - self.height(u - step, v)[0]) / (2 * step)
        hv = (self.height(u, v + step)[0] - self.height(u, v - step)[0]) / (2 * step)
        b = self.base
        n = b.normal.reshape(3, *(1,) * u.ndim)
        # s(u, v) = base + u U + v V + h N: tangents U + h_u N and V + h_v N
        normal = np.cross(b.u_axis.reshape(n.shape) + hu * n, b.v_axis.reshape(n.shape) + hv * n, axis=0)
        normal /= np.linalg.norm(normal, axis=0, keepdims=True)
        sign = np.sign((normal * n).sum(0))
        return normal * np.where(sign == 0, 1, sign)


@dataclass(frozen=True)
class SphereSurface:
    """A sphere of ``radius`` about ``centre`` seen from outside (e.g. a ball bar's spheres).

    Ray o + t d meets it at the smaller root of |o + t d - c|^2 = r^2; the
    cosine of incidence is -n.d / |d| with n the outward normal there. The
    texture is read at the hit point's x, y relative to the centre (a uniform
    texture for the lab's spheres).
    """

    centre: np.ndarray
    radius: float
    texture: Texture
    material: str

    def intersect(self, origins: np.ndarray, dirs: np.ndarray) -> tuple[np.ndarray, ...]:
        o = np.asarray(origins, float).reshape(3)
        rel = o - self.centre
        a = _dot(np.ones(3), dirs * dirs)
        b = _dot(rel, dirs)
        c = float(rel @ rel) - self.radius**2
        disc = b * b - a * c
        with np.errstate(invalid="ignore", divide="ignore"):
            t = (-b - np.sqrt(np.maximum(disc, 0.0))) / a
        t = np.where((disc >= 0) & (t > 0), t, np.inf)
        finite = np.isfinite(t)
        tt = np.where(finite, t, 0.0)
        hit = [rel[i] + tt * dirs[i] for i in range(3)]  # hit point relative to the centre
        with np.errstate(invalid="ignore", divide="ignore"):
            cos = -(hit[0] * dirs[0] + hit[1] * dirs[1] + hit[2] * dirs[2]) / (self.radius * np.sqrt(a))
        reflectance = np.where(finite, self.texture(hit[0], hit[1]), 0.0)
        return t, np.where(finite, np.clip(cos, 0.0, 1.0), 0.0), reflectance


Surface = PlaneSurface | HeightFieldSurface | SphereSurface


@dataclass
class Scene:
    """Surfaces of one target set-up, each tagged with its material name."""

    surfaces: list[Surface] = field(default_factory=list)

    def add(self, surface: Surface) -> Scene:
        self.surfaces.append(surface)
        return self

    def cast(self, origins: np.ndarray, dirs: np.ndarray) -> Hit:
        """Nearest hit per ray: planes by the compiled caster, other surfaces in numpy."""
        planes = [i for i, s in enumerate(self.surfaces) if isinstance(s, PlaneSurface)]
        if planes:
            hit = self._cast_planes(planes, np.asarray(origins, float).reshape(3), dirs)
        else:
            hit = Hit.empty(dirs.shape[1:])
        for index, surface in enumerate(self.surfaces):
            if index in planes:
                continue
            t, cos, reflectance = surface.intersect(origins, dirs)
            nearer = t < hit.t
            hit.t = np.where(nearer, t, hit.t)
            hit.cos = np.where(nearer, cos, hit.cos)
            hit.reflectance = np.where(nearer, reflectance, hit.reflectance)
            hit.surface = np.where(nearer, index, hit.surface).astype(np.int16)
        return hit

    def _cast_planes(self, indices: list[int], origin: np.ndarray, dirs: np.ndarray) -> Hit:
        surfaces = [self.surfaces[i] for i in indices]
        frames = np.array([[s.origin, s.u_axis, s.v_axis, s.normal] for s in surfaces], dtype=float)
        shape_code = np.array([s.shape.code if s.shape is not None else 0 for s in surfaces], dtype=np.int64)
        shape_params = np.array([s.shape.params() if s.shape is not None else (0.0,) * 4 for s in surfaces])
        texture_code = np.array([s.texture.code for s in surfaces], dtype=np.int64)
        texture_params = np.array([s.texture.params() for s in surfaces])
        flat = np.ascontiguousarray(dirs.reshape(3, -1), dtype=float)
        n = flat.shape[1]
        t, cos, refl = np.empty(n), np.empty(n), np.empty(n)
        surf = np.empty(n, dtype=np.int64)
        cast_planes(origin, flat, frames, shape_code, shape_params, texture_code, texture_params, t, cos, refl, surf)
        shape = dirs.shape[1:]
        ids = np.asarray(indices, dtype=np.int16)
        return Hit(t.reshape(shape), cos.reshape(shape), refl.reshape(shape),
                   np.where(surf >= 0, ids[np.maximum(surf, 0)], -1).astype(np.int16).reshape(shape))

    def materials(self) -> list[str]:
        return [s.material for s in self.surfaces]
