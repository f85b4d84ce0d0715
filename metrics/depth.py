"""Depth measurement error on a flat target (Thesis 2024, 4.2.1, ISO 5725-2 terms).

* repeatability: per-pixel standard deviation over the stack (centre pixel reported);
* precision: 90 % quantile of the per-pixel standard deviations of one position;
* trueness: per-pixel stack mean minus the reference distance (z, not radial);
* accuracy: a single frame (the first) minus the reference distance.

Curves over distance report the median and the 90 % quantile (Q90) of the
absolute values; the invalid-pixel fraction is reported alongside so that a
camera hiding bad pixels does not look better.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit, prange

from metrics.stack import StackStats
from metrics.uncertainty import (
    delete_a_group_jackknife,
    quantile_standard_error,
    spread_sensitivity,
    standard_error_of_std,
)


def quantile_abs(values: np.ndarray, q: float) -> float:
    """Quantile ``q`` (0..1) of |values| over finite entries; NaN if there are none.

    Examples
    --------
    >>> quantile_abs(np.array([-3.0, 1.0, 2.0, np.nan]), 0.5)  # median of 3, 1, 2
    2.0
    """
    return median_q90_abs(values, (q,))[0]


def median_q90_abs(values: np.ndarray, qs: tuple[float, ...] = (0.5, 0.9)) -> tuple[float, ...]:
    """Quantiles of |values| over finite entries, NumPy's linear ``quantile`` bit for bit; NaN if none.

    A float32 or float64 array's quantiles are selected among the values near them (:func:`_abs_quantiles`),
    not by partitioning all of them; other types go through ``np.quantile``.

    Examples
    --------
    |values| = 0, 1, ..., 10: median 5, 90 % quantile 9 (linear interpolation).

    >>> median_q90_abs(np.append(-np.arange(11.0), np.nan))
    (5.0, 9.0)
    """
    if values.dtype in (np.float32, np.float64):
        return tuple(float(x) for x in _abs_quantiles(np.ascontiguousarray(values).reshape(-1),
                                                      np.array(qs, dtype=np.float64)))
    v = np.abs(values[np.isfinite(values)])
    if not v.size:
        return tuple(float("nan") for _ in qs)
    return tuple(float(x) for x in np.quantile(v, qs))


def center_pixel(shape: tuple[int, int]) -> tuple[int, int]:
    """Row, column of the centre pixel (H // 2, W // 2).

    Examples
    --------
    >>> center_pixel((480, 640))
    (240, 320)
    """
    return shape[0] // 2, shape[1] // 2


@dataclass(frozen=True)
class DepthErrors:
    reference_mm: float
    n_frames: int
    trueness_median_mm: float
    trueness_q90_mm: float
    trueness_signed_median_mm: float
    accuracy_median_mm: float
    accuracy_q90_mm: float
    precision_median_mm: float
    precision_q90_mm: float
    repeatability_center_mm: float
    invalid_fraction: float


def depth_errors(stats: StackStats, first_frame: np.ndarray, reference_mm: float) -> DepthErrors:
    """All Thesis 2024, 4.2.1 figures of one stack of a flat target at ``reference_mm``.

    ``stats`` are the stack statistics of z, ``first_frame`` its frame 0 (for
    accuracy, evaluated on the pixels valid in that frame and in the stack).

    Examples
    --------
    Two frames 2 mm apart at every pixel of a wall at 1000 mm: stack means 1000, 1002, 1004, 1006
    (trueness 0, 2, 4, 6: median 3), first frame 999, 1001, 1003, 1005 (accuracy |-1|, 1, 3, 5:
    median 2), per-pixel sample std sqrt(2) = 1.414.

    >>> from metrics.stack import stack_stats
    >>> first = np.array([[999.0, 1001.0], [1003.0, 1005.0]])
    >>> errors = depth_errors(stack_stats(np.stack([first, first + 2.0])), first, 1000.0)
    >>> errors.trueness_median_mm, errors.accuracy_median_mm, round(errors.precision_median_mm, 3)
    (3.0, 2.0, 1.414)
    """
    valid = stats.valid
    trueness = stats.mean[valid] - reference_mm
    accuracy = first_frame[valid] - reference_mm
    std = stats.std[valid]
    r, c = center_pixel(valid.shape)
    t50, t90 = median_q90_abs(trueness)
    a50, a90 = median_q90_abs(accuracy)
    p50, p90 = median_q90_abs(std)
    return DepthErrors(
        reference_mm=float(reference_mm),
        n_frames=stats.n_frames,
        trueness_median_mm=t50,
        trueness_q90_mm=t90,
        trueness_signed_median_mm=float(np.median(trueness)) if trueness.size else float("nan"),
        accuracy_median_mm=a50,
        accuracy_q90_mm=a90,
        precision_median_mm=p50,
        precision_q90_mm=p90,
        repeatability_center_mm=float(stats.std[r, c]) if valid[r, c] else float("nan"),
        invalid_fraction=float(1.0 - valid.mean()),
    )


def center_repeatability_uncertainty(stats: StackStats) -> float:
    """Type A standard uncertainty of the centre pixel's repeatability, a sample standard deviation s of n frames:
    s / sqrt(2 (n - 1)) (GUM E.4.3, Table E.1); NaN where the centre pixel is invalid.

    Examples
    --------
    The centre pixel seen as 1, 2, 3 over three frames: s = 1, uncertainty 1 / sqrt(4) = 0.5.

    >>> from metrics.stack import stack_stats
    >>> center_repeatability_uncertainty(stack_stats(np.arange(1.0, 4.0)[:, None, None] * np.ones((3, 1, 1))))
    0.5
    """
    r, c = center_pixel(stats.valid.shape)
    if not stats.valid[r, c]:
        return float("nan")
    return standard_error_of_std(float(stats.std[r, c]), int(stats.count[r, c]))


@dataclass(frozen=True)
class DepthErrorUncertainties:
    """Type A standard uncertainties (GUM 4.2) of the Q90 figures of one stack: what the frames' noise leaves
    in them; and the magnitudes of the sensitivity coefficients of trueness and accuracy Q90 to the reference
    distance (GUM 5.1.3), which scale the reference's components (the caller's)."""

    trueness_q90_mm: float
    accuracy_q90_mm: float
    precision_q90_mm: float
    trueness_reference_sensitivity: float
    accuracy_reference_sensitivity: float


#: step (mm) of the reference distance for the numerical sensitivity coefficients where the reference's
#: standard uncertainty is not known: about what it is (a laser meter's mean reading and offset)
REFERENCE_STEP_MM = 0.1


@njit(cache=True, nogil=True, inline="always")
def _copy(source: np.ndarray, target: np.ndarray) -> np.ndarray:  # pragma: no cover - compiled
    """``target`` (as long as ``source``) holding ``source``'s values, by a plain loop: numba compiles an array
    assignment's broadcasting checks for seconds."""
    for i in range(source.size):
        target[i] = source[i]
    return target


