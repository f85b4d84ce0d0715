"""Measurement uncertainty of a figure, following the GUM (JCGM 100:2008).

A figure's uncertainty budget is a list of components, each a standard uncertainty in the figure's unit: an
input's standard uncertainty times the figure's sensitivity to it (GUM 5.1.3; evaluated numerically
where the figure is no closed formula of the input, :func:`sensitivity`). The components are taken as
uncorrelated and combined by the root sum of squares (GUM 5.1.2, eq. 10); the expanded uncertainty is
U = k u_c with the coverage factor k = 2 (GUM 6.2.1, 6.3.3: about 95 % for a near-normal distribution).

The components are evaluated

* by Type A from the data (GUM 4.2): the experimental standard deviation of the mean s / sqrt(n) (GUM 4.2.3),
  that of a single observation s (GUM 4.2.2), that of an experimental standard deviation s / sqrt(2 (n - 1))
  (GUM E.4.3, Table E.1), and, for a statistic that is none of these (a quantile over pixels of per-pixel
  stack statistics), the jackknife standard error over the frames (Efron & Tibshirani 1993, 11.2). The
  jackknife, not the bootstrap: a bootstrap resample repeats some frames and leaves others out, which changes
  the noise of the per-pixel means and standard deviations from resample to resample, and a quantile over
  pixels follows that noise level; on simulated runs the bootstrap so stated about twice the spread the
  figures showed over seeds, the jackknife (every replica n - 1 distinct frames) the spread itself. The
  jackknife is taken of the quantile's cumulative proportion, not of the quantile itself, and mapped through
  the quantile function (:func:`quantile_standard_error`): on quantized output the per-pixel statistics sit on a
  lattice and every replica's quantile can fall on the same lattice value, a jackknife of 0;
* by Type B from stated specifications (GUM 4.3): a bound +-a with no other knowledge as a rectangular
  distribution, u = a / sqrt(3) (GUM 4.3.7), a value stated as a multiple k of a standard deviation as
  u = value / k (GUM 4.3.3).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

#: coverage factor of the expanded uncertainty (GUM 6.2.1; about 95 % coverage, GUM 6.3.3)
COVERAGE_FACTOR = 2.0


@dataclass(frozen=True)
class Component:
    """One line of an uncertainty budget: what it is and its standard uncertainty in the figure's unit."""

    name: str
    value: float


def combined_standard_uncertainty(budget: Sequence[Component]) -> float:
    """Root sum of squares of uncorrelated components, each already times its sensitivity coefficient (GUM
    5.1.2, eq. 10 and 5.1.3); NaN when the budget is empty or a component is not finite.

    Examples
    --------
    >>> combined_standard_uncertainty([Component("a", 0.3), Component("b", 0.4)])
    0.5
    """
    values = [c.value for c in budget]
    if not values or not all(math.isfinite(v) for v in values):
        return math.nan
    return math.sqrt(sum(v * v for v in values))


def expanded_uncertainty(standard: float, k: float = COVERAGE_FACTOR) -> float:
    """U = k u_c (GUM 6.2.1), k = 2 by default.

    Examples
    --------
    >>> expanded_uncertainty(0.5)
    1.0
    """
    return k * standard


def distinguishable(a: float, expanded_a: float, b: float, expanded_b: float) -> bool:
    """Whether two measured values differ by more than the expanded uncertainty of their difference,
    sqrt(U_a^2 + U_b^2): the values' errors independent (GUM 5.1.2: u_c(a - b)^2 = u(a)^2 + u(b)^2) and both
    expanded with the same coverage factor (GUM 6.2.1).

    Examples
    --------
    >>> distinguishable(1.00, 0.10, 1.12, 0.10)  # 0.12 against 0.141
    False
    >>> distinguishable(1.00, 0.10, 1.50, 0.10)
    True
    """
    return abs(a - b) > math.hypot(expanded_a, expanded_b)


