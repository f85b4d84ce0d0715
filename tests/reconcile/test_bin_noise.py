"""The compiled noise statistics per bin give the numbers of the array formulation bit for bit."""

from __future__ import annotations

import numpy as np
import pytest

from labctl.reconcile.bin_noise import bin_noise


def _array_formulation(z: np.ndarray, bin_px: int) -> tuple[np.ndarray, ...]:
    """The statistics with numpy arrays over every bin's pixels (m, mean variance, between, valid rate)."""
    n, height, width = z.shape
    h, w = height // bin_px, width // bin_px
    v = z[:, :h * bin_px, :w * bin_px].astype(float).reshape(n, h, bin_px, w, bin_px)
    pixels = np.moveaxis(v, -3, -2).reshape(n, h, w, bin_px * bin_px)
    finite = np.isfinite(pixels)
    full = finite.all(axis=0)
    m = full.sum(axis=-1)
    deviation = np.where(full, pixels - np.where(full, pixels, 0.0).mean(axis=0), 0.0)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean_var = ((deviation**2).sum(axis=0) / max(n - 1, 1)).sum(axis=-1) / m
        between = ((deviation.sum(axis=-1) / m) ** 2).sum(axis=0) / max(n - 1, 1)
    return m, mean_var, between, finite.mean(axis=(0, 3))


@pytest.mark.parametrize("bin_px", [1, 3, 4, 12, 16, 24])
def test_bin_noise_equals_the_array_formulation_bit_for_bit(bin_px: int) -> None:
    rng = np.random.default_rng(bin_px)
    z = (1500.0 + rng.normal(0.0, 2.0, (10, 50, 75))).astype(np.float32)
    z[rng.random(z.shape) < 0.05] = np.nan  # scattered invalid pixel-frames
    z[:, :bin_px, :bin_px] = np.nan  # a bin with no pixel valid in every frame
    for got, expected in zip(bin_noise(z, bin_px), _array_formulation(z, bin_px), strict=True):
        assert got.shape == expected.shape
        np.testing.assert_array_equal(got, expected)
