"""Known answers for the remission-and-angle metrics: ROI on the axis, tilted planes, the misalignment fit."""

import math

import numpy as np
import pytest

from metrics.remission import (
    axis_roi,
    fit_misalignment,
    geometric_reference,
    measure_roi,
    pooled_std_jackknife,
    target_window,
    trueness_vs_zero,
    with_ring,
)

H, W = 120, 160
F_PX = (W / 2) / math.tan(math.radians(33.5))  # 67 deg over 160 px
RADIUS = 850.0


def plate_stacks(theta_deg: float, distance: float, sigma: float = 0.0, frames: int = 8, seed: int = 0,
                 roi: tuple[slice, slice] | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """x, y, z stacks of a pinhole camera (principal point at the image centre) seeing a plane that crosses
    the optical axis at ``distance``, tilted by ``theta_deg`` about y; Gaussian range noise ``sigma``."""
    rows, cols = roi if roi is not None else (slice(0, H), slice(0, W))
    v, u = np.mgrid[rows, cols].astype(float)
    u = (u - (W - 1) / 2) / F_PX
    v = (v - (H - 1) / 2) / F_PX
    z = distance / (1.0 + math.tan(math.radians(theta_deg)) * u)
    rng = np.random.default_rng(seed)
    zs = z[None] + sigma * rng.standard_normal((frames, *z.shape))
    return zs * u, zs * v, zs


@pytest.mark.parametrize("h, w, size", [(480, 640, 5), (120, 160, 5), (121, 161, 5), (120, 161, 5),
                                        (121, 160, 6), (172, 224, 5), (7, 8, 20)])
def test_roi_is_symmetric_about_the_principal_point(h, w, size):
    rows, cols = axis_roi(h, w, size)
    for s, n in ((rows, h), (cols, w)):
        idx = np.arange(n)[s]
        assert idx.mean() == pytest.approx((n - 1) / 2)
        assert idx.size == min(n, size + (n - size) % 2)


def test_even_image_gets_an_even_roi():
    assert axis_roi(480, 640) == (slice(237, 243), slice(317, 323))
    assert axis_roi(481, 641) == (slice(238, 243), slice(318, 323))


def test_half_pixel_offset_of_a_centre_pixel_roi_is_odd_in_the_angle():
    """A 5 x 5 ROI around (H//2, W//2) sits half a pixel right of the axis: its mean depth is off by
    about -d tan(theta) / (2 f) (sign with theta); the 6 x 6 axis ROI has no such odd term."""
    d = 900.0
    naive = (slice(H // 2 - 2, H // 2 + 3), slice(W // 2 - 2, W // 2 + 3))
    centred = axis_roi(H, W)

    def mean_error(roi, theta):
        return float(plate_stacks(theta, d, roi=roi)[2].mean()) - d

    for theta in (40.0, 70.0):
        odd_naive = (mean_error(naive, theta) - mean_error(naive, -theta)) / 2
        assert odd_naive == pytest.approx(-d * math.tan(math.radians(theta)) / (2 * F_PX), rel=0.05)
        assert abs(mean_error(centred, theta) - mean_error(centred, -theta)) < 1e-6


def test_axis_distance_of_a_tilted_plane_is_exact_where_the_roi_mean_is_not():
    """At 80 deg the 6 x 6 ROI mean of z is biased by d tan^2 <u^2> (about 6 mm); the plane fit is not."""
    roi = axis_roi(H, W)
    for theta in (-80.0, -40.0, 0.0, 30.0, 70.0, 80.0):
        x, y, z = plate_stacks(theta, 900.0, roi=roi)
        m = measure_roi(x, y, z)
        assert m.on_target and m.pixels == 36 and m.invalid_fraction == 0 and m.off_target_fraction == 0
        assert m.distance_mm == pytest.approx(900.0, abs=1e-6)
    x, y, z = plate_stacks(80.0, 900.0, roi=roi)
    u2 = np.mean((np.arange(6) - 2.5) ** 2) / F_PX**2
    assert float(z.mean()) - 900.0 == pytest.approx(900.0 * math.tan(math.radians(80)) ** 2 * u2, rel=0.1)
    assert float(z.mean()) - 900.0 > 5.0


def test_noise_gives_pooled_repeatability_and_a_consistent_standard_error():
    """sigma = 2 mm, 10 frames, 36 pixels: the pooled std has 324 degrees of freedom (4 % relative
    error), so it lies within 15 %; the axis distance lies within 4 of its own standard errors."""
    roi = axis_roi(H, W)
    pulls = []
    for seed in range(40):
        x, y, z = plate_stacks(60.0, 900.0, sigma=2.0, frames=10, seed=seed, roi=roi)
        m = measure_roi(x, y, z)
        assert m.repeatability_mm == pytest.approx(2.0, rel=0.15)
        pulls.append((m.distance_mm - 900.0) / m.distance_se_mm)
    # 40 pulls: their std is 1 within 0.35 (about 3 standard errors of a std from 40 samples)
    assert abs(np.std(pulls) - 1.0) < 0.35
    assert max(abs(p) for p in pulls) < 4.0


def test_off_target_pixels_are_dropped_and_counted():
    """One column on the curtains 2 m behind, one invalid column, the columns next to them (which may
    straddle the plate's edge) and one mixed pixel: with a third of the ROI left the step is not on target
    (the plane fit, which finds the mixed pixel, does not run); with the invalid column back, the rest
    gives the exact distance. Fractions add up."""
    roi = axis_roi(H, W)
    x, y, z = plate_stacks(70.0, 900.0, roi=roi)
    z[:, :, 5:] = 900.0 + 2000.0 / math.cos(math.radians(70))  # far beyond the plate
    z[:, 2, 1] += 60.0  # a mixed pixel, within 20 % of the median but off the plane
    plate_column = z[:, :, 0].copy()
    z[:, :, 0] = np.nan  # invalid column
    m = measure_roi(x, y, z, target_window(70.0, RADIUS))
    assert m.invalid_fraction == pytest.approx(6 / 36) and m.off_target_fraction == pytest.approx(18 / 36)
    assert m.pixels == 12 and not m.on_target and math.isnan(m.distance_mm)
    z[:, :, 0] = plate_column
    m = measure_roi(x, y, z, target_window(70.0, RADIUS))
    assert m.invalid_fraction == 0 and m.off_target_fraction == pytest.approx(13 / 36)
    assert m.on_target and m.pixels == 23
    assert m.distance_mm == pytest.approx(900.0, abs=1e-6)


def test_roi_pixels_next_to_the_background_in_the_ring_are_left_out():
    """The plate ends between the ROI's last column and the ring beyond it: that column may straddle the
    edge, so it is left out (off target), the rest gives the exact distance; the ring itself never counts."""
    grown, inner = with_ring(axis_roi(H, W), H, W)
    assert grown == (slice(56, 64), slice(76, 84)) and inner == (slice(1, 7), slice(1, 7))
    assert with_ring((slice(0, 6), slice(154, 160)), H, W) == ((slice(0, 7), slice(153, 160)),
                                                             (slice(0, 6), slice(1, 7)))
    x, y, z = plate_stacks(60.0, 900.0, roi=grown)
    z[:, :, 7] = 900.0 + 2000.0 / math.cos(math.radians(60))  # the ring column beyond the ROI: curtains
    z[:, 0, :] = np.nan  # the ring row above the ROI: invalid
    whole = measure_roi(x, y, z, target_window(60.0, RADIUS), inner=inner)
    assert whole.pixels == 25 and whole.off_target_fraction == pytest.approx(11 / 36) and whole.invalid_fraction == 0
    assert whole.on_target and whole.distance_mm == pytest.approx(900.0, abs=1e-6)


def test_roi_entirely_on_the_background_is_not_on_target():
    x, y, z = plate_stacks(0.0, RADIUS + 2000.0, roi=axis_roi(H, W))
    m = measure_roi(x, y, z, target_window(0.0, RADIUS))
    assert not m.on_target and math.isnan(m.distance_mm) and m.off_target_fraction == 1.0


@pytest.mark.parametrize("theta", range(-80, 81, 10))
def test_target_window_holds_misaligned_targets_and_excludes_the_curtain(theta):
    lo, hi = target_window(theta, RADIUS)
    for delta in (-99.0, 99.0):  # just inside the 100 mm the window allows for each term
        for e in (-99.0, 99.0):
            for b in (-99.0, 99.0):
                assert lo <= float(geometric_reference(theta, RADIUS, delta, e)) + b <= hi
    assert RADIUS + 2000.0 / math.cos(math.radians(theta)) > hi


def test_spec_numbers_of_figure_5_15():
    """Thesis 2024, 5.4: for 20 mm, +95 mm at 80 deg relative to 0 deg (target) and -113 mm at 80 deg (camera
    axis), not the "about 20 cm" of Thesis 2024, 5.4.2."""
    target = geometric_reference([0.0, 80.0], RADIUS, delta_mm=20.0)
    assert target[1] - target[0] == pytest.approx(95.2, abs=0.1)
    camera = geometric_reference([0.0, 80.0], RADIUS, e_mm=20.0)
    assert camera[0] == RADIUS and camera[1] - RADIUS == pytest.approx(-113.4, abs=0.1)
    assert geometric_reference(-80.0, RADIUS, e_mm=20.0) - RADIUS == pytest.approx(113.4, abs=0.1)


ANGLES = np.arange(-80.0, 81.0, 10.0)


@pytest.mark.parametrize("delta, e, b", [(20.0, 15.0, 10.0), (-12.0, -25.0, 3.0), (0.0, 30.0, -5.0)])
def test_fit_recovers_analytic_offsets_and_its_standard_errors_are_honest(delta, e, b):
    """0.3 mm noise on every angle, 300 trials: unbiased within 3 standard errors of the mean, and
    the spread of the estimates matches the reported standard error within 15 %."""
    truth = geometric_reference(ANGLES, RADIUS, delta, e) + b
    rng = np.random.default_rng(1)
    fits = [fit_misalignment(ANGLES, truth + 0.3 * rng.standard_normal(ANGLES.size), RADIUS)
            for _ in range(300)]
    for attr, true in (("delta_mm", delta), ("e_mm", e), ("bias_mm", b)):
        values = np.array([getattr(f, attr) for f in fits])
        se = np.mean([getattr(f, attr.replace("_mm", "_se_mm")) for f in fits])
        assert abs(values.mean() - true) < 3 * values.std() / math.sqrt(values.size)
        assert values.std() == pytest.approx(se, rel=0.15)
    assert np.mean([f.residual_rms_mm for f in fits]) == pytest.approx(0.3 * math.sqrt(14 / 17), rel=0.1)


def test_fit_weights_points_by_their_standard_error_and_skips_missing_ones():
    """A 30 mm error on a point with a 50 mm standard error barely moves the fit; NaN points are skipped."""
    truth = geometric_reference(ANGLES, RADIUS, 20.0, -15.0)
    measured = truth.copy()
    measured[-1] += 30.0
    measured[0] = np.nan
    se = np.full(ANGLES.size, 0.05)
    se[-1] = 50.0
    fit = fit_misalignment(ANGLES, measured, RADIUS, se)
    assert fit.delta_mm == pytest.approx(20.0, abs=0.05) and fit.e_mm == pytest.approx(-15.0, abs=0.05)
    assert fit.angles_deg.size == ANGLES.size - 1
    unweighted = fit_misalignment(ANGLES, measured, RADIUS)
    assert abs(unweighted.delta_mm - 20.0) > 1.0


def test_fit_needs_four_points_and_separable_angles():
    with pytest.raises(ValueError, match="at least 4"):
        fit_misalignment([0.0, 10.0, 20.0], [850.0] * 3, RADIUS)
    with pytest.raises(ValueError, match="degenerate"):
        fit_misalignment([20.0] * 5, [850.0] * 5, RADIUS)


def test_fit_with_radius_per_point():
    radii = np.where(ANGLES < 0, 800.0, 850.0)
    fit = fit_misalignment(ANGLES, geometric_reference(ANGLES, radii, 10.0, 5.0), radii)
    assert fit.delta_mm == pytest.approx(10.0, abs=1e-9) and fit.e_mm == pytest.approx(5.0, abs=1e-9)
    assert float(fit.reference(30.0, 800.0)) == pytest.approx(float(geometric_reference(30.0, 800.0, 10.0, 5.0)))


def test_trueness_vs_zero():
    t = trueness_vs_zero([-10.0, 0.0, 10.0], [905.0, 900.0, 898.0])
    assert list(t) == [5.0, 0.0, -2.0]
    assert np.isnan(trueness_vs_zero([-10.0, 10.0], [905.0, 898.0])).all()
    assert np.isnan(trueness_vs_zero([-10.0, 0.0], [905.0, np.nan])).all()


@pytest.mark.parametrize("block", [1, 4])
def test_pooled_repeatability_uncertainty_covers_its_spread_over_repetitions(block):
    """The jackknife over the frames states the spread the pooled std shows over 300 independent repetitions
    (within 20 %). With independent pixels that is also sigma / sqrt(2 nu), nu = P (N - 1) (GUM E.4.3); with
    the noise shared by blocks of 4 pixels (as a matching window correlates neighbours) the pixels carry a
    quarter of the degrees of freedom, the spread doubles, and the jackknife follows it where the
    per-pixel formula would not."""
    rng = np.random.default_rng(20261126)
    frames, pixels, sigma = 20, 240, 1.5
    pooled, stated = [], []
    for _ in range(300):
        noise = np.repeat(rng.normal(0.0, sigma, size=(frames, pixels // block)), block, axis=1)
        stack = 800.0 + rng.normal(0.0, 3.0, size=pixels) + noise  # a fixed surface plus the frames' noise
        pooled.append(math.sqrt(np.mean(np.var(stack, axis=0, ddof=1))))
        stated.append(pooled_std_jackknife(stack))
    spread = float(np.std(pooled, ddof=1))
    assert np.mean(stated) == pytest.approx(spread, rel=0.2)
    independent = sigma / math.sqrt(2 * pixels * (frames - 1))
    assert spread == pytest.approx(independent * math.sqrt(block), rel=0.2)


def test_pooled_repeatability_uncertainty_skips_missing_values_and_needs_three_frames():
    stack = np.random.default_rng(3).normal(size=(12, 50))
    holed = stack.copy()
    holed[0, :25] = np.nan
    assert math.isfinite(pooled_std_jackknife(holed)) and pooled_std_jackknife(holed) > 0
    assert math.isnan(pooled_std_jackknife(stack[:2]))
