"""The stereo depth's predicted temporal noise against its definition, enumerated directly: the variance of the
depth over the disparity levels, rounded to the output steps, averaged over where the true disparity and depth sit
on both grids (labctl/reconcile/noise_model.py, ``stored_disparity_noise``)."""

import numpy as np
import pytest
from scipy import stats

from labctl.reconcile.noise_model import (
    DISPARITY_POSITIONS,
    LATTICE_RATIO,
    OUTPUT_OFFSETS,
    TAIL_SIGMAS,
    _lattice_noise,
    stored_disparity_noise,
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
