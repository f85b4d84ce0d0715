"""The fixed pattern's held-out profiles: each step's from the sums over the other steps."""

import numpy as np

from labctl.reconcile.candidates import _additive_profiles, _held_out_sums


def test_held_out_sums_leave_each_step_out_and_keep_exact_zeros():
    rng = np.random.default_rng(2)
    values = rng.uniform(0.0, 1.0, (6, 3, 4))
    values[:, 0, 0] = 0.0
    values[2, 1, 1], values[[0, 1, 3, 4, 5], 1, 1] = 7.0, 0.0  # only step 2 holds this bin
    out = _held_out_sums(values)
    for s in range(len(values)):
        np.testing.assert_allclose(out[s], np.delete(values, s, axis=0).sum(0), rtol=1e-14)
    assert np.all(out[:, 0, 0] == 0.0) and out[2, 1, 1] == 0.0


def test_additive_profiles_recover_a_column_and_a_row_pattern():
    rng = np.random.default_rng(3)
    col, row = rng.normal(0.0, 1.0, 8), rng.normal(0.0, 1.0, 5)
    col, row = col - col.mean(), row - row.mean()
    weight = rng.uniform(0.5, 2.0, (10, 5, 8))
    weight[:, :, 7] = 0.0  # a column never compared
    res = row[None, :, None] + col[None, None, :] + 4.0  # the constant goes to neither profile
    c, r = _additive_profiles((weight * res).sum(0), weight.sum(0), iterations=60)
    np.testing.assert_allclose(c[:7], col[:7] - col[:7].mean(), atol=1e-9)
    np.testing.assert_allclose(r, row, atol=1e-9)
    assert c[7] == 0.0
