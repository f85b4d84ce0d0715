"""x/y measurement error (Thesis 2024, 5.3, Table 6-6): known noise gives known statistics.

Neighbour spacing on the checkerboard. A corner at sub-pixel (u, v) is read
bilinearly from four pixels with weights w = ((1-f_u)(1-f_v), f_u(1-f_v),
(1-f_u)f_v, f_u f_v); with independent per-pixel noise of std sigma its x has
std sigma sqrt(sum w^2) (a linear true field is interpolated exactly). The
error of a neighbour pair a, b, e = |x_b - x_a| - tile, is then normal with
mean mu (zero for exact corner positions) and variance
sigma^2 (sum w_a^2 + sum w_b^2). Over the pairs, |e| follows the mixture of
these folded normals; its 90 % quantile q solves mean_k P(|e_k| < q) = 0.9,
and the sample quantile of n pairs has the standard error
sqrt(0.9 0.1 / n) / f(q), f the mixture's density of |e| at q (likewise the
signed median with sqrt(0.25 / n) / f_e(0)). Tolerance: 4 standard errors.
Reading the cloud at rounded positions (Thesis 2024, 5.2.2) would raise the spread
by about 50 % (sum w^2 is 4/9 on average), far outside it.
"""

import math

import cv2
import numpy as np
import pytest
from scipy import optimize
from scipy.stats import chi2, norm

from metrics.distortion import Corners, detect_corners
from metrics.stack import stack_stats
from metrics.xy_error import spacing_errors, xy_errors, xy_precision
from sim.model import default_model_text, parse_model
from sim.preview import simulate_frame

TILE = 19.0


def weights_sq(uv):
    fu, fv = uv[:, 0] - np.floor(uv[:, 0]), uv[:, 1] - np.floor(uv[:, 1])
    return ((1 - fu) * (1 - fv)) ** 2 + (fu * (1 - fv)) ** 2 + ((1 - fu) * fv) ** 2 + (fu * fv) ** 2


def pairs(ij, axis):
    index = {tuple(k): n for n, k in enumerate(ij.tolist())}
    step = (1, 0) if axis == 0 else (0, 1)
    return np.array([(n, index[(i + step[0], j + step[1])]) for (i, j), n in index.items()
                     if (i + step[0], j + step[1]) in index])


def expected_stats(mu, s):
    """Q90 of |e| and the median of e for e_k ~ N(mu_k, s_k), with their standard errors for len(mu) pairs."""
    def folded_cdf(q):
        return np.mean(norm.cdf((q - mu) / s) - norm.cdf((-q - mu) / s))

    def folded_pdf(q):
        return np.mean(norm.pdf((q - mu) / s) / s + norm.pdf((-q - mu) / s) / s)

    q90 = optimize.brentq(lambda q: folded_cdf(q) - 0.9, 0.0, 20 * s.max() + np.abs(mu).max())
    median = optimize.brentq(lambda m: np.mean(norm.cdf((m - mu) / s)) - 0.5, -10 * s.max() - 1, 10 * s.max() + 1)
    f_median = np.mean(norm.pdf((median - mu) / s) / s)
    n = len(mu)
    return q90, math.sqrt(0.09 / n) / folded_pdf(q90), median, math.sqrt(0.25 / n) / f_median


def check(errors, mu_s_x, mu_s_y):
    for measured, (mu, s) in ((errors.x_errors, mu_s_x), (errors.y_errors, mu_s_y)):
        assert len(measured) == len(mu)
        q90, se_q, median, se_m = expected_stats(mu, s)
        assert np.quantile(np.abs(measured), 0.9) == pytest.approx(q90, abs=4 * se_q)
        assert np.median(measured) == pytest.approx(median, abs=4 * se_m)
        assert 4 * se_q < 0.2 * q90  # the tolerance is tight enough to see a 50 % wrong spread
    assert errors.x_q90_mm == pytest.approx(np.quantile(np.abs(errors.x_errors), 0.9))
    assert errors.y_median_mm == pytest.approx(np.median(errors.y_errors))


# ------------------------------------------------------------------------------ exact corners, known noise
H, W, N_FRAMES, SIGMA, PX = 360, 480, 12, 1.5, 12.37  # corner spacing PX pixels, not a whole number


@pytest.fixture(scope="module")
def exact_board():
    i, j = np.meshgrid(np.arange(-18, 19), np.arange(-13, 14))
    ij = np.column_stack([i.ravel(), j.ravel()])
    uv = np.column_stack([(W - 1) / 2 + 0.3 + PX * ij[:, 0], (H - 1) / 2 - 0.2 + PX * ij[:, 1]])
    v, u = np.mgrid[0:H, 0:W].astype(float)
    truth = np.dstack([(u - (W - 1) / 2) * TILE / PX, (v - (H - 1) / 2) * TILE / PX, np.full_like(u, 800.0)])
    rng = np.random.default_rng(5)
    noise = SIGMA * rng.standard_normal((N_FRAMES, H, W, 2))
    stack = truth[None].repeat(N_FRAMES, 0)
    stack[..., :2] += noise
    return Corners(uv, ij, (H, W), "exact", (PX, PX)), stack


