"""The statistics of the cameras' roundings against their definitions, enumerated directly
(labctl/reconcile/noise_model.py): the stereo depth's temporal noise, the variance of the depth over the disparity
levels, rounded to the output steps, averaged over where the true disparity and depth sit on both grids
(``stored_disparity_noise``); and a ToF depth's stored mean, E[round(v + sigma n)] over the output steps
(``tof_stored_bias``)."""

import numpy as np
import pytest
from scipy import stats

from labctl.reconcile.noise_model import (
    DISPARITY_POSITIONS,
    LATTICE_RATIO,
    OUTPUT_OFFSETS,
    TAIL_SIGMAS,
    _lattice_noise,
    _rounded_mean,
    stored_disparity_noise,
    tof_stored_bias,
)

FB, STEP_D = 9904.5, 1 / 32  # the d455 at the test size: f b (px mm), disparity step (px)
LEVELS = int(np.ceil(5 * LATTICE_RATIO)) + 1


def _by_enumeration(z: float, sigma_d: float, step_mm: float, positions: int, offsets: int) -> tuple[float, float]:
    """sqrt of the mean variance and the std of ln std over every (disparity position, output offset): at each,
    the depth's distribution over the disparity levels within ``TAIL_SIGMAS`` sigma_d (or ``LEVELS``), the depth
    linear in the disparity (slope z^2 / (f b)), each value rounded to the output step at that offset."""
    scale, r = z**2 / FB, sigma_d / STEP_D
    reach = min(LEVELS, int(np.ceil(TAIL_SIGMAS * r + 1.0)))
    j = np.arange(-reach, reach + 1)
    variances = []
    for delta in (np.arange(positions) + 0.5) / positions - 0.5:
        p = stats.norm.cdf((j + 0.5 - delta) / r) - stats.norm.cdf((j - 0.5 - delta) / r)
        depth = -scale * (j - delta) * STEP_D
        for u in (np.arange(offsets) + 0.5) / offsets * step_mm:
            v = np.floor((depth + u) / step_mm + 0.5) * step_mm if step_mm > 0 else depth
            variances.append(p @ v**2 - (p @ v) ** 2)
    variances = np.array(variances)
    return float(np.sqrt(variances.mean())), float(np.std(0.5 * np.log(variances)))


@pytest.mark.parametrize("z", [806.0, 1506.0, 3006.0])
@pytest.mark.parametrize("sigma_d", [0.0248, 0.06])
def test_the_rounded_stereo_noise_is_the_mean_of_its_variances_over_both_grids(z, sigma_d):
    """Millimetre output (the positions -delta computed as mirrors of +delta, and the offsets as steps of a
    running sum, noise_model._lattice_noise) and no output step, against the enumeration."""
    for step_mm, offsets in ((1.0, OUTPUT_OFFSETS), (0.0, 1)):
        std, spread = stored_disparity_noise(np.array([z]), np.array([sigma_d]), STEP_D, FB, step_mm)
        expected = _by_enumeration(z, sigma_d, step_mm, DISPARITY_POSITIONS, offsets)
        if np.isnan(std[0]):  # below half the output step: not predicted
            assert z**2 / FB * sigma_d < step_mm / 2
            continue
        assert std[0] == pytest.approx(expected[0], rel=1e-12)
        assert spread[0] == pytest.approx(expected[1], rel=1e-9, abs=1e-12)


def test_an_odd_count_of_disparity_positions_counts_the_centre_once():
    """Seven disparity positions (delta = 0 among them, its own mirror) against the enumeration."""
    z, sigma_d = 1506.0, 0.03
    std, spread = _lattice_noise(np.array([sigma_d / STEP_D]), np.array([z**2 / FB]), STEP_D, 1.0, LEVELS, 7,
                                 OUTPUT_OFFSETS, TAIL_SIGMAS)
    expected = _by_enumeration(z, sigma_d, 1.0, 7, OUTPUT_OFFSETS)
    assert std[0] == pytest.approx(expected[0], rel=1e-12)
    assert spread[0] == pytest.approx(expected[1], rel=1e-9)


def _stored_mean_by_enumeration(v: float, sigma: float, step: float) -> float:
    """E[round_step(v + sigma n)] - v over every step within 15 sigma of v (the normal mass beyond, 4e-51, is
    below a double's resolution)."""
    k = np.arange(np.floor((v - 15 * sigma) / step), np.ceil((v + 15 * sigma) / step) + 1)
    mass = stats.norm.cdf(((k + 0.5) * step - v) / sigma) - stats.norm.cdf(((k - 0.5) * step - v) / sigma)
    return float(mass @ (k * step) / mass.sum() - v)


@pytest.mark.parametrize("ratio", [0.05, 0.2, 0.2499, 0.25, 0.4, 0.9, 2.0, 3.9])
def test_a_tof_depths_stored_mean_is_its_expectation_over_the_output_steps(ratio):
    """sigma / step on both sides of where the levels' sum gives way to the rounding's Fourier series
    (noise_model.FOURIER_RATIO), at values all over a step: the bias against the enumeration to 1e-12 of a step
    (the sum over the levels within 6 sigma leaves out a normal mass of 2e-9)."""
    step = 1.0
    values = 806.0 + np.linspace(0.0, 1.0, 13)[:, None]  # one point per bin
    got = _rounded_mean(values, np.full(len(values), ratio * step), step)
    expected = [_stored_mean_by_enumeration(v, ratio * step, step) for v in values[:, 0]]
    tolerance = 1e-12 if ratio >= 0.25 else 1e-8
    np.testing.assert_allclose(got, expected, rtol=0, atol=tolerance * step)


def test_a_flat_tof_bin_is_biased_by_where_its_depth_sits_on_the_steps():
    """A frontal wall's bins, the noise a third of a step: one depth, one bias, set by where the depth sits between
    two steps (on a step none, a quarter step above one -0.036 of a step)."""
    for depth in (806.0, 806.25):
        z = np.full((3, 3), depth)
        bias = tof_stored_bias(z, np.full_like(z, 1 / 3), 1.0, 4)
        np.testing.assert_allclose(bias, _stored_mean_by_enumeration(depth, 1 / 3, 1.0), rtol=0, atol=1e-12)
    assert bias[1, 1] == pytest.approx(-0.0355, abs=1e-4)