@njit(cache=True, nogil=True)
def _select(a: np.ndarray, k: int) -> float:  # pragma: no cover - compiled
    """The k-th smallest (0-based) of the 1-D ``a`` (no NaN), ``a`` reordered in place so that no value before
    index k is larger and none after it smaller, as ``np.partition(a, k)`` leaves it (Hoare 1961, FIND: partition
    about the median of three, keep the side holding k). Written out rather than ``np.partition``, whose compiled
    form takes numba about 12 s to build for each type of array."""
    lo, hi = 0, a.size - 1
    while lo < hi:
        mid = (lo + hi) // 2
        if a[mid] < a[lo]:
            a[lo], a[mid] = a[mid], a[lo]
        if a[hi] < a[lo]:
            a[lo], a[hi] = a[hi], a[lo]
        if a[hi] < a[mid]:
            a[mid], a[hi] = a[hi], a[mid]
        pivot = a[mid]
        i, j = lo, hi
        while i <= j:
            while a[i] < pivot:
                i += 1
            while pivot < a[j]:
                j -= 1
            if i <= j:
                a[i], a[j] = a[j], a[i]
                i += 1
                j -= 1
        if k <= j:
            hi = j
        elif k >= i:
            lo = i
        else:  # between j and i every value is the pivot
            break
    return a[k]


