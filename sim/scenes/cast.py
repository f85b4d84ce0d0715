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
def _inside(code, p0, p1, p2, p3, u, v):  # pragma: no cover
    if code == 0:
        return True
    if code == 1:  # rectangle: half width, half height
        return abs(u) <= p0 and abs(v) <= p1
    r = math.hypot(u, v)  # star: segments, radius, disc radius, rotation
    if r > p1:
        return False
    if r <= p2:
        return True
    phi = (math.atan2(v, u) - p3) % (2.0 * math.pi)
    return int(math.floor(phi * p0 / (2.0 * math.pi))) % 2 == 0


@njit(cache=True, inline="always")
def _texture(code, p0, p1, p2, cos_a, sin_a, u, v):  # pragma: no cover
    if code == 0:
        return p0
    if code == 1:  # checker: tile, white, black
        parity = (math.floor(u / p0) + math.floor(v / p0)) % 2.0
        return p1 if parity == 0.0 else p2
    # slanted quadrant: angle (as cos_a, sin_a), white, black
    return p2 if (cos_a * u + sin_a * v > 0.0) and (-sin_a * u + cos_a * v > 0.0) else p1


@njit(parallel=True, cache=True)
def cast_planes(origin, dirs, frames, shape_code, shape_params, texture_code, texture_params,
                t_out, cos_out, refl_out, surf_out):  # pragma: no cover
    """Nearest plane hit for every ray of ``dirs`` (3, N); planes as rows of ``frames`` (K, 4, 3): p0, U, V, n."""
    n_rays = dirs.shape[1]
    k_planes = frames.shape[0]
    # per plane: the origin's offset along n, U, V (the same for every ray) and the texture angle's cos/sin
    reach = np.empty(k_planes)
    u0 = np.empty(k_planes)
    v0 = np.empty(k_planes)
    cos_a = np.empty(k_planes)
    sin_a = np.empty(k_planes)
    for k in range(k_planes):
        rx, ry, rz = origin[0] - frames[k, 0, 0], origin[1] - frames[k, 0, 1], origin[2] - frames[k, 0, 2]
        reach[k] = -(frames[k, 3, 0] * rx + frames[k, 3, 1] * ry + frames[k, 3, 2] * rz)
        u0[k] = frames[k, 1, 0] * rx + frames[k, 1, 1] * ry + frames[k, 1, 2] * rz
        v0[k] = frames[k, 2, 0] * rx + frames[k, 2, 1] * ry + frames[k, 2, 2] * rz
        cos_a[k] = math.cos(texture_params[k, 0])
        sin_a[k] = math.sin(texture_params[k, 0])
    for i in prange(n_rays):
        dx, dy, dz = dirs[0, i], dirs[1, i], dirs[2, i]
        best = np.inf
        best_cos = 0.0
        best_refl = 0.0
        best_k = -1
        for k in range(k_planes):
            denom = frames[k, 3, 0] * dx + frames[k, 3, 1] * dy + frames[k, 3, 2] * dz
            if denom >= -1e-12:
                continue
            t = reach[k] / denom
            if t <= 0.0 or t >= best:
                continue
            u = u0[k] + t * (frames[k, 1, 0] * dx + frames[k, 1, 1] * dy + frames[k, 1, 2] * dz)
            v = v0[k] + t * (frames[k, 2, 0] * dx + frames[k, 2, 1] * dy + frames[k, 2, 2] * dz)
            if not _inside(shape_code[k], shape_params[k, 0], shape_params[k, 1], shape_params[k, 2],
                           shape_params[k, 3], u, v):
                continue
            best = t
            best_cos = -denom
            best_refl = _texture(texture_code[k], texture_params[k, 0], texture_params[k, 1], texture_params[k, 2],
                                 cos_a[k], sin_a[k], u, v)
            best_k = k
        t_out[i] = best
        cos_out[i] = best_cos
        refl_out[i] = best_refl
        surf_out[i] = best_k
