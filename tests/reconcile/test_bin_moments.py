"""The compiled binned stack statistics give the numbers of the per-pixel statistics binned by numpy bit for bit."""

from __future__ import annotations

import numpy as np
import pytest

from labctl.reconcile.bin_moments import binned_stack_stats
from labctl.reconcile.observe import bin_mean
from metrics.stack import stack_stats


def _array_formulation(stack: np.ndarray, bin_px: int) -> tuple[np.ndarray, ...]:
    """``stack_stats`` per pixel, then ``bin_mean`` of the valid means and of the variances of the mean."""
    stats = stack_stats(stack)
    mean, count = bin_mean(np.where(stats.valid, stats.mean, np.nan), bin_px)
    variance, _ = bin_mean(np.where(stats.valid, stats.std**2 / np.maximum(stats.count, 1), np.nan), bin_px)
    return mean, count, variance


@pytest.mark.parametrize("dtype", [np.float32, np.float64, np.int16])
@pytest.mark.parametrize("frames", [1, 2, 3, 10])
@pytest.mark.parametrize("bin_px", [1, 3, 4, 12, 16, 24])
def test_binned_stack_stats_equal_the_array_formulation_bit_for_bit(bin_px: int, frames: int, dtype: type) -> None:
    rng = np.random.default_rng(100 * bin_px + frames)
    stack = (1500.0 + rng.normal(0.0, 2.0, (frames, 50, 75))).astype(np.float32)
    stack[rng.random(stack.shape) < 0.3] = np.nan  # scattered invalid pixel-frames: some pixels fail the half rule
    stack[:, :bin_px, :bin_px] = np.nan  # a bin with no valid pixel
    stack[:, -1, :] = np.inf  # a row of valid but infinite pixels (in the last row of bins when 50 is a multiple)
    stack = stack.astype(dtype) if dtype is not np.int16 else np.nan_to_num(stack, posinf=0.0).astype(dtype)
    for got, expected in zip(binned_stack_stats(stack, bin_px), _array_formulation(stack, bin_px), strict=True):
        assert got.dtype == expected.dtype and got.shape == expected.shape
        np.testing.assert_array_equal(got, expected)
