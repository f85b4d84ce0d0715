"""The quantization detector's sample of a stack: the same finite values a listing of every finite position would
give, found in one compiled pass."""

from __future__ import annotations

import numpy as np
import pytest

from metrics.plausibility import _finite_sample, quantization_step


@pytest.mark.parametrize(("size", "finite_fraction"), [(1000, 0.5), (3 * 65536 + 17, 0.3), (2_000_000, 0.9),
                                                        (65536, 0.0), (10, 1.0), (0, 1.0)])
def test_the_sample_is_the_evenly_spread_finite_values(size, finite_fraction):
    finite = np.random.default_rng(size).random(size) < finite_fraction
    positions = np.flatnonzero(finite)  # the reference: every finite position listed, then thinned
    if positions.size > 20000:
        positions = positions[np.linspace(0, positions.size - 1, 20000).astype(int)]
    np.testing.assert_array_equal(_finite_sample(np.where(finite, 1.0, np.nan), 20000), positions)


def test_a_stack_with_invalid_pixels_shows_its_whole_millimetre_output():
    stack = np.round(np.random.default_rng(1).normal(1000.0, 3.0, size=(20, 60, 80))).astype(np.float32)
    stack[stack > 1003] = np.nan
    assert quantization_step(stack) == 1.0
    assert np.isnan(quantization_step(stack + np.random.default_rng(2).normal(0.0, 0.01, stack.shape)))
