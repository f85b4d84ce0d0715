"""The diffuse floor bounce's depth signature: the imaginary part of its phasor alone.

The ``plane_phasor`` candidate (labctl/reconcile/candidates.py) fits dr ~ Im(m) / k at every trial plane
and distance of its grid, m the bounce's phasor relative to the direct light (sim/effects/diffuse_floor_multipath.py
``bounce_phasor``, the effect's ``formula``). The simulator integrates the whole complex m; the grid needs its
imaginary part only. Im of a sum of kernel x (cos + j sin) is the sum of kernel x sin in the same order, so
``bounce_imag`` runs the simulator's product rule node for node without the cosines and the real part, and gives
``bounce_phasor(...).imag`` bit for bit (tests/reconcile/test_bounce_signature.py) at about two thirds of the
cost.
"""

from __future__ import annotations

import functools
import math
from typing import Any

import numpy as np
from numba import njit, prange

from sim.effects.floor_multipath import PLANES


@functools.cache
def _rule(nodes: int) -> tuple[np.ndarray, np.ndarray]:
    """Gauss-Legendre nodes and weights on [0, 1] (the simulator's rule)."""
    s, w = np.polynomial.legendre.leggauss(nodes)
    return (s + 1.0) / 2.0, w / 2.0


def bounce_imag(x: np.ndarray, y: np.ndarray, z: np.ndarray, plane: str, distance_mm: float, sensor: Any,
                nodes: int) -> np.ndarray:
    """Im(m / rho) of the points (x, y, z) (camera frame, mm; 1-d arrays of one length), with the arguments of
    ``bounce_phasor``: equal to ``bounce_phasor(x, y, z, plane, distance_mm, sensor, nodes).imag``."""
    axis, side = PLANES[plane]
    p = sensor.profile
    across, lateral = (p.fov_h_deg, p.fov_v_deg) if axis == 0 else (p.fov_v_deg, p.fov_h_deg)
    d = float(distance_mm)
    w0 = d / math.tan(math.radians(across) / 2)  # the depth where the emitter's cone reaches the plane
    tan_lateral = math.tan(math.radians(lateral) / 2)
    x, y, z = (np.ascontiguousarray(np.nan_to_num(np.asarray(v, float))) for v in (x, y, z))
    h = d - side * (x, y)[axis]
    b = y if axis == 0 else x
    return _bounce_imag(h, b, x * x + y * y + z * z, z, d, w0, tan_lateral, sensor.wavenumber, *_rule(nodes),
                        *_rule(nodes // 2))


@njit(parallel=True, cache=True, nogil=True)
def _bounce_imag(h: np.ndarray, b: np.ndarray, r2: np.ndarray, z: np.ndarray, d: float, w0: float,
                 tan_lateral: float, k: float, s_nodes: np.ndarray, s_weights: np.ndarray, t_nodes: np.ndarray,
                 t_weights: np.ndarray) -> np.ndarray:  # pragma: no cover (compiled)
    """Im(m / rho) per point: sim's ``_bounce`` with each node's sine alone (each point on its own)."""
    out = np.zeros(z.size)
    for i in prange(z.size):
        if not (h[i] > 0.0 and z[i] > w0):
            continue
        r = math.sqrt(r2[i])
        depth = z[i] - w0
        total = 0.0
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
                    total += kernel * math.sin(phase)
        out[i] = total * r**3 / (math.pi * z[i])
    return out
