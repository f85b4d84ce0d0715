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

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from metrics.stack import StackStats
from metrics.uncertainty import jackknife_standard_errors, sensitivity, standard_error_of_std


def quantile_abs(values: np.ndarray, q: float) -> float:
    """Quantile ``q`` (0..1) of |values| over finite entries; NaN if there are none.

    Examples
    --------
    >>> quantile_abs(np.array([-3.0, 1.0, 2.0, np.nan]), 0.5)  # median of 3, 1, 2
    2.0
    """
    return median_q90_abs(values, (q,))[0]


def median_q90_abs(values: np.ndarray, qs: tuple[float, ...] = (0.5, 0.9)) -> tuple[float, ...]:
    """Quantiles of |values| over finite entries (one partition for all); NaN if none.

    Examples
    --------
    |values| = 0, 1, ..., 10: median 5, 90 % quantile 9 (linear interpolation).

    >>> median_q90_abs(np.append(-np.arange(11.0), np.nan))
    (5.0, 9.0)
    """
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
    in them; and the sensitivity coefficients of trueness and accuracy Q90 to the reference distance (GUM
    5.1.3), which scale the reference's components (the caller's)."""

    trueness_q90_mm: float
    accuracy_q90_mm: float
    precision_q90_mm: float
    trueness_reference_sensitivity: float
    accuracy_reference_sensitivity: float


#: step (mm) of the reference distance for the numerical sensitivity coefficients: about the reference's
#: standard uncertainty (a laser meter's mean reading and offset)
REFERENCE_STEP_MM = 0.1


def _moments_without(stack: np.ndarray, stats: StackStats) -> Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]]:
    """Per-pixel mean and sample std, over the pixels valid in the stack, of the frames where a boolean mask over
    the frames is true (the jackknife's replicates). With one frame left out, the replicate is the stack's sums
    less that frame's values (no pass over the stack); any other mask takes one matrix product."""
    valid = stats.valid
    mean = stats.mean[valid]
    deviation = (stack[:, valid] - mean).astype(np.float32)
    seen = np.isfinite(deviation).astype(np.float32)
    deviation = np.nan_to_num(deviation, nan=0.0)
    squared = deviation * deviation
    totals = (seen.sum(axis=0, dtype=np.float64), deviation.sum(axis=0, dtype=np.float64),
              squared.sum(axis=0, dtype=np.float64))

    def moments(kept: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        left_out = np.flatnonzero(~kept)
        if left_out.size == 1:
            i = int(left_out[0])
            c, s, ss = totals[0] - seen[i], totals[1] - deviation[i], totals[2] - squared[i]
        else:
            w = kept.astype(np.float32)
            c, s, ss = w @ seen, w @ deviation, w @ squared
        with np.errstate(divide="ignore", invalid="ignore"):
            shift = s / c
            var = (ss - s * shift) / (c - 1)
        ok = c >= 2
        return np.where(ok, mean + shift, np.nan), np.where(ok, np.sqrt(np.maximum(var, 0.0)), np.nan)

    return moments


def precision_q90_uncertainty(stack: np.ndarray, stats: StackStats) -> float:
    """Type A standard uncertainty of the Q90 of the per-pixel standard deviation of the (N, H, W) ``stack``
    (statistics ``stats``) over its valid pixels: the jackknife over the frames (Efron & Tibshirani 1993,
    eq. 11.5), as for depth precision in :func:`depth_error_uncertainties`; NaN with fewer than two frames.

    The jackknife of a quantile over pixels is conservative where the pixels' noise is independent and alike:
    each frame left out moves some pixels across the quantile, which adds to the replicates' spread.

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
    n = stack.shape[0]
    if n < 2:
        return float("nan")
    moments = _moments_without(stack, stats)
    return jackknife_standard_errors(lambda kept: (quantile_abs(moments(kept)[1], 0.9),), n)[0]


def depth_error_uncertainties(stack: np.ndarray, stats: StackStats, reference_mm: float) -> DepthErrorUncertainties:
    """Type A uncertainties of the Q90 figures of :func:`depth_errors` of the (N, H, W) ``stack`` whose
    statistics are ``stats``.

    * trueness and precision Q90 (quantiles over pixels of per-pixel stack statistics): the jackknife standard
      error over the frames (Efron & Tibshirani 1993, eq. 11.5), each frame left out in turn, on the pixels
      valid in the stack;
    * accuracy Q90 (one frame): the experimental standard deviation of the figure over the frames, each taken
      as the single frame (GUM 4.2.2);
    * the sensitivity of trueness and accuracy Q90 to the reference: by central differences of
      ``REFERENCE_STEP_MM`` (GUM 5.1.3). A quantile of |error| moves by less than the reference where the
      errors lie on both sides of 0 (near 0 for errors centred on it, up to 1 for errors of one sign).

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
    moments = _moments_without(stack, stats)

    def q90s(kept: np.ndarray) -> tuple[float, float]:
        """Trueness and precision Q90 of the frames where ``kept`` is true."""
        mean_k, std_k = moments(kept)
        return quantile_abs(mean_k - reference_mm, 0.9), quantile_abs(std_k, 0.9)

    trueness, precision = jackknife_standard_errors(q90s, n) if n >= 2 else (float("nan"), float("nan"))
    per_frame = np.array([quantile_abs(stack[k][valid] - reference_mm, 0.9) for k in range(n)])
    per_frame = per_frame[np.isfinite(per_frame)]
    first = stack[0][valid]
    return DepthErrorUncertainties(
        trueness_q90_mm=trueness,
        accuracy_q90_mm=float(np.std(per_frame, ddof=1)) if per_frame.size >= 2 else float("nan"),
        precision_q90_mm=precision,
        trueness_reference_sensitivity=sensitivity(lambda r: quantile_abs(mean - r, 0.9), reference_mm,
                                                   REFERENCE_STEP_MM),
        accuracy_reference_sensitivity=sensitivity(lambda r: quantile_abs(first - r, 0.9), reference_mm,
                                                   REFERENCE_STEP_MM),
    )
