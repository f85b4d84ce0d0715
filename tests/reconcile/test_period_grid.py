"""The periodic candidates' period grids: a grid point within an eighth of a cycle of every period over the span."""

import numpy as np
import pytest

from labctl.reconcile.candidates import even_frequency_periods


@pytest.mark.parametrize("shortest,longest,span,anchor", [
    (150.0, 4488.7, 4488.7, 4488.7),  # the wiggling on the test campaign's compared ranges, mm
    (150.0, 300.0, 120.0, 300.0),  # a span shorter than the longest period
    (0.5, 4.0, 14.0, 1.0),  # the pixel locking on the d455's compared disparities, px
])
def test_every_period_has_a_grid_point_slipping_at_most_an_eighth_of_a_cycle_over_the_span(
        shortest, longest, span, anchor):
    """A trial period Q against a true P turns (1/Q - 1/P) S cycles apart over a span S: the nearest grid point
    must keep that within 1/8 for every P in the searched range."""
    grid = np.array(even_frequency_periods(shortest, longest, span, anchor))
    assert np.all(np.diff(grid) > 0) and grid[0] >= shortest * (1 - 1e-12) and grid[-1] <= longest * (1 + 1e-12)
    assert np.min(np.abs(grid - anchor)) <= 1e-9 * anchor
    true = np.random.default_rng(7).uniform(1 / longest, 1 / shortest, 2000)  # frequencies
    slip = np.min(np.abs(1 / grid[None, :] - true[:, None]), axis=1) * span
    assert slip.max() <= 1 / 8 + 1e-9