def conformity(value: float, limit: float, expanded: float | None, kind: str = "max_abs") -> str:
    """The decision on a value against a limit with guard bands of its expanded uncertainty U (JCGM 106:2012,
    clause 8: guarded acceptance and guarded rejection, w = U; ISO 14253-1:2017: conformity is proven inside the
    specification reduced by U, non-conformity outside it widened by U): ``pass`` where the value lies inside the
    limit by more than U, ``fail`` where it lies outside by more than U, else ``marginal``. ``kind``:
    ``max_abs`` (|value| <= limit) or ``min`` (value >= limit). Without U (None), on the value alone.

    Examples
    --------
    >>> conformity(-4.9, 5.0, 0.3), conformity(4.5, 5.0, 0.3), conformity(5.4, 5.0, 0.3), conformity(5.0, 5.0, None)
    ('marginal', 'pass', 'fail', 'pass')
    >>> conformity(91.0, 90.0, 2.0, "min"), conformity(91.0, 90.0, None, "min"), conformity(87.0, 90.0, 2.0, "min")
    ('marginal', 'pass', 'fail')
    """
    u = expanded if expanded is not None and math.isfinite(expanded) else 0.0
    margin = limit - abs(value) if kind == "max_abs" else value - limit  # > 0 inside the limit
    if margin > u or (u == 0.0 and margin == 0.0):
        return "pass"
    if margin < -u:
        return "fail"
    return "marginal"


def rectangular(half_width: float) -> float:
    """Standard uncertainty of a quantity known only to lie within +-``half_width`` (GUM 4.3.7: a / sqrt(3)).

    Examples
    --------
    >>> round(rectangular(1.0), 4)
    0.5774
    """
    return half_width / math.sqrt(3.0)


def from_multiple(stated: float, k: float) -> float:
    """Standard uncertainty of a value stated as ``k`` standard deviations (GUM 4.3.3: stated / k).

    Examples
    --------
    A repeatability of 0.3 mm stated at 2 sigma:

    >>> from_multiple(0.3, 2.0)
    0.15
    """
    return stated / k


def sensitivity(f: Callable[[float], float], x: float, step: float) -> float:
    """Sensitivity coefficient df/dx at ``x``, evaluated numerically by the central difference
    (f(x + step) - f(x - step)) / (2 step) (GUM 5.1.3, Note 2); a component u(x) then contributes |c| u(x) (GUM
    5.1.3).

    Examples
    --------
    >>> round(sensitivity(lambda x: x * x, 3.0, 0.1), 6)
    6.0
    """
    return (f(x + step) - f(x - step)) / (2.0 * step)


def _normal_grid(points: int) -> tuple[np.ndarray, np.ndarray]:
    """``points`` values of a standard normal variable t evenly over +-6 and their weights (the density,
    normalized): the grid over which :func:`spread_sensitivity` and :func:`quantile_standard_error` take the
    standard deviation of a function of t (:func:`_normal_spread`) by a weighted sum instead of random draws."""
    t = np.linspace(-6.0, 6.0, points)
    density = np.exp(-0.5 * t**2)
    return t, density / np.sum(density)


def _normal_spread(values: np.ndarray, weights: np.ndarray) -> float:
    """The standard deviation of a function of t whose ``values`` at the points of :func:`_normal_grid` are given,
    with that grid's ``weights``."""
    return math.sqrt(float(weights @ (values - weights @ values) ** 2))


#: points and weights over which :func:`spread_sensitivity` averages: +-6 in steps of 0.25 (each point costs an
#: evaluation of f), a sum that takes a kink or a step of f within 1 % (the standard deviation of |t| or of a
#: rounded t, t standard normal; Gauss-Hermite quadrature of as many points misses a kink by 3 %)
_SPREAD_POINTS, _SPREAD_WEIGHTS = _normal_grid(49)


def spread_sensitivity(f: Callable[[float], float], x: float, u: float, step: float) -> float:
    """The magnitude of the sensitivity of ``f`` to an input ``x`` of standard uncertainty ``u``, over the input's
    own distribution: the standard deviation of f(x + u t), t standard normal, divided by u. This is the
    propagation of a normally distributed input through f (JCGM 101:2008, GUM Supplement 1, 5.9), with the
    expectation over t a weighted sum over ``_SPREAD_POINTS`` instead of random draws; a component of the input then
    contributes the returned value times its own standard uncertainty, as with :func:`sensitivity` (GUM 5.1.3),
    to which it reduces where f is linear over x +- a few u. Where f has kinks or steps within that range (a
    quantile over quantized values), a central difference sees only the part of f next to x; this sees the
    parts the input actually visits. Without a finite u > 0: |:func:`sensitivity`| with ``step``.

    Examples
    --------
    >>> round(spread_sensitivity(lambda x: 3.0 * x, 1.0, 0.2, 0.1), 6)
    3.0
    >>> round(spread_sensitivity(lambda x: abs(x), 0.0, 1.0, 0.1), 3)  # sd of |t|, t standard normal: 0.603
    0.608
    >>> spread_sensitivity(lambda x: abs(x), 0.0, 0.0, 0.1)  # the central difference at the kink
    0.0
    """
    if not (math.isfinite(u) and u > 0):
        return abs(sensitivity(f, x, step))
    return _normal_spread(np.array([f(x + u * t) for t in _SPREAD_POINTS]), _SPREAD_WEIGHTS) / u


