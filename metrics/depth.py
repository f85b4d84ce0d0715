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

from dataclasses import dataclass

import numpy as np

from metrics.stack import StackStats


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
