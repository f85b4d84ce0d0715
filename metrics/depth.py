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
    """Quantile ``q`` (0..1) of |values| over finite entries; NaN if there are none."""
    return median_q90_abs(values, (q,))[0]


def median_q90_abs(values: np.ndarray, qs: tuple[float, ...] = (0.5, 0.9)) -> tuple[float, ...]:
    """Quantiles of |values| over finite entries (one partition for all); NaN if none."""
    v = np.abs(values[np.isfinite(values)])
    if not v.size:
        return tuple(float("nan") for _ in qs)
    return tuple(float(x) for x in np.quantile(v, qs))


def center_pixel(shape: tuple[int, int]) -> tuple[int, int]:
    """Row, column of the centre pixel (H // 2, W // 2)."""
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
