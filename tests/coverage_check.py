"""The known-answer check of the uncertainty coverage tests: over independent repetitions (seeds), the stated
U = 2 u covers each figure's deviation from the mean over the seeds in about 95 % of them (GUM 6.2, 6.3), and the
stated u matches the spread actually seen (a grossly overstated uncertainty fails too)."""

from __future__ import annotations

import numpy as np


def assert_u_covers_the_spread(name: str, value: np.ndarray, u: np.ndarray, min_covered: int, ratio: float) -> None:
    """``value`` and standard uncertainty ``u`` of figure ``name`` per seed: every one finite and u > 0, U = 2 u
    covering at least ``min_covered`` seeds, and the mean u within a factor ``ratio`` of the spread over seeds."""
    assert np.isfinite(value).all() and np.isfinite(u).all() and (u > 0).all()
    covered = int(np.sum(np.abs(value - value.mean()) <= 2.0 * u))
    spread = float(np.std(value, ddof=1))
    assert covered >= min_covered, f"{name}: U covers {covered} of {value.size} seeds (spread {spread:.4g}, u {u.mean():.4g})"
    assert 1 / ratio <= u.mean() / spread <= ratio, f"{name}: mean u {u.mean():.4g}, spread over seeds {spread:.4g}"