def standard_error_of_mean(values: np.ndarray) -> float:
    """s / sqrt(n) over the finite ``values`` (GUM 4.2.3); NaN with fewer than two.

    Examples
    --------
    >>> standard_error_of_mean(np.array([1.0, 2.0, 3.0, 4.0, np.nan]))  # s = 1.291, n = 4
    0.6454972243679028
    """
    v = values[np.isfinite(values)]
    if v.size < 2:
        return math.nan
    return float(np.std(v, ddof=1) / math.sqrt(v.size))


def standard_error_of_std(std: float, n: int) -> float:
    """Standard uncertainty of a sample standard deviation ``std`` of ``n`` normal observations,
    std / sqrt(2 (n - 1)) (GUM E.4.3, Table E.1); NaN for n < 2.

    Examples
    --------
    >>> standard_error_of_std(1.0, 9)
    0.25
    """
    if n < 2:
        return math.nan
    return std / math.sqrt(2.0 * (n - 1))


def jackknife_standard_errors(statistics: Callable[[np.ndarray], Sequence[float]], n: int) -> tuple[float, ...]:
    """Jackknife standard errors of several statistics of the same ``n`` >= 2 observations (Efron & Tibshirani
    1993, eq. 11.5): sqrt((n - 1) / n sum_i (theta_(i) - theta_(.))^2) over the n values ``statistics(kept)``
    with observation i left out (``kept`` a boolean mask, false only at i). NaN where fewer than two are
    finite.

    Examples
    --------
    For the mean, the jackknife gives s / sqrt(n) exactly.

    >>> x = np.array([1.0, 2.0, 4.0, 8.0])
    >>> (se,) = jackknife_standard_errors(lambda kept: (float(x[kept].mean()),), x.size)
    >>> round(se, 9) == round(standard_error_of_mean(x), 9)
    True
    """
    if n < 2:
        raise ValueError(f"a jackknife needs at least two observations, got {n}")
    return delete_a_group_jackknife(np.array([statistics(np.arange(n) != i) for i in range(n)], dtype=float))


