"""A stack's per-pixel statistics averaged over pixel bins, in one compiled pass (labctl/reconcile/observe.py).

Per ``bin_px`` x ``bin_px`` bin of an (n, H, W) stack (cropped to whole bins,
NaN = invalid): the mean of the finite per-pixel stack means, their count, and
the mean of the finite per-pixel variances of the stack mean (std^2 / count),
where the per-pixel statistics are :func:`metrics.stack.stack_stats`' (its
moments, :func:`metrics.stack.row_moments`, and its half-valid rule). The pass
gives the numbers of ``stack_stats`` followed by ``observe.bin_mean`` bit for
bit, without the full-resolution arrays in between: each bin's sum keeps
numpy's order for ``sum(axis=(1, 3))`` of the (h, bin_px, w, bin_px) view, the
bin's rows one after the other, each row's ``bin_px`` values by numpy's
pairwise summation (``bin_noise._pairwise_sum``).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from labctl.reconcile.bin_noise import STACK_DEPTH, _pairwise_sum
from metrics.stack import row_moments


@njit(parallel=True, cache=True, nogil=True, error_model="numpy")
def _binned_moments(stack: np.ndarray, bin_px: int) -> tuple[np.ndarray, np.ndarray,
                                                             np.ndarray]:  # pragma: no cover - compiled
    """Per bin: the mean of the finite per-pixel means (NaN where there is none), their count, and the mean of the
    finite per-pixel variances of the mean. A row of bins at a time: its pixels' moments row by row, then each
    bin's sums."""
    n, height, width = stack.shape
    h, w = height // bin_px, width // bin_px
    mean = np.empty((h, w))
    count = np.zeros((h, w), np.int64)
    var = np.empty((h, w))
    least = min(2, n)
    for by in prange(h):
        pixel_count = np.empty((bin_px, width), np.int64)
        pixel_mean = np.empty((bin_px, width))
        pixel_m2 = np.empty((bin_px, width))
        means = np.zeros((bin_px, width))  # the finite per-pixel means, 0 elsewhere (numpy's np.where(ok, v, 0.0))
        variances = np.zeros((bin_px, width))
        finite_mean = np.zeros((bin_px, width), np.bool_)
        finite_var = np.zeros((bin_px, width), np.bool_)
        nodes = np.empty((STACK_DEPTH, 3), np.int64)
        left = np.empty(STACK_DEPTH)
        for dy in range(bin_px):
            row_moments(stack, by * bin_px + dy, pixel_count[dy], pixel_mean[dy], pixel_m2[dy])
            for x in range(w * bin_px):
                c = pixel_count[dy, x]
                valid = 2 * c >= n and c >= least
                m = pixel_mean[dy, x] if valid else np.nan
                std = math.sqrt(pixel_m2[dy, x] / np.float64(c - 1)) if valid else np.nan
                v = std * std / np.float64(max(c, 1)) if valid else np.nan
                finite_mean[dy, x] = math.isfinite(m)
                finite_var[dy, x] = math.isfinite(v)
                means[dy, x] = m if finite_mean[dy, x] else 0.0
                variances[dy, x] = v if finite_var[dy, x] else 0.0
        for bx in range(w):
            mean_sum = 0.0
            var_sum = 0.0
            mean_count = 0
            var_count = 0
            for dy in range(bin_px):
                mean_sum += _pairwise_sum(means[dy], bx * bin_px, bin_px, nodes, left)
                var_sum += _pairwise_sum(variances[dy], bx * bin_px, bin_px, nodes, left)
                for dx in range(bin_px):
                    mean_count += 1 if finite_mean[dy, bx * bin_px + dx] else 0
                    var_count += 1 if finite_var[dy, bx * bin_px + dx] else 0
            count[by, bx] = mean_count
            mean[by, bx] = mean_sum / mean_count if mean_count > 0 else np.nan
            var[by, bx] = var_sum / var_count if var_count > 0 else np.nan
    return mean, count, var


def binned_stack_stats(stack: np.ndarray, bin_px: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per ``bin_px`` x ``bin_px`` bin of an (n, H, W) stack (NaN = invalid; cropped to whole bins): the mean of
    the valid pixels' stack means (NaN where no pixel is valid), their count, and the mean of their variances of
    the stack mean, std^2 / count (:func:`metrics.stack.stack_stats`' per-pixel statistics and validity).

    Examples
    --------
    One 2 x 2 bin of three frames: a pixel seen as 1, 2, 3 (mean 2, variance of the mean 1 / 3), three valid in
    a single frame (invalid).

    >>> stack = np.full((3, 2, 2), np.nan)
    >>> stack[:, 0, 0] = [1.0, 2.0, 3.0]
    >>> stack[2] = [[3.0, 5.0], [5.0, 5.0]]
    >>> [a.tolist() for a in binned_stack_stats(stack, 2)]
    [[[2.0]], [[1]], [[0.3333333333333333]]]
    """
    if stack.dtype not in (np.float32, np.float64):
        stack = stack.astype(np.float32)
    return _binned_moments(np.ascontiguousarray(stack), bin_px)
