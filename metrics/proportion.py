"""How large a rate can be when k of n trials showed the event: the exact binomial upper confidence bound.

Clopper, C. J.; Pearson, E. S. (1934), "The use of confidence or fiducial
limits illustrated in the case of the binomial", Biometrika 26 (4), 404-413:
the one-sided upper limit p_u at confidence 1 - alpha solves
P(X <= k | n, p_u) = alpha, which is the 1 - alpha quantile of the
Beta(k + 1, n - k) distribution; for k = 0 it is 1 - alpha^(1/n), about 3/n at
95 % (the "rule of three", Hanley & Lippman-Hand 1983, JAMA 249 (13)).
"""

from __future__ import annotations

from scipy import stats


def upper_bound(k: int, n: int, confidence: float = 0.95) -> float:
    """One-sided Clopper-Pearson upper bound of a rate observed ``k`` times in ``n`` trials (1.0 when k = n).

    Examples
    --------
    No event in 100 trials: 1 - 0.05^(1/100) = 0.0295, about 3 / n; 9 of 10: 0.95^(1/10) = 0.9949.

    >>> round(upper_bound(0, 100), 4), round(upper_bound(9, 10), 4), upper_bound(3, 3)
    (0.0295, 0.9949, 1.0)
    """
    if n < 1 or not 0 <= k <= n:
        raise ValueError(f"need 0 <= k <= n and n >= 1, got k={k}, n={n}")
    if k == n:
        return 1.0
    return float(stats.beta.ppf(confidence, k + 1, n - k))
