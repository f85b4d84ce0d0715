import math
import warnings

import numpy as np
import pytest
from scipy.stats import chi2

from metrics.stack import RoiMean, central_roi, leave_group_out_means, stack_stats
from metrics.uncertainty import contiguous_groups


def test_mean_and_std_match_numpy_on_complete_stack():
    rng = np.random.default_rng(0)
    stack = rng.normal(1000.0, 3.0, (50, 20, 70)).astype(np.float32)
    stats = stack_stats(stack)
    np.testing.assert_allclose(stats.mean, stack.astype(float).mean(0), rtol=0, atol=1e-9)
    np.testing.assert_allclose(stats.std, stack.astype(float).std(0, ddof=1), rtol=1e-10)
    assert stats.valid.all()


def _sequential_moments(values: list[float]) -> tuple[int, float, float]:
    """Valid count, mean and sum of squared deviations of one pixel's frames as stack_stats defines them (shifted by
    the first valid value, float64 sums taken frame by frame in order), in plain Python floats."""
    valid = [v for v in values if not math.isnan(v)]
    if not valid:
        return 0, math.nan, math.nan
    s = ss = 0.0
    for v in valid:
        d = v - valid[0]
        s += d
        ss += d * d
    return len(valid), valid[0] + s / len(valid), max(ss - s * s / len(valid), 0.0)


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("frames", range(1, 10))
def test_moments_match_numpy_and_frame_by_frame_sums_for_any_number_of_frames(frames, dtype):
    """Every remainder of the kernel's four frames at a time, with invalid frames scattered and pixels valid in
    none: counts and means as numpy's (nanmean, nanstd), and bit for bit the frame-by-frame sums."""
    rng = np.random.default_rng(frames)
    stack = rng.normal(1500.0, 2.0, (frames, 3, 11)).astype(dtype)
    stack[rng.random(stack.shape) < 0.3] = np.nan
    stack[:, 2, 10] = np.nan
    stats = stack_stats(stack)
    values = stack.astype(float)
    count = np.isfinite(values).sum(axis=0)
    np.testing.assert_array_equal(stats.count, count)
    valid = (2 * count >= frames) & (count >= min(2, frames))
    with np.errstate(invalid="ignore", divide="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        mean, std = np.nanmean(values, axis=0), np.nanstd(values, axis=0, ddof=1)
    np.testing.assert_allclose(stats.mean[valid], mean[valid], rtol=1e-13)
    np.testing.assert_allclose(stats.std[valid], std[valid], rtol=1e-9, atol=1e-12)
    assert np.isnan(stats.mean[~valid]).all() and np.isnan(stats.std[~valid]).all()
    for r in range(3):
        for c in range(11):
            n, m, m2 = _sequential_moments(values[:, r, c].tolist())
            if valid[r, c]:
                assert stats.mean[r, c] == m
                assert stats.std[r, c] == math.sqrt(m2 / (n - 1)) if n > 1 else math.isnan(stats.std[r, c])


def test_invalid_frames_are_ignored_per_pixel():
    stack = np.full((10, 2, 2), 5.0, np.float32)
    stack[:, 0, 0] = np.arange(10)
    stack[:3, 0, 0] = np.nan  # valid in 7 of 10 frames
    stack[:6, 1, 1] = np.nan  # valid in 4 of 10: fewer than half -> invalid
    stats = stack_stats(stack)
    assert stats.count[0, 0] == 7
    assert stats.mean[0, 0] == pytest.approx(np.mean(np.arange(3, 10)))
    assert stats.std[0, 0] == pytest.approx(np.std(np.arange(3, 10), ddof=1))
    assert not stats.valid[1, 1] and math.isnan(stats.mean[1, 1])
    assert stats.valid[0, 1]


def test_exactly_half_valid_counts_as_valid():
    stack = np.ones((10, 1, 1), np.float32)
    stack[:5] = np.nan
    assert stack_stats(stack).valid[0, 0]


def test_sample_std_distribution_matches_chi_square():
    """Per-pixel sample std of Gaussian noise: s^2 (n-1)/sigma^2 ~ chi2(n-1)."""
    rng = np.random.default_rng(3)
    n, sigma = 20, 2.0
    stats = stack_stats(rng.normal(0, sigma, (n, 200, 200)).astype(np.float32))
    q90 = np.quantile(stats.std, 0.9)
    assert q90 == pytest.approx(sigma * math.sqrt(chi2.ppf(0.9, n - 1) / (n - 1)), rel=0.01)


def test_rejects_non_stack():
    with pytest.raises(ValueError, match="N, H, W"):
        stack_stats(np.zeros((3, 3)))


def test_roi_mean_streams_like_stack_mean():
    rng = np.random.default_rng(1)
    stack = rng.normal(2000, 1, (9, 30, 40)).astype(np.float32)
    stack[0, 15, 20] = np.nan
    roi = central_roi(30, 40, 0.25)
    acc = RoiMean(roi, 9)
    for frame in stack:
        acc.add(frame)
    expected = np.mean(stack_stats(stack[:, roi[0], roi[1]]).mean)
    assert acc.value() == pytest.approx(expected, abs=1e-9)


def test_central_roi_is_centred():
    rows, cols = central_roi(480, 640, 0.1)
    assert (rows.start, rows.stop, cols.start, cols.stop) == (216, 264, 288, 352)


def test_tiny_noise_far_away_does_not_cancel():
    """float32 input, 4 m away, 10 um noise: the one-pass kernel must keep full precision."""
    rng = np.random.default_rng(9)
    stack = (4000.0 + 0.01 * rng.standard_normal((100, 8, 9))).astype(np.float32)
    stack[0, 0, 0] = np.nan  # first frame invalid: the kernel shifts by the first valid one
    stats = stack_stats(stack)
    ref = stack.astype(np.float64)
    np.testing.assert_allclose(stats.std[1:], ref[:, 1:].std(0, ddof=1), rtol=1e-6)
    np.testing.assert_allclose(stats.std[0, 0], np.nanstd(ref[:, 0, 0], ddof=1), rtol=1e-6)
    np.testing.assert_allclose(stats.mean[0, 0], np.nanmean(ref[:, 0, 0]), rtol=1e-12)


def test_integer_stacks_are_accepted():
    stats = stack_stats(np.arange(24, dtype=np.uint16).reshape(4, 2, 3))
    np.testing.assert_allclose(stats.mean, np.arange(24).reshape(4, 2, 3).mean(0))


def test_leave_group_out_means_are_the_means_of_the_frames_kept():
    """Each replicate equals stack_stats of the stack without that group, invalid pixels included."""
    rng = np.random.default_rng(5)
    stack = rng.normal(1000.0, 3.0, (23, 6, 7)).astype(np.float32)
    stack[rng.random(stack.shape) < 0.3] = np.nan
    stack[:, 0, 0] = np.nan
    stack[:12, 1, 1] = np.nan  # valid only in the last 11 frames
    groups = contiguous_groups(23, 10)
    left_out = leave_group_out_means(stack, groups)
    assert left_out.shape == (10, 6, 7)
    for g, group in enumerate(groups):
        expected = stack_stats(np.delete(stack, list(group), axis=0)).mean
        np.testing.assert_allclose(left_out[g], expected, rtol=0, atol=1e-9, equal_nan=True)


def test_leave_group_out_means_reject_groups_that_do_not_cover_the_stack():
    with pytest.raises(ValueError, match="contiguous"):
        leave_group_out_means(np.zeros((4, 1, 1)), [range(0, 2), range(3, 4)])
