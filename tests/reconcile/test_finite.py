"""``finite``: numpy's ``nan_to_num`` of a prediction's maps, in fewer passes."""

from __future__ import annotations

import numpy as np
import pytest

from labctl.reconcile.finite import finite


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_finite_gives_numpys_nan_to_num_for_every_kind_of_value(dtype):
    values = np.array([[np.nan, np.inf, -np.inf, -0.0], [0.0, 1.5, -2.5e30, 3e-40]]).astype(dtype)
    got = finite(values)
    expected = np.nan_to_num(values)  # numpy's own: NaN 0, +-inf the largest finite float of the type
    assert got.dtype == expected.dtype
    np.testing.assert_array_equal(got, expected)
    np.testing.assert_array_equal(np.signbit(got), np.signbit(expected))
    assert np.isnan(values[0, 0])  # a copy: the input is left as it was
