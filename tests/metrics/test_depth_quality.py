"""Known answers for the vendor depth-quality figures: analytic planes with known noise, holes and offsets."""

import math

import numpy as np
import pytest
from scipy.stats import norm

from metrics.depth_quality import (
    DQT_FRAMES,
    centre_window,
    dqt_frame,
    dqt_roi,
    fill_rate_pct,
    fit_plane,
    spatial_precision_mm,
    temporal_precision_mm,
    trim_by_z,
    vendor_figures,
)

H, W = 240, 320


def rays(fov_h_deg: float = 60.0, height: int = H, width: int = W) -> tuple[np.ndarray, np.ndarray, float]:
    """Pinhole ray slopes tx, ty (H, W) and the focal length in pixels."""
    f = (width / 2) / math.tan(math.radians(fov_h_deg) / 2)
    tx = (np.arange(width) - (width - 1) / 2) / f
    ty = (np.arange(height) - (height - 1) / 2) / f
    return np.broadcast_to(tx, (height, width)), np.broadcast_to(ty[:, None], (height, width)), f


def plane_points(distance: float, tilt_deg: float = 0.0, fov_h_deg: float = 60.0):
    """x, y, z of the plane z = distance + tan(tilt) x seen along the rays."""
    tx, ty, f = rays(fov_h_deg)
    z = distance / (1.0 - math.tan(math.radians(tilt_deg)) * tx)
    return tx * z, ty * z, z, f


def trimmed_sigma(sigma: float) -> float:
    """Standard deviation of a normal distribution with its lowest and highest 0.5 % removed."""
    c = norm.ppf(0.995)
    return sigma * math.sqrt(1.0 - 2.0 * c * norm.pdf(c) / 0.99)


def test_dqt_roi_is_the_centred_40_percent():
    assert dqt_roi(480, 640) == (slice(144, 336), slice(192, 448))
    assert centre_window(480, 640) == (slice(220, 260), slice(300, 340))


def test_fill_rate_counts_holes():
    z = np.full((100, 80), 2000.0)
    z[:, ::8] = np.nan  # one column in eight
    z[0, 1] = 0.0  # librealsense's "no depth" value
    assert fill_rate_pct(z) == pytest.approx(100.0 * (7 / 8 - 1 / 8000))


def test_tilted_noise_free_plane_is_fitted_exactly():
    x, y, z, _ = plane_points(2000.0, tilt_deg=20.0)
    result = dqt_frame(x, y, z, ground_truth_mm=1990.0)
    assert result.plane_fit_rms_mm == pytest.approx(0.0, abs=1e-6)
    assert result.fill_rate_pct == 100.0
    # the plane meets the optical axis at 2000 mm, 10 mm beyond the ground truth
    assert result.z_accuracy_pct == pytest.approx(100 * 10 / 1990, abs=1e-6)
    assert result.distance_mm == pytest.approx(2000.0 * math.cos(math.radians(20.0)), rel=1e-9)
    plane = fit_plane(np.stack([x.ravel(), y.ravel(), z.ravel()], -1))
    assert math.degrees(math.acos(plane.normal[2])) == pytest.approx(20.0, abs=1e-6)


def test_plane_fit_rms_of_a_noisy_plane_with_holes():
    """Gaussian z noise sigma on a wall facing the camera: the 0.5 % trimming at each end removes the
    tails, RMS = sigma of the truncated normal; holes change the fill rate only."""
    rng = np.random.default_rng(1)
    x, y, z, _ = plane_points(1500.0)
    sigma = 3.0
    z = z + sigma * rng.standard_normal(z.shape)
    z[rng.random(z.shape) < 0.2] = np.nan
    result = dqt_frame(x, y, z, ground_truth_mm=1500.0)
    assert result.fill_rate_pct == pytest.approx(80.0, abs=0.5)
    assert result.plane_fit_rms_mm == pytest.approx(trimmed_sigma(sigma), rel=0.01)
    assert result.plane_fit_rms_pct == pytest.approx(100 * trimmed_sigma(sigma) / 1500.0, rel=0.01)
    assert abs(result.z_accuracy_pct) < 100 * 4 * sigma / math.sqrt(0.8 * H * W) / 1500.0


def test_z_accuracy_of_a_known_offset():
    """A wall measured 12 mm too far at 2400 mm: +0.5 %; too near: -0.5 %."""
    rng = np.random.default_rng(2)
    for offset in (12.0, -12.0):
        x, y, z, _ = plane_points(2400.0 + offset, tilt_deg=5.0)
        z = z + 1.0 * rng.standard_normal(z.shape)
        assert dqt_frame(x, y, z, 2400.0).z_accuracy_pct == pytest.approx(100 * offset / 2400.0, abs=0.005)


