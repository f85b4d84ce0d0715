"""Compiled ray casting against planes with coded textures and shapes (sim/scenes/patterns.py).

All rays leave one point (the camera centre). Per ray and plane:
t = n.(p0 - o) / n.d on the front side (n.d < 0), in-plane coordinates
u = U.(o - p0) + t U.d, v likewise; the plane exists where its shape says so;
the nearest hit wins. Equivalent to ``PlaneSurface.intersect`` in numpy, and
tested against it.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange


@njit(cache=True, inline="always")
def _inside(code: int, p: np.ndarray, u: float, v: float) -> bool:  # pragma: no cover
    if code == 0:
        return True
    if code == 1:  # rectangle: half width, half height
        return abs(u) <= p[0] and abs(v) <= p[1]
    r = math.hypot(u, v)  # star: segments, radius, disc radius, rotation
    if r > p[1]:
        return False
    if r <= p[2]:
        return True
    phi = (math.atan2(v, u) - p[3]) % (2.0 * math.pi)
    return int(math.floor(phi * p[0] / (2.0 * math.pi))) % 2 == 0


@njit(cache=True, inline="always")
def _texture(code: int, p: np.ndarray, u: float, v: float) -> float:  # pragma: no cover
    if code == 0:
        return p[0]
    if code == 1:  # checker: tile, white, black
        parity = (math.floor(u / p[0]) + math.floor(v / p[0])) % 2.0
        return p[1] if parity == 0.0 else p[2]
    ca, sa = math.cos(p[0]), math.sin(p[0])  # slanted quadrant: angle, white, black
    return p[2] if (ca * u + sa * v > 0.0) and (-sa * u + ca * v > 0.0) else p[1]


@njit(parallel=True, cache=True)
def cast_planes(origin, dirs, frames, shape_code, shape_params, texture_code, texture_params,
                t_out, cos_out, refl_out, surf_out):  # pragma: no cover
    """Nearest plane hit for every ray of ``dirs`` (3, N); planes as rows of ``frames`` (K, 4, 3): p0, U, V, n."""
    n_rays = dirs.shape[1]
    k_planes = frames.shape[0]
    for i in prange(n_rays):
        dx, dy, dz = dirs[0, i], dirs[1, i], dirs[2, i]
        best = np.inf
        best_cos = 0.0
        best_refl = 0.0
        best_k = -1
        for k in range(k_planes):
            nx, ny, nz = frames[k, 3, 0], frames[k, 3, 1], frames[k, 3, 2]
            denom = nx * dx + ny * dy + nz * dz
            if denom >= -1e-12:
                continue
            rx = origin[0] - frames[k, 0, 0]
            ry = origin[1] - frames[k, 0, 1]
            rz = origin[2] - frames[k, 0, 2]
            t = -(nx * rx + ny * ry + nz * rz) / denom
            if t <= 0.0 or t >= best:
                continue
            u = (frames[k, 1, 0] * (rx + t * dx) + frames[k, 1, 1] * (ry + t * dy) + frames[k, 1, 2] * (rz + t * dz))
            v = (frames[k, 2, 0] * (rx + t * dx) + frames[k, 2, 1] * (ry + t * dy) + frames[k, 2, 2] * (rz + t * dz))
            if not _inside(shape_code[k], shape_params[k], u, v):
                continue
            best = t
            best_cos = -denom
            best_refl = _texture(texture_code[k], texture_params[k], u, v)
            best_k = k
        t_out[i] = best
        cos_out[i] = best_cos
        refl_out[i] = best_refl
        surf_out[i] = best_k
