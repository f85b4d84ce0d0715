"""Compiled aggregation of a pixel's ray samples into its light quantities (see sim/render.py).

For samples i of one pixel (N rows of S samples): shading_i = rho_i cos_i^m,
irradiance_i = shading_i / (t_i / 1 m)^2, range_i = t_i + b_i (b: the surface's
sub-surface bias); the pixel gets the means of irradiance and shading, the
hit fraction, the mean phasor irradiance_i exp(j k range_i) when ``wavenumber``
> 0, the irradiance-weighted range, camera depth and incidence cosine of
its dominant surface (the one returning most light; a tiny weight per hit
decides where none returns light), and the plain (unweighted) means of that
surface's range and camera depth over its samples.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

#: pixels per parallel chunk (one scratch array per chunk, not per pixel)
CHUNK = 4096


@njit(cache=True, inline="always")
def _shade(refl, c, lambert):  # pragma: no cover
    c = min(max(c, 0.0), 1.0)
    return refl * c if lambert == 1.0 else refl * c**lambert


@njit(parallel=True, cache=True)
def aggregate(t, cos, refl, surf, z_cam, bias, lambert, wavenumber, n_surfaces,
              irradiance, passive, hit_fraction, phasor, range_dom, z_dom, cos_dom, surface_dom, range_plain,
              z_plain):  # pragma: no cover
    n, s = t.shape
    for chunk in prange((n + CHUNK - 1) // CHUNK):
        score = np.zeros(n_surfaces)
        for i in range(chunk * CHUNK, min(n, (chunk + 1) * CHUNK)):
            _pixel(i, s, t, cos, refl, surf, z_cam, bias, lambert, wavenumber, score, irradiance, passive,
                   hit_fraction, phasor, range_dom, z_dom, cos_dom, surface_dom, range_plain, z_plain)


@njit(cache=True, inline="always")
def _pixel(i, s, t, cos, refl, surf, z_cam, bias, lambert, wavenumber, score, irradiance, passive, hit_fraction,
           phasor, range_dom, z_dom, cos_dom, surface_dom, range_plain, z_plain):  # pragma: no cover
    score[:] = 0.0
    irr_sum = 0.0
    shade_sum = 0.0
    hits = 0
    re = 0.0
    im = 0.0
    for j in range(s):
        k = surf[i, j]
        if k < 0:
            continue
        shade = _shade(refl[i, j], cos[i, j], lambert[k])
        irr = shade / (t[i, j] / 1000.0) ** 2
        irr_sum += irr
        shade_sum += shade
        hits += 1
        score[k] += irr + 1e-12
        if wavenumber > 0.0:
            phase = wavenumber * (t[i, j] + bias[k])
            re += irr * math.cos(phase)
            im += irr * math.sin(phase)
    irradiance[i] = irr_sum / s
    passive[i] = shade_sum / s
    hit_fraction[i] = hits / s
    phasor[i] = complex(re / s, im / s)
    if hits == 0:
        range_dom[i] = np.nan
        z_dom[i] = np.nan
        range_plain[i] = np.nan
        z_plain[i] = np.nan
        cos_dom[i] = 0.0
        surface_dom[i] = -1
        return
    dom = int(np.argmax(score))
    w_sum = 0.0
    r_acc = 0.0
    z_acc = 0.0
    c_acc = 0.0
    count = 0
    r_plain = 0.0
    z_sum = 0.0
    for j in range(s):
        if surf[i, j] != dom:
            continue
        w = _shade(refl[i, j], cos[i, j], lambert[dom]) / (t[i, j] / 1000.0) ** 2 + 1e-12
        w_sum += w
        r_acc += w * (t[i, j] + bias[dom])
        z_acc += w * z_cam[i, j]
        c_acc += w * cos[i, j]
        count += 1
        r_plain += t[i, j] + bias[dom]
        z_sum += z_cam[i, j]
    range_dom[i] = r_acc / w_sum
    z_dom[i] = z_acc / w_sum
    cos_dom[i] = c_acc / w_sum
    surface_dom[i] = dom
    range_plain[i] = r_plain / count
    z_plain[i] = z_sum / count


@njit(parallel=True, cache=True)
def sample_light(t, cos, refl, surf, bias, lambert, wavenumber, irradiance, passive, phasor):  # pragma: no cover
    """Light of single samples (flat arrays): irradiance, shading and, with ``wavenumber`` > 0, the phasor."""
    for i in prange(t.size):
        k = surf[i]
        if k < 0:
            irradiance[i] = 0.0
            passive[i] = 0.0
            phasor[i] = 0.0
            continue
        shade = _shade(refl[i], cos[i], lambert[k])
        irr = shade / (t[i] / 1000.0) ** 2
        irradiance[i] = irr
        passive[i] = shade
        if wavenumber > 0.0:
            phase = wavenumber * (t[i] + bias[k])
            phasor[i] = complex(irr * math.cos(phase), irr * math.sin(phase))
        else:
            phasor[i] = 0.0