@njit(cache=True, nogil=True)
def _linear_quantile(values: np.ndarray, n: int, below: int, inside: np.ndarray, n_inside: int,
                     q: float) -> float:  # pragma: no cover - compiled
    """NumPy's ``quantile(values[:n], q)`` (method ``linear``, Hyndman & Fan 1996, definition 7), its arithmetic
    step by step: the virtual index (n - 1) q, its two neighbouring order statistics a and b, and the
    interpolation a + (b - a) g, or b - (b - a) (1 - g) where the weight g >= 0.5. The order statistics are
    taken from ``inside[:n_inside]``, the values between two bounds of which ``below`` values lie below the lower
    one, when both ranks fall among them, else from all the values (NaN where n = 0)."""
    if n == 0:
        return np.nan
    virtual = (n - 1) * q
    k = n - 1 if virtual >= n - 1 else int(np.floor(virtual))
    rank = k - below
    if 0 <= rank and rank + (k < n - 1) < n_inside:
        part = _copy(inside[:n_inside], np.empty(n_inside, inside.dtype))
    else:
        rank = k
        part = _copy(values[:n], np.empty(n, values.dtype))
    a = _select(part, rank)
    if k == n - 1:
        return np.float64(a)
    b = part[rank + 1]
    for i in range(rank + 2, part.size):
        b = min(b, part[i])
    gamma = virtual - k
    diff = b - a
    if gamma >= 0.5:
        return np.float64(b) - np.float64(diff) * (1.0 - gamma)
    return np.float64(a) + np.float64(diff) * gamma


#: values taken (evenly spaced) to bracket a quantile of many: each is sought among the values between the sample's
#: order statistics ``SAMPLE_MARGIN`` below and above the sample's own quantile, else among all of them
SAMPLE = 4096
SAMPLE_MARGIN = 128


