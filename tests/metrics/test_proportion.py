"""The exact binomial upper bound against its definition and the closed form for no events."""

from __future__ import annotations

import pytest
from scipy import stats

from metrics.proportion import upper_bound


@pytest.mark.parametrize("n", [48, 200, 1000])
def test_no_event_is_the_closed_form(n: int) -> None:
    # P(X = 0) = (1 - p)^n = alpha  =>  p = 1 - alpha^(1/n)
    assert upper_bound(0, n) == pytest.approx(1 - 0.05 ** (1 / n), rel=1e-9)


def test_rule_of_three_at_48_runs() -> None:
    assert upper_bound(0, 48) == pytest.approx(0.0605, abs=5e-4)  # 3 / 48 = 0.0625 approximately


@pytest.mark.parametrize(("k", "n"), [(1, 200), (5, 200), (17, 40)])
def test_bound_leaves_alpha_below_k(k: int, n: int) -> None:
    # the defining equation: at p_u the chance of k or fewer events is alpha (binomial CDF, not the beta quantile)
    assert stats.binom.cdf(k, n, upper_bound(k, n)) == pytest.approx(0.05, rel=1e-6)


def test_all_events_and_bad_counts() -> None:
    assert upper_bound(3, 3) == 1.0
    with pytest.raises(ValueError):
        upper_bound(4, 3)