def spread(corners, sigma, axis):
    p = pairs(corners.ij, axis)
    w2 = weights_sq(corners.uv)
    return np.zeros(len(p)), sigma * np.sqrt(w2[p[:, 0]] + w2[p[:, 1]])


def test_trueness_and_accuracy_follow_the_per_point_noise(exact_board):
    corners, stack = exact_board
    mean = np.dstack([stack_stats(stack[..., c]).mean for c in range(3)])
    result = xy_errors(mean, stack[0], corners, TILE)
    check(result.trueness, spread(corners, SIGMA / math.sqrt(N_FRAMES), 0),
          spread(corners, SIGMA / math.sqrt(N_FRAMES), 1))
    check(result.accuracy, spread(corners, SIGMA, 0), spread(corners, SIGMA, 1))
    assert result.trueness.x_q90_mm < result.accuracy.x_q90_mm / 3  # averaging 12 frames: sqrt(12) = 3.5


def test_scale_error_shows_as_signed_median(exact_board):
    corners, stack = exact_board
    scaled = stack[0] * np.array([1.02, 0.99, 1.0])
    e = spacing_errors(scaled, corners, TILE)
    assert e.x_median_mm == pytest.approx(0.02 * TILE, abs=0.15) and e.y_median_mm == pytest.approx(-0.01 * TILE,
                                                                                                   abs=0.15)


def test_invalid_points_drop_their_pairs(exact_board):
    corners, stack = exact_board
    cloud = stack[0].copy()
    u, v = np.floor(corners.uv[0]).astype(int)
    cloud[v, u] = np.nan
    e = spacing_errors(cloud, corners, TILE)
    full = spacing_errors(stack[0], corners, TILE)
    lost = [len(pairs(corners.ij, a)) - len(pairs(corners.ij[1:], a)) for a in (0, 1)]
    assert (len(full.x_errors) - len(e.x_errors), len(full.y_errors) - len(e.y_errors)) == tuple(lost)
    with pytest.raises(ValueError, match="H x W x 3"):
        spacing_errors(cloud[..., :2], corners, TILE)


# ------------------------------------------------------------------------ simulated board, known noise
@pytest.mark.parametrize("image_seed", [8, 12])
def test_corner_labels_do_not_depend_on_the_sector_detectors_random_state(image_seed: int) -> None:
    """OpenCV's sector-based detector draws from OpenCV's global random generator; in this state it
    returned a sheared grid (steps a and a + 2 b) on these two noise realizations, and the corners were
    labelled along it (341 corners, median label error 3 tiles). Every corner must sit where its label
    puts it on the pinhole board (tile 6.7 px), whatever the generator's state."""
    model = parse_model(default_model_text("flexx2"))
    p = model.profile()
    *_, intensity, _ = simulate_frame(model, "checkerboard", {"tile_mm": TILE}, distance_mm=600.0, seed=image_seed)
    fx = (p.width / 2) / math.tan(math.radians(p.fov_h_deg) / 2)
    fy = (p.height / 2) / math.tan(math.radians(p.fov_v_deg) / 2)
    cv2.setRNGSeed(25)
    corners = detect_corners(intensity)
    true_uv = np.column_stack([(p.width - 1) / 2 + fx * corners.ij[:, 0] * TILE / 599.8,
                               (p.height - 1) / 2 + fy * corners.ij[:, 1] * TILE / 599.8])
    assert np.abs(corners.uv - true_uv).max() < 1.0


def test_simulated_board_with_known_cloud_noise():
    """Corners found in the simulator's intensity image; the cloud is the camera's pinhole geometry plus
    known noise. The detection error of each corner (found - true, in px, times z / f) enters as the
    pair's known mean mu; the rest is the noise."""
    model = parse_model(default_model_text("flexx2"))
    p = model.profile()
    z = 599.8
    *_, intensity, _ = simulate_frame(model, "checkerboard", {"tile_mm": TILE}, distance_mm=600.0)
    corners = detect_corners(intensity)
    fx = (p.width / 2) / math.tan(math.radians(p.fov_h_deg) / 2)
    fy = (p.height / 2) / math.tan(math.radians(p.fov_v_deg) / 2)
    cx, cy = (p.width - 1) / 2, (p.height - 1) / 2
    v, u = np.mgrid[0:p.height, 0:p.width].astype(float)
    truth = np.dstack([z * (u - cx) / fx, z * (v - cy) / fy, np.full_like(u, z)])
    n, sigma = 16, 2.0
    rng = np.random.default_rng(11)
    stack = truth[None].repeat(n, 0)
    stack[..., :2] += sigma * rng.standard_normal((n, p.height, p.width, 2))
    mean = stack.mean(axis=0)
    true_uv = np.column_stack([cx + fx * corners.ij[:, 0] * TILE / z, cy + fy * corners.ij[:, 1] * TILE / z])
    detection_mm = (corners.uv - true_uv) * np.array([z / fx, z / fy])
    assert np.median(np.abs(corners.uv - true_uv)) < 0.2
    result = xy_errors(mean, stack[0], corners, TILE)
    for errors, s in ((result.trueness, sigma / math.sqrt(n)), (result.accuracy, sigma)):
        known = []
        for axis in (0, 1):
            pr = pairs(corners.ij, axis)
            mu = detection_mm[pr[:, 1], axis] - detection_mm[pr[:, 0], axis]
            known.append((mu, spread(corners, s, axis)[1]))
        check(errors, *known)