@njit(cache=True, nogil=True)
def _abs_quantiles(values: np.ndarray, qs: np.ndarray) -> np.ndarray:  # pragma: no cover - compiled
    """The quantiles ``qs`` of |values| over the finite ones of the 1-D ``values`` (NaN where none), each as
    :func:`_linear_quantile` selects it: among the values near it, bracketed by an evenly spaced sample of them.
    The passes store every value and advance by whether it is kept (no branch to mispredict)."""
    v = np.empty(values.size, values.dtype)
    n = 0
    for i in range(values.size):
        x = values[i]
        v[n] = abs(x)
        n += x - x == 0.0
    out = np.empty(qs.size)
    if n == 0:
        out[:] = np.nan
        return out
    sample = v[:n:max(1, n // SAMPLE)]
    m = sample.size
    scratch = np.empty(m, values.dtype)
    inside = np.empty(n, values.dtype)
    for j in range(qs.size):
        at = int(qs[j] * (m - 1))
        low = _select(_copy(sample, scratch), max(at - SAMPLE_MARGIN, 0))
        high = _select(_copy(sample, scratch), min(at + SAMPLE_MARGIN, m - 1))
        below = n_inside = 0
        for i in range(n):
            x = v[i]
            below += x < low
            inside[n_inside] = x
            n_inside += (x >= low) & (x <= high)
        out[j] = _linear_quantile(v, n, below, inside, n_inside, qs[j])
    return out


@njit(cache=True, nogil=True)
def _frame_deviation(v: float, mean: float) -> tuple[float, float, float]:  # pragma: no cover - compiled
    """A frame's value's deviation from the pixel's stack mean in float32 (NaN as 0, infinities as float32's
    largest magnitudes), whether it is finite (1 or 0), and its square in float32."""
    d = np.float32(np.float64(v) - mean)
    if d - d == 0.0:
        return np.float64(d), 1.0, np.float64(d * d)
    if d != d:
        return 0.0, 0.0, 0.0
    big = np.float32(3.4028234663852886e38) if d > 0 else np.float32(-3.4028234663852886e38)
    return np.float64(big), 0.0, np.float64(big * big)


@njit(parallel=True, cache=True, nogil=True)
def _frame_totals(stack: np.ndarray, pixels: np.ndarray,
                  mean: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # pragma: no cover - compiled
    """Per pixel of the flat ``pixels`` of the (N, H * W) ``stack``: the sums over the frames, in frame order
    and in float64, of its finite count, deviation and squared deviation (:func:`_frame_deviation`)."""
    n = stack.shape[0]
    size = pixels.size
    count, total, squares = np.zeros(size), np.zeros(size), np.zeros(size)
    block = 4096
    for b in prange((size + block - 1) // block):
        for k in range(n):
            for p in range(b * block, min(size, (b + 1) * block)):
                d, seen, d2 = _frame_deviation(stack[k, pixels[p]], mean[p])
                if k == 0:
                    count[p], total[p], squares[p] = seen, d, d2
                else:
                    count[p] += seen
                    total[p] += d
                    squares[p] += d2
    return count, total, squares


@njit(cache=True, nogil=True, inline="always")
def _count_at_or_below(v: float, threshold: float, tolerance: float, counts: np.ndarray, f: int) -> None:  # pragma: no cover
    """Count a finite ``v`` in ``counts[f]`` (used) and ``counts[2 + f]`` (at or below ``threshold``; within
    ``tolerance`` of it, half)."""
    if v - v == 0.0:
        counts[f] += 1.0
        if v < threshold - tolerance:
            counts[2 + f] += 1.0
        elif v <= threshold + tolerance:
            counts[2 + f] += 0.5


@njit(parallel=True, cache=True, nogil=True)
def _left_out_shares(stack: np.ndarray, pixels: np.ndarray, mean: np.ndarray, count: np.ndarray, total: np.ndarray,
                     squares: np.ndarray, reference: float, thresholds: np.ndarray,
                     tolerance: np.ndarray) -> np.ndarray:  # pragma: no cover - compiled
    """(N, 2) per frame left out: the share of the pixels whose |mean - ``reference``|, and whose std, lies at or
    below ``thresholds`` (0 and 1), the pixels' means and sample stds without the frame from the totals less its
    values; a value within ``tolerance`` of its threshold counts half (a mid-distribution share, so that values
    equal to it but for their last bits do not count in some replicates and not in others). Among the pixels
    with two frames or more left and a finite value; NaN where there are none. The pixels are taken in blocks,
    every frame of a block before the next block (the block's totals stay in the cache); the counts, whole and
    half numbers, are exact in any order."""
    n = stack.shape[0]
    size = pixels.size
    block = 4096
    blocks = (size + block - 1) // block
    counts = np.zeros((blocks, n, 4))  # per block and frame: used (0, 1), at or below (2, 3)
    for b in prange(blocks):
        for i in range(n):
            here = counts[b, i]
            for p in range(b * block, min(size, (b + 1) * block)):
                d, seen, d2 = _frame_deviation(stack[i, pixels[p]], mean[p])
                c = count[p] - seen
                if not c >= 2:
                    continue
                s = total[p] - d
                shift = s / c
                var = (squares[p] - d2 - s * shift) / (c - 1)
                _count_at_or_below(abs(mean[p] + shift - reference), thresholds[0], tolerance[0], here, 0)
                _count_at_or_below(abs(np.sqrt(0.0 if var < 0.0 else var)), thresholds[1], tolerance[1], here, 1)
    # the blocks added in order, as counts.sum(axis=0) adds them (written out: numba takes seconds to compile an
    # axis sum)
    summed = np.zeros((n, 4))
    for b in range(blocks):
        for i in range(n):
            for f in range(4):
                summed[i, f] += counts[b, i, f]
    out = np.empty((n, 2))
    for i in range(n):
        for f in range(2):
            out[i, f] = summed[i, 2 + f] / summed[i, f] if summed[i, f] > 0 else np.nan
    return out


@njit(parallel=True, cache=True, nogil=True)
def _frame_q90s(stack: np.ndarray, pixels: np.ndarray, reference: np.floating, bounds: np.ndarray,
                q: float) -> np.ndarray:  # pragma: no cover - compiled
    """Per frame of the (N, H * W) ``stack``: the quantile ``q`` of |value - ``reference``| over the finite values of
    the flat ``pixels``, the difference taken in the stack's precision (``reference`` of the stack's dtype: as NumPy
    takes a float32 array less a Python float); ``bounds``: (low, high) between which it is sought first."""
    n = stack.shape[0]
    size = pixels.size
    out = np.empty(n)
    for i in prange(n):
        values = np.empty(size, stack.dtype)
        inside = np.empty(size, stack.dtype)
        used = below = n_inside = 0
        for p in range(size):
            v = abs(stack[i, pixels[p]] - reference)
            if v - v == 0.0:
                values[used] = v
                used += 1
                if v < bounds[0]:
                    below += 1
                elif v <= bounds[1]:
                    inside[n_inside] = v
                    n_inside += 1
        out[i] = _linear_quantile(values, used, below, inside, n_inside, q)
    return out


#: the single frames' Q90s (accuracy) are sought first among the values whose rank in the first frame's lies within
#: this fraction of the pixels (plus ``BRACKET_PIXELS``) of its Q90: frames of one stack differ little there
BRACKET_FRACTION = 0.02
BRACKET_PIXELS = 64


def _bracket(values: np.ndarray, q: float) -> np.ndarray:
    """(low, high) of the finite |values| around their quantile ``q``: the order statistics ``BRACKET_FRACTION``
    of them (and ``BRACKET_PIXELS``) below and above it (where to seek a replicate's quantile first)."""
    v = np.sort(np.abs(values[np.isfinite(values)]))
    if not v.size:
        return np.array([np.inf, -np.inf])
    k = int((v.size - 1) * q)
    margin = int(BRACKET_FRACTION * v.size) + BRACKET_PIXELS
    return np.array([v[max(k - margin, 0)], v[min(k + margin + 1, v.size - 1)]], dtype=np.float64)


#: a replicate's value within this (relative) of the whole stack's Q90 counts half in the share at or below it:
#: a lattice value computed from the sums less a frame (deviations in float32, about 6e-8 relative) differs from
#: the same value computed from the frames kept
SHARE_TOLERANCE = 1e-6


def _left_out(stack: np.ndarray, stats: StackStats, reference_mm: float, thresholds: tuple[float, float]) -> np.ndarray:
    """(N, 2) per frame left out in turn: the share of the pixels of the (N, H, W) ``stack`` valid in it
    (``stats``) whose |mean - ``reference_mm``|, and whose sample std, lies at or below ``thresholds`` (the whole
    stack's Q90s), the replicates of the jackknife over the frames of the cumulative proportions at the Q90s. A
    replicate is the stack's sums less that frame's values: per pixel, the deviations from the stack mean in
    float32 (NaN counted out) and their squares, summed in float64 (no further pass over the stack)."""
    flat = np.ascontiguousarray(stack).reshape(stack.shape[0], -1)
    valid = stats.valid.reshape(-1)
    pixels = np.flatnonzero(valid)
    mean = stats.mean.reshape(-1)[pixels]
    totals = _frame_totals(flat, pixels, mean)
    at = np.array(thresholds, dtype=np.float64)
    return _left_out_shares(flat, pixels, mean, *totals, float(reference_mm), at,
                            SHARE_TOLERANCE * np.where(np.isfinite(at), np.abs(at), 0.0))


def _q90_uncertainty(values: np.ndarray, shares: np.ndarray) -> float:
    """Type A standard uncertainty of the Q90 of ``values`` from the replicates ``shares`` of the proportion at or
    below it, one per frame left out: the jackknife of the proportion (Efron & Tibshirani 1993, eq. 11.5) mapped
    through the quantile function (:func:`metrics.uncertainty.quantile_standard_error`)."""
    (share_u,) = delete_a_group_jackknife(shares[:, None])
    return quantile_standard_error(values, 0.9, share_u)


def precision_q90_uncertainty(stack: np.ndarray, stats: StackStats) -> float:
    """Type A standard uncertainty of the Q90 of the per-pixel standard deviation of the (N, H, W) ``stack``
    (statistics ``stats``) over its valid pixels, as for depth precision in :func:`depth_error_uncertainties`:
    the jackknife over the frames (Efron & Tibshirani 1993, eq. 11.5) of the share of the pixels at or below the
    Q90, mapped through the quantile function of the pixels' stds (Bahadur's representation, Woodruff 1952;
    :func:`metrics.uncertainty.quantile_standard_error`); NaN with fewer than two frames.

    Not the jackknife of the Q90 itself: on quantized output (the D455's z16, the AM-T100's whole steps) the
    per-pixel stds take a few lattice values, and the Q90 of every replicate can sit on the same one, a jackknife
    of 0 where the figure moves between lattice values from stack to stack. The share at or below the Q90 is a
    mean over the pixels and moves with every frame left out. The jackknife of a share over pixels is
    conservative (its expectation is at least the variance, Efron & Stein 1981), and more so where the pixels'
    noise is independent and alike.

    Examples
    --------
    Gaussian noise of sigma 1 on 2000 pixels over 20 frames: the Q90 of the per-pixel std (1.2) scatters by
    0.0062 between repetitions (a sample quantile's sqrt(q (1 - q) / P) / f(Q), f = 1.08 the density of the
    std of 20 frames at its 90 % point); the jackknife states about twice that.

    >>> from metrics.stack import stack_stats
    >>> stack = np.random.default_rng(5).normal(size=(20, 40, 50))
    >>> round(precision_q90_uncertainty(stack, stack_stats(stack)), 3)
    0.012
    """
    if stack.shape[0] < 2:
        return float("nan")
    std = stats.std[stats.valid]
    q90 = quantile_abs(std, 0.9)
    return _q90_uncertainty(std, _left_out(stack, stats, 0.0, (math.nan, q90))[:, 1])


def depth_error_uncertainties(stack: np.ndarray, stats: StackStats, reference_mm: float,
                               reference_u_mm: float = math.nan) -> DepthErrorUncertainties:
    """Type A uncertainties of the Q90 figures of :func:`depth_errors` of the (N, H, W) ``stack`` whose
    statistics are ``stats``, and their sensitivities to the reference ``reference_mm`` of standard uncertainty
    ``reference_u_mm`` (NaN: not known).

    * trueness and precision Q90 (quantiles over pixels of per-pixel stack statistics): the jackknife over the
      frames (Efron & Tibshirani 1993, eq. 11.5), each frame left out in turn, on the pixels valid in the stack,
      of the share of the pixels at or below the Q90, mapped through the quantile function of the pixels' values
      (:func:`precision_q90_uncertainty`, :func:`metrics.uncertainty.quantile_standard_error`);
    * accuracy Q90 (one frame): the experimental standard deviation of the figure over the frames, each taken
      as the single frame (GUM 4.2.2);
    * the sensitivity (its magnitude) of trueness and accuracy Q90 to the reference: over the reference's own
      distribution, normal with ``reference_u_mm`` (:func:`metrics.uncertainty.spread_sensitivity`, JCGM
      101:2008); by central differences of ``REFERENCE_STEP_MM`` (GUM 5.1.3) where that is not known. A
      quantile of |error| moves by less than the reference where the errors lie on both sides of 0 (near 0 for
      errors centred on it, up to 1 for errors of one sign). On quantized output (depth in whole millimetres)
      the quantile is a function of the reference with a kink wherever the quantile's pixel changes sides, and
      a central difference of 0.1 mm takes the slope of whichever part it lands on (0.04-0.35 on a simulated
      D455), where the reference's actual spread moves the figure by more.

    Examples
    --------
    Four frames, each the wall at 1000 mm plus -1.5, -0.5, 0.5, 1.5 mm at every pixel: every single frame's
    accuracy Q90 is one of 1.5, 0.5, 0.5, 1.5 (sample std 0.577).

    >>> from metrics.stack import stack_stats
    >>> stack = 1000.0 + np.array([-1.5, -0.5, 0.5, 1.5])[:, None, None] * np.ones((4, 3, 3))
    >>> round(depth_error_uncertainties(stack, stack_stats(stack), 1000.0).accuracy_q90_mm, 3)
    0.577
    """
    valid = stats.valid
    n = stack.shape[0]
    mean = stats.mean[valid]
    trueness = precision = float("nan")
    if n >= 2:
        errors, std = np.abs(mean - reference_mm), stats.std[valid]
        shares = _left_out(stack, stats, reference_mm, (quantile_abs(errors, 0.9), quantile_abs(std, 0.9)))
        trueness, precision = _q90_uncertainty(errors, shares[:, 0]), _q90_uncertainty(std, shares[:, 1])
    flat = np.ascontiguousarray(stack).reshape(n, -1)
    if flat.dtype not in (np.float32, np.float64):
        flat = flat.astype(np.float64)
    pixels = np.flatnonzero(valid.reshape(-1))
    per_frame = _frame_q90s(flat, pixels, flat.dtype.type(reference_mm), _bracket(flat[0, pixels] - reference_mm, 0.9),
                            0.9)
    per_frame = per_frame[np.isfinite(per_frame)]
    first = stack[0][valid]
    return DepthErrorUncertainties(
        trueness_q90_mm=trueness,
        accuracy_q90_mm=float(np.std(per_frame, ddof=1)) if per_frame.size >= 2 else float("nan"),
        precision_q90_mm=precision,
        trueness_reference_sensitivity=spread_sensitivity(lambda r: quantile_abs(mean - r, 0.9), reference_mm,
                                                          reference_u_mm, REFERENCE_STEP_MM),
        accuracy_reference_sensitivity=spread_sensitivity(lambda r: quantile_abs(first - r, 0.9), reference_mm,
                                                          reference_u_mm, REFERENCE_STEP_MM),
    )