def test_trimming_removes_half_a_percent_of_gross_outliers_at_each_end():
    rng = np.random.default_rng(3)
    x, y, z, _ = plane_points(2000.0)
    z = z + 2.0 * rng.standard_normal(z.shape)
    n_out = z.size // 200
    idx = rng.choice(z.size, 2 * n_out, replace=False)
    flat = z.reshape(-1).copy()
    flat[idx[:n_out]] += 400.0
    flat[idx[n_out:]] -= 400.0
    points = np.stack([x.ravel(), y.ravel(), flat], -1)
    kept = trim_by_z(points)
    assert len(kept) == z.size - 2 * n_out
    assert np.abs(kept[:, 2] - 2000.0).max() < 50.0


def test_subpixel_rms_from_a_known_disparity_noise():
    """Stereo wall: disparity d = f B / Z + N(0, s); the points along the rays at z = f B / d. Narrow FOV, so
    that ranges equal depths to 0.2 %: subpixel RMS = s of the trimmed normal."""
    rng = np.random.default_rng(4)
    tx, ty, f = rays(fov_h_deg=8.0)
    baseline, distance, s = 95.0, 2000.0, 0.08
    d = f * baseline / distance + s * rng.standard_normal(tx.shape)
    z = f * baseline / d
    result = dqt_frame(tx * z, ty * z, z, distance, focal_px=f, baseline_mm=baseline)
    assert result.subpixel_rms_px == pytest.approx(trimmed_sigma(s), rel=0.02)
    assert math.isnan(dqt_frame(tx * z, ty * z, z, distance).subpixel_rms_px)


def test_spatial_precision_is_the_rms_about_the_plane():
    rng = np.random.default_rng(5)
    x, y, z, _ = plane_points(1000.0, tilt_deg=10.0)
    rows, cols = centre_window(H, W)
    sigma = 1.5
    values = [spatial_precision_mm(x[rows, cols], y[rows, cols], (z + sigma * rng.standard_normal(z.shape))[rows, cols])
              for _ in range(25)]
    n = 40 * 40
    assert np.mean(values) == pytest.approx(sigma * math.sqrt((n - 3) / n), rel=0.01)


def test_temporal_precision_ignores_fixed_pattern_and_averages_variances():
    """Per-pixel noise sigma(x) = 1 mm on the left half, 2 mm on the right; a fixed per-pixel offset
    pattern of 5 mm (not temporal): result sqrt((1 + 4) / 2) mm."""
    rng = np.random.default_rng(6)
    sigma = np.where(np.arange(40) < 20, 1.0, 2.0)[None, :] * np.ones((40, 1))
    fixed = 2000.0 + 5.0 * rng.standard_normal((40, 40))
    stack = fixed + sigma * rng.standard_normal((50, 40, 40))
    assert temporal_precision_mm(stack.astype(np.float32)) == pytest.approx(math.sqrt(2.5), rel=0.01)


def test_vendor_figures_of_a_stack():
    """Depth Quality Tool figures from the ROI of the first frames, Basler's from the centre window of all."""
    rng = np.random.default_rng(7)
    x, y, z, f = plane_points(2000.0)
    n = 12
    zs = np.stack([z + 2.0 * rng.standard_normal(z.shape) for _ in range(n)])
    xs, ys = np.broadcast_to(x, zs.shape), np.broadcast_to(y, zs.shape)
    rows, cols = dqt_roi(H, W)
    w_rows, w_cols = centre_window(H, W)
    result = vendor_figures((xs[:DQT_FRAMES, rows, cols], ys[:DQT_FRAMES, rows, cols], zs[:DQT_FRAMES, rows, cols]),
                            (xs[:, w_rows, w_cols], ys[:, w_rows, w_cols], zs[:, w_rows, w_cols]),
                            2000.0, focal_px=f, baseline_mm=50.0)
    assert result.n_frames == n
    assert result.fill_rate_pct == 100.0
    assert result.plane_fit_rms_mm == pytest.approx(trimmed_sigma(2.0), rel=0.01)
    assert result.spatial_precision_mm == pytest.approx(2.0, rel=0.02)
    assert result.temporal_precision_mm == pytest.approx(2.0, rel=0.02)
    # z noise at fixed x, y changes the range |p| by dz z / |p|: disparity noise f B / z^2 dz / k^3 with
    # k = |p| / z = sqrt(1 + tx^2 + ty^2) (the tool's range-based disparities; to first order)
    k = np.sqrt(1 + (x[rows, cols] ** 2 + y[rows, cols] ** 2) / 2000.0**2)
    expected = f * 50.0 / 2000.0**2 * trimmed_sigma(2.0) * math.sqrt(np.mean(k**-6))
    assert result.subpixel_rms_px == pytest.approx(expected, rel=0.01)