def test_simulated_frames_trueness_below_accuracy():
    """The simulator's own ToF noise: the mean of frames beats one frame (Thesis 2024, Table 6-6 ToF columns)."""
    model = parse_model(default_model_text("flexx2"))
    frames = [simulate_frame(model, "checkerboard", {"tile_mm": TILE}, distance_mm=600.0, seed=s) for s in range(4)]
    clouds = np.array([np.dstack(f[:3]) for f in frames])
    corners = detect_corners(np.mean([f[3] for f in frames], axis=0))
    result = xy_errors(clouds.mean(axis=0), clouds[0], corners, TILE)
    assert result.trueness.x_q90_mm < result.accuracy.x_q90_mm and result.trueness.y_q90_mm < result.accuracy.y_q90_mm
    assert abs(result.trueness.x_median_mm) < 0.3 and abs(result.trueness.y_median_mm) < 0.3


# ------------------------------------------------------------------------------------- wall precision
def test_precision_and_repeatability_of_x_and_y():
    """Per-pixel std over N frames of known sigma: Q90 and median of s ~ sigma sqrt(chi2_{N-1} / (N-1));
    the centre pixel (H//2, W//2) has its own, larger sigma; a pixel invalid in most frames is invalid."""
    n, h, w, sx, sy, centre_sigma = 40, 90, 120, 0.5, 0.8, 3.0
    rng = np.random.default_rng(3)
    sig_x, sig_y = np.full((h, w), sx), np.full((h, w), sy)
    sig_x[h // 2, w // 2] = sig_y[h // 2, w // 2] = centre_sigma
    x = (rng.standard_normal((n, h, w)) * sig_x).astype(np.float32)
    y = (100.0 + rng.standard_normal((n, h, w)) * sig_y).astype(np.float32)
    x[: n // 2 + 1, :9, :] = np.nan  # 9 rows valid in fewer than half of the frames
    result = xy_precision(x, y)
    factor = {q: math.sqrt(chi2.ppf(q, n - 1) / (n - 1)) for q in (0.5, 0.9, 1e-4, 1 - 1e-4)}
    assert result.precision_q90_x_mm == pytest.approx(sx * factor[0.9], rel=0.02)
    assert result.precision_median_x_mm == pytest.approx(sx * factor[0.5], rel=0.02)
    assert result.precision_q90_y_mm == pytest.approx(sy * factor[0.9], rel=0.02)
    for value in (result.repeatability_center_x_mm, result.repeatability_center_y_mm):
        assert centre_sigma * factor[1e-4] < value < centre_sigma * factor[1 - 1e-4]
    assert result.invalid_fraction == pytest.approx(9 / h)
    assert stack_stats(x).valid.sum() == (h - 9) * w


def test_off_axis_repeatability_carries_the_depth_noise():
    """A noise-free pinhole camera on a wall with depth noise sigma_z: x = z (u - cx) / f is 0 at the
    principal point whatever the noise, while halfway to the edge std(x) = |u - cx| / f * sigma_z."""
    n, h, w, f, sigma_z = 60, 80, 120, 100.0, 2.0
    rng = np.random.default_rng(5)
    z = 2000.0 + rng.standard_normal((n, h, w)) * sigma_z
    u = np.arange(w) - w // 2  # principal point at the centre pixel
    v = np.arange(h) - h // 2
    x = z * u[None, None, :] / f
    y = z * v[None, :, None] / f
    result = xy_precision(x, y)
    assert result.repeatability_center_x_mm == result.repeatability_center_y_mm == 0.0
    assert result.center_xy_mm == (0.0, 0.0)
    bounds = [math.sqrt(chi2.ppf(q, n - 1) / (n - 1)) for q in (1e-4, 1 - 1e-4)]
    expected_x, expected_y = (w // 4) / f * sigma_z, (h // 4) / f * sigma_z
    assert expected_x * bounds[0] < result.repeatability_off_axis_x_mm < expected_x * bounds[1]
    assert expected_y * bounds[0] < result.repeatability_off_axis_y_mm < expected_y * bounds[1]
    assert result.off_axis_xy_mm[0] == pytest.approx(2000.0 * (w // 4) / f, rel=0.01)
    assert result.off_axis_xy_mm[1] == pytest.approx(2000.0 * (h // 4) / f, rel=0.01)
