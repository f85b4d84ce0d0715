"""Known answers: a flat target at a known distance seen with known Gaussian noise."""

import math

import numpy as np
import pytest
from scipy.stats import chi2, norm

from metrics.depth import center_pixel, depth_errors, quantile_abs
from metrics.stack import stack_stats

N, H, W = 100, 90, 120
SIGMA = 1.5
REF = 2000.0


@pytest.fixture(scope="module")
def noisy_plane():
    rng = np.random.default_rng(42)
    return (REF + SIGMA * rng.standard_normal((N, H, W))).astype(np.float32)


def test_precision_is_q90_of_per_pixel_std(noisy_plane):
    e = depth_errors(stack_stats(noisy_plane), noisy_plane[0], REF)
    assert e.precision_q90_mm == pytest.approx(SIGMA * math.sqrt(chi2.ppf(0.9, N - 1) / (N - 1)), rel=0.01)
    assert e.precision_median_mm == pytest.approx(SIGMA * math.sqrt(chi2.ppf(0.5, N - 1) / (N - 1)), rel=0.01)


def test_trueness_of_unbiased_plane_is_mean_noise(noisy_plane):
    """|mean - ref| is half-normal with scale sigma/sqrt(N)."""
    e = depth_errors(stack_stats(noisy_plane), noisy_plane[0], REF)
    scale = SIGMA / math.sqrt(N)
    assert e.trueness_q90_mm == pytest.approx(norm.ppf(0.95) * scale, rel=0.04)
    assert e.trueness_median_mm == pytest.approx(norm.ppf(0.75) * scale, rel=0.04)
    assert abs(e.trueness_signed_median_mm) < 3 * scale / math.sqrt(H * W) * 10


def test_accuracy_is_single_frame_error(noisy_plane):
    e = depth_errors(stack_stats(noisy_plane), noisy_plane[0], REF)
    assert e.accuracy_q90_mm == pytest.approx(norm.ppf(0.95) * SIGMA, rel=0.04)


def test_bias_shows_in_trueness_not_precision(noisy_plane):
    biased = noisy_plane + 3.0
    e = depth_errors(stack_stats(biased), biased[0], REF)
    assert e.trueness_signed_median_mm == pytest.approx(3.0, abs=0.02)
    assert e.precision_q90_mm == pytest.approx(SIGMA * math.sqrt(chi2.ppf(0.9, N - 1) / (N - 1)), rel=0.01)


def test_invalid_pixels_counted_and_excluded():
    stack = np.full((10, 10, 10), REF, np.float32)
    stack[:, :2, :] = np.nan
    stack[:, 5, 5] = REF + 50.0
    e = depth_errors(stack_stats(stack), stack[0], REF)
    assert e.invalid_fraction == pytest.approx(0.2)
    assert e.trueness_q90_mm == 0.0  # one outlier in 80 valid pixels stays above Q90


def test_center_pixel_repeatability():
    stack = np.full((4, 5, 6), REF, np.float32)
    r, c = center_pixel((5, 6))
    stack[:, r, c] = [1, 2, 3, 4]
    e = depth_errors(stack_stats(stack), stack[0], REF)
    assert e.repeatability_center_mm == pytest.approx(np.std([1, 2, 3, 4], ddof=1))


def test_quantile_abs_ignores_nan():
    assert quantile_abs(np.array([np.nan, -1.0, 2.0, -3.0]), 1.0) == 3.0
    assert math.isnan(quantile_abs(np.array([np.nan]), 0.9))


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_the_compiled_quantile_is_numpys_bit_for_bit_wherever_the_bracket_lies(dtype):
    """The jackknife's quantiles (metrics.depth._linear_quantile) equal np.quantile's exactly, whether the sought
    ranks fall among the bracketed values or the quantile falls back to all of them; ties included."""
    from metrics.depth import _linear_quantile

    rng = np.random.default_rng(7)
    for trial in range(600):
        n = int(rng.integers(1, 200))
        values = np.abs(rng.normal(size=n)).astype(dtype)
        if trial % 3 == 0:
            values = np.round(values * 3).astype(dtype)
        q = (0.9, 0.5, 0.0, 1.0, 0.99)[trial % 5]
        ordered = np.sort(values)
        low, high = sorted(ordered[rng.integers(0, n, 2)])
        inside = values[(values >= low) & (values <= high)]
        got = _linear_quantile(values.copy(), n, int(np.sum(values < low)), inside.copy(), inside.size, q)
        assert float(got).hex() == float(np.quantile(values, (q,))[0]).hex()
