"""Plausibility of a measured figure: limits a figure cannot cross without measuring something else.

* Nyquist: a sampled image holds no frequency above 0.5 cycles per pixel
  (Nyquist-Shannon; ISO 12233:2017 reports the e-SFR up to it). An SFR10
  above 0.5 cy/px is aliasing, sharpening or a noisy edge, not resolution.
* Quantization: a camera that outputs coordinates in steps of q (the
  AM-T100's integer millimetres, the RealSense z16 depth unit) cannot show a
  spread or error below q reliably: the std of a quantized signal follows the
  true one only when the noise exceeds about half a step (Sheppard's
  correction, q^2 / 12), and a noise below that reads 0 or jumps by whole steps.
* Coordinate near zero: the std of x = z (u - cx) / f at a pixel on the
  principal axis carries no depth noise (x ~ 0 whatever z does).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

#: cycles per pixel: the highest frequency a sampled image holds
NYQUIST_CY_PX = 0.5
#: a finer step is float rounding (float32 steps below 4096 mm are <= 0.5 um) or the lattice z (u - cx) / f
#: of x and y back-projected from whole-millimetre depth (1 / (2 f) <= 2.5 um for f >= 200 px), not an
#: output resolution; the figures are never that small
MIN_QUANTIZATION_MM = 0.01
#: |coordinate| / distance below which a pixel counts as on the principal axis (0.57 deg)
NEAR_AXIS_RATIO = 0.01


@njit(cache=True, nogil=True)
def _finite_ranks(values: np.ndarray, ranks: np.ndarray) -> np.ndarray:  # pragma: no cover - compiled
    """Positions of the finite values of the given ascending ranks (0 = the first finite value), in one pass."""
    out = np.empty(ranks.size, np.int64)
    rank = 0
    m = 0
    for i in range(values.size):
        if m == ranks.size:
            break
        v = values[i]
        if v - v == 0.0:  # finite
            while m < ranks.size and ranks[m] == rank:
                out[m] = i
                m += 1
            rank += 1
    return out


@njit(cache=True, nogil=True)
def _count_finite(values: np.ndarray) -> int:  # pragma: no cover - compiled
    """How many of the flat ``values`` are finite."""
    count = 0
    for i in range(values.size):
        v = values[i]
        count += v - v == 0.0
    return count


def _finite_sample(values: np.ndarray, sample: int) -> np.ndarray:
    """Positions in the flat ``values`` of ``sample`` finite values evenly spread over the finite ones (all of
    them if fewer): the k-th finite value for k = linspace(0, count - 1, sample), located by a compiled pass over
    the values (none where every value is finite), so that a whole stack's positions are never listed."""
    total = _count_finite(values)
    wanted = (np.linspace(0, total - 1, sample).astype(int) if total > sample else np.arange(total)).astype(np.int64)
    return wanted if total == values.size else _finite_ranks(values, wanted)  # all finite: the k-th is at k


def quantization_step(values: np.ndarray, sample: int = 20000) -> float:
    """The common step of the finite ``values`` (e.g. 1.0 for integer-millimetre output), NaN if continuous.

    The step is the smallest difference between distinct values of a sample;
    the values count as quantized when every one is a whole number of steps
    from the smallest (within 0.1 % of a step) and the step is at least 10 um.

    Examples
    --------
    >>> quantization_step(np.array([1000.0, 1002.0, 1001.0, 1005.0]))  # whole millimetres
    1.0
    >>> quantization_step(np.array([1.0, 1.5, 2.2]))  # 2.2 is no whole number of 0.5 steps from 1.0
    nan
    """
    flat = np.asarray(values).reshape(-1)
    distinct = np.unique(flat[_finite_sample(flat, sample)].astype(float))
    if distinct.size < 2:
        return math.nan
    step = float(np.min(np.diff(distinct)))
    if step < MIN_QUANTIZATION_MM:
        return math.nan
    multiples = (distinct - distinct[0]) / step
    return step if bool(np.all(np.abs(multiples - np.round(multiples)) < 1e-3)) else math.nan


def above_nyquist(sfr10_cy_px: float) -> bool:
    """True when an SFR10 lies above the Nyquist frequency (0.5 cy/px).

    Examples
    --------
    >>> above_nyquist(0.6), above_nyquist(0.3)
    (True, False)
    """
    return math.isfinite(sfr10_cy_px) and sfr10_cy_px > NYQUIST_CY_PX


def at_quantization_step(value_mm: float, step_mm: float) -> bool:
    """True when a spread or error (mm) is below one quantization step of the output.

    Examples
    --------
    >>> at_quantization_step(0.4, 1.0), at_quantization_step(1.2, 1.0)
    (True, False)
    """
    return math.isfinite(value_mm) and math.isfinite(step_mm) and 0.0 <= abs(value_mm) < step_mm


def near_axis(coordinate_mm: float, distance_mm: float) -> bool:
    """True when a pixel's x (or y) is within 1 % of the distance of 0: on the principal axis.

    Examples
    --------
    >>> near_axis(5.0, 1000.0), near_axis(15.0, 1000.0)  # 0.5 % and 1.5 % of the distance
    (True, False)
    """
    return math.isfinite(coordinate_mm) and math.isfinite(distance_mm) and \
        abs(coordinate_mm) < NEAR_AXIS_RATIO * abs(distance_mm)