def contiguous_groups(n: int, groups: int) -> list[range]:
    """The ``n`` observations 0 .. n - 1 in ``groups`` contiguous groups whose sizes differ by one at most (the
    larger first): the groups of :func:`delete_a_group_jackknife`.

    Examples
    --------
    >>> contiguous_groups(7, 3)
    [range(0, 3), range(3, 5), range(5, 7)]
    """
    if not 1 <= groups <= n:
        raise ValueError(f"{groups} groups of {n} observations")
    bounds = np.cumsum([0] + [n // groups + (g < n % groups) for g in range(groups)])
    return [range(int(a), int(b)) for a, b in zip(bounds[:-1], bounds[1:])]


def delete_a_group_jackknife(replicates: np.ndarray) -> tuple[float, ...]:
    """Delete-a-group jackknife standard errors of K statistics from their (G, K) ``replicates``, row g the
    statistics with group g of the observations left out (Quenouille 1956, Tukey 1958; Efron & Tibshirani 1993,
    11.2 and eq. 11.5 for groups of one; Busing, Meijer & van der Leeden 1999 for groups of several):
    sqrt((G - 1) / G sum_g (theta_(g) - theta_(.))^2). The formula is that of groups of equal size; groups of
    :func:`contiguous_groups` differ by one observation at most. Replicates that are not finite (the statistic
    failed without the group) are left out, G then counting those that remain; NaN where fewer than two remain.

    Examples
    --------
    Six observations in three groups of two: the replicates of the mean are the means of the other four, and for
    groups of equal size the delete-a-group jackknife of the mean is the standard error of the mean of the
    group means, s_g / sqrt(G).

    >>> x = np.array([1.0, 2.0, 4.0, 8.0, 3.0, 5.0])
    >>> groups = contiguous_groups(x.size, 3)
    >>> replicates = np.array([[np.delete(x, list(g)).mean()] for g in groups])
    >>> (se,) = delete_a_group_jackknife(replicates)
    >>> group_means = np.array([x[list(g)].mean() for g in groups])
    >>> round(se, 9) == round(standard_error_of_mean(group_means), 9)
    True
    """
    out = []
    for v in np.asarray(replicates, dtype=float).reshape(len(replicates), -1).T:
        v = v[np.isfinite(v)]
        out.append(float(np.sqrt((v.size - 1) / v.size * np.sum((v - v.mean()) ** 2))) if v.size >= 2 else math.nan)
    return tuple(out)


#: points and weights over which :func:`quantile_standard_error` averages the quantile function: +-6 standard
#: deviations in 481 steps, fine enough for a quantile function that is a step function
_NORMAL_POINTS, _NORMAL_WEIGHTS = _normal_grid(481)
#: values closer than this (relative to the largest magnitude) count as one lattice value in
#: :func:`quantile_standard_error` (the same value computed along different paths differs in its last bits)
TIE_TOLERANCE = 1e-9


def _quantile_functions(values: np.ndarray) -> tuple[tuple[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]:
    """Knots (levels, values) of two quantile functions of the sorted, finite ``values``: NumPy's ``linear``
    (Hyndman & Fan 1996, definition 7; value k at level k / (n - 1)), and the continuized one, each distinct
    value's share spread evenly over its cell, from the midpoint to the value below to the midpoint to the
    value above (the first and last cells as wide on their outer side as on their inner)."""
    n = values.size
    linear = (np.arange(n) / max(n - 1, 1), values)
    scale = max(abs(float(values[0])), abs(float(values[-1])))
    starts = np.flatnonzero(np.concatenate([[True], np.diff(values) > TIE_TOLERANCE * scale]))
    distinct = values[starts]
    if distinct.size == 1:
        return linear, (np.array([0.0, 1.0]), np.array([distinct[0], distinct[0]]))
    levels = np.concatenate([[0.0], np.append(starts[1:], n) / n])
    mid = (distinct[1:] + distinct[:-1]) / 2
    edges = np.concatenate([[2 * distinct[0] - mid[0]], mid, [2 * distinct[-1] - mid[-1]]])
    return linear, (levels, edges)


def quantile_standard_error(values: np.ndarray, q: float, cdf_standard_error: float) -> float:
    """Standard uncertainty of the quantile ``q`` (NumPy's ``linear``) of the finite ``values`` from the standard
    uncertainty of the cumulative proportion at it, ``cdf_standard_error`` (u of the share of values at or below
    the quantile, e.g. its jackknife over the frames the values come from); NaN where that is not finite.

    The error of a sample quantile is that of the cumulative proportion at it, mapped through the quantile
    function (Bahadur's representation, Serfling 1980, 2.5; Woodruff 1952 turns a confidence interval of the
    proportion into one of the quantile in the same way, Francisco & Fuller 1991 show it consistent under a
    complex design): u is the standard deviation of Q(q + delta), delta normal with standard deviation
    ``cdf_standard_error``. For values of a continuous distribution this is cdf_standard_error / f(Q), f the
    density at the quantile. On a lattice (quantized output) the sample quantile function is a step function,
    and Q(q + delta) shows the jumps to the next lattice values that the quantile makes between repetitions
    when the proportion at a lattice value lies near q; deep inside one lattice value's share it shows none.
    The continuized quantile function, each lattice value's share spread over its cell (jittering, Machado &
    Santos Silva 2005), shows where within that cell the quantile of the statistic the lattice hides lies.
    u is the larger of the two: never 0 while the values differ (a lattice hides the quantile, it does not fix
    it), and the two are the same for values without ties.

    Examples
    --------
    100 000 normal values: the quantile 0.9 (1.28) moves by u_F / f(1.28) = u_F / 0.1755 for a proportion
    known to u_F; 0.005 gives 0.0285 (this sample's density near the quantile a little lower).

    >>> values = np.random.default_rng(2).normal(size=100_000)
    >>> round(quantile_standard_error(values, 0.9, 0.005), 4)
    0.0283

    Values on the integers, 1 the quantile 0.9 with 85 % of them below 1 and 10 % at it: the quantile stays on
    1 unless the proportion moves by 5 %, but the hidden quantile moves within 1's cell, 1 wide, by
    u_F / 0.10 (the share per unit).

    >>> lattice = np.repeat([0.0, 1.0, 2.0], [8500, 1000, 500])
    >>> round(quantile_standard_error(lattice, 0.9, 0.002), 4)
    0.02
    """
    v = np.sort(np.asarray(values, dtype=float).ravel())
    v = v[np.isfinite(v)]
    if not v.size or not math.isfinite(cdf_standard_error):
        return math.nan
    levels = np.clip(q + cdf_standard_error * _NORMAL_POINTS, 0.0, 1.0)
    spread = []
    for knots, at in _quantile_functions(v):
        g = np.interp(levels, knots, at)
        spread.append(_normal_spread(g, _NORMAL_WEIGHTS))
    return max(spread)
