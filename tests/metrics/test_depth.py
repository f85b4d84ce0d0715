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
def test_the_selection_leaves_the_kth_smallest_at_k_with_none_smaller_after_and_none_larger_before(dtype):
    """metrics.depth._select against a full sort: any size, heavy ties (few distinct values), sorted and reversed
    input, every k of the small arrays."""
    from metrics.depth import _select

    rng = np.random.default_rng(5)
    cases = [rng.normal(size=int(rng.integers(1, 300))) for _ in range(60)]
    cases += [rng.integers(0, 3, size=int(rng.integers(1, 300))).astype(float) for _ in range(60)]
    cases += [np.arange(50.0), np.arange(50.0)[::-1], np.zeros(17)]
    for values in cases:
        values = values.astype(dtype)
        ordered = np.sort(values)
        for k in (range(values.size) if values.size <= 50 else rng.integers(0, values.size, 10)):
            a = values.copy()
            assert _select(a, int(k)) == ordered[k]
            assert a[k] == ordered[k] and (a[:k] <= a[k]).all() and (a[k + 1:] >= a[k]).all()
            np.testing.assert_array_equal(np.sort(a), ordered)  # reordered, nothing lost


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


def test_a_quantile_of_normal_values_moves_by_the_proportions_uncertainty_over_the_density():
    """Bahadur's representation: u(Q) = u(F) / f(Q); values at the normal's quantiles (k + 1/2) / n, so that the
    sample's density is the normal's."""
    from metrics.uncertainty import quantile_standard_error

    n = 100_000
    values = norm.ppf((np.arange(n) + 0.5) / n)
    for u_share in (0.001, 0.003):
        expected = u_share / norm.pdf(norm.ppf(0.9))
        assert quantile_standard_error(values, 0.9, u_share) == pytest.approx(expected, rel=0.01)


def test_a_quantile_on_the_boundary_of_two_lattice_values_moves_between_them():
    """90 % of the values at 0 and 10 % at 2: the Q90 sits where the share at 0 ends, and a proportion known only
    to u_F > 0 puts it on either value with probability 1/2 each: standard deviation 2 / 2 = 1. The jackknife of
    the Q90 itself (every replica on 0 or every one on 2) would state 0."""
    from metrics.uncertainty import quantile_standard_error

    values = np.repeat([0.0, 2.0], [9000, 1000])
    assert quantile_standard_error(values, 0.9, 0.003) == pytest.approx(1.0, rel=0.01)
    assert math.isnan(quantile_standard_error(values, 0.9, math.nan))


@pytest.mark.parametrize("sigma", [0.5, 0.8])
def test_the_q90_uncertainties_of_a_quantized_stack_cover_their_spread_over_repetitions(sigma):
    """Known answer by repetition: a wall at 1000.3 mm with Gaussian noise of ``sigma`` mm, output in whole
    millimetres (the AM-T100's, the D455's z16), 8 frames of 40 x 50 pixels, drawn ``SEEDS`` times. The per-pixel
    stds and means sit on a lattice and the precision and trueness Q90 take two or three values over the
    repetitions. Each repetition's U = 2 u must cover its deviation from the mean over the repetitions in at least
    90 of 100 (a correct 95 % interval falls below that with probability 3 %), u > 0 in every one, and the mean u
    within a factor 2 of the standard deviation over the repetitions."""
    from metrics.depth import depth_error_uncertainties

    seeds = 100
    rows = []
    for seed in range(seeds):
        z = np.round(1000.3 + sigma * np.random.default_rng(seed).standard_normal((8, 40, 50)))
        stats = stack_stats(z)
        errors, u = depth_errors(stats, z[0], 1000.0), depth_error_uncertainties(z, stats, 1000.0)
        rows.append((errors.precision_q90_mm, u.precision_q90_mm, errors.trueness_q90_mm, u.trueness_q90_mm))
    rows = np.array(rows)
    for name, value, u in (("precision", rows[:, 0], rows[:, 1]), ("trueness", rows[:, 2], rows[:, 3])):
        spread = float(np.std(value, ddof=1))
        covered = int(np.sum(np.abs(value - value.mean()) <= 2.0 * u))
        assert np.unique(value).size <= 4, name  # a lattice figure
        assert (u > 0).all(), name
        assert covered >= 90, f"{name}: U covers {covered} of {seeds} (spread {spread:.4g}, u {u.mean():.4g})"
        assert 0.5 <= u.mean() / spread <= 2.0, f"{name}: mean u {u.mean():.4g}, spread {spread:.4g}"


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_median_and_q90_are_numpys_bit_for_bit(dtype):
    """median_q90_abs (selected among the values its sample brackets, metrics.depth._abs_quantiles) equals
    np.quantile of the finite |values| exactly: any size, ties, NaN and infinities, and values whose evenly spaced
    sample misleads the bracket (every sampled value 0, the others not)."""
    from metrics.depth import SAMPLE, median_q90_abs

    rng = np.random.default_rng(11)
    for trial in range(120):
        n = int(rng.integers(0, 50)) if trial % 4 == 0 else int(rng.integers(2 * SAMPLE, 40 * SAMPLE))
        values = rng.normal(size=n).astype(dtype)
        if trial % 5 == 1:
            values = np.round(values * 3).astype(dtype)
        if trial % 5 == 2:
            values[rng.random(n) < 0.3] = np.nan
            values[rng.random(n) < 0.01] = np.inf
        if trial % 5 == 3:
            values[:: max(1, n // SAMPLE)] = 0
        qs = ((0.5, 0.9), (0.9,), (0.0, 1.0, 0.37))[trial % 3]
        finite = np.abs(values[np.isfinite(values)])
        expected = np.quantile(finite, qs) if finite.size else np.full(len(qs), np.nan)
        got = median_q90_abs(values, qs)
        assert [float(g).hex() for g in got] == [float(e).hex() for e in expected]
