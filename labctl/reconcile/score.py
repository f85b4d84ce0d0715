"""Scoring a candidate effect: penalized likelihood at the level of steps, cross-validated by step.

With the nuisance profiled out and the residuals whitened (r, one row per
usable bin), a candidate's signature columns S are fitted by least squares at
every grid point of its nonlinear parameter. Neighbouring bins of one step
share the step's conditions (one exposure, one pose, one warm-up state), so
the independent replications are the steps, not the bins: each step is one
observation with its own residual scale (a step that another, still missing
effect disturbs must not drown the evidence elsewhere), and the score is the
Bayesian information criterion improvement counted over the n steps:

    dBIC = sum_s sum_f ln(RSS_0,sf / RSS_1,sf) - k ln(n)        (Schwarz 1978)

with f the residual family (depth, intensity, noise, validity, correlation:
each with its own scale) and k
the effect's free parameters. Leave-one-step-out cross-validation
checks that the fit predicts each step from the others (closed form for the
linear fit: theta_-s = (A - A_s)^-1 (b - b_s) with A = S'S, b = S'r).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy import optimize

from labctl.reconcile.candidates import Candidate, Column, Context
from labctl.reconcile.residuals import FAMILIES, Layout
from labctl.reconcile.results import Parameters

#: a runner-up within 10 of the winner's dBIC (Kass & Raftery 1995: a BIC difference above 10 is "very strong"
#: evidence) cannot be told from it
MARGIN = 10.0
#: candidates whose fitted changes correlate at least this much explain the same part of the residual (set by hand)
COMPETING_CORRELATION = 0.5


@dataclass(frozen=True)
class Fit:
    """The best linear fit of a candidate over its grid."""

    name: str
    params: Parameters
    score: float  # dBIC over steps
    rss0: float
    rss1: float
    loso_gain: float  # 1 - held-out RSS with the effect / held-out RSS without it
    stderr: list[float]  # standard errors of the linear coefficients
    signature: np.ndarray  # fitted change of the whitened residual vector (S theta)
    nonlinear: Any = None  # the grid point the fit is at (``Candidate.grid``)


def competing(a: Fit, b: Fit) -> bool:
    """Whether two candidates explain the same part of the residual (their fitted changes correlate)."""
    norm = float(np.linalg.norm(a.signature) * np.linalg.norm(b.signature))
    return norm > 0 and abs(float(a.signature @ b.signature)) / norm >= COMPETING_CORRELATION


def delta_bic(rss0: np.ndarray, rss1: np.ndarray, n_params: int, n_steps: int) -> float:
    """Schwarz's criterion improvement counted over independent steps (residual sums of squares per step
    and family)."""
    used = rss0 > 0
    if n_steps < 2:
        return -math.inf
    return float(np.sum(np.log(rss0[used] / np.maximum(rss1[used], 1e-300)))) - n_params * math.log(n_steps)


def cell_rss(r: np.ndarray, fitted: np.ndarray, columns: np.ndarray, rss0: np.ndarray, lay: Layout,
             steps: np.ndarray) -> np.ndarray:
    """The RSS of ``r - fitted`` per (step, family) cell (``Layout.row_cells``), ``fitted`` being ``columns`` times
    finite coefficients. A family whose rows the columns leave at zero keeps its cells of ``rss0`` (the RSS of
    ``r``: r - 0 is r), and the others are summed over their own rows only, in the same order, so that the
    result is the same as summing over all rows."""
    out = rss0.copy()
    families = len(FAMILIES)
    for k, rows in enumerate(lay.family_rows()):
        if np.any(columns[rows]):
            rest = r[rows] - fitted[rows]
            out[k::families] = np.bincount(steps[rows], rest * rest, lay.n_steps)
    return out


def loso_gain(columns: np.ndarray, r: np.ndarray, steps: np.ndarray, n_steps: int) -> float:
    """Relative reduction of the held-out RSS when each step is predicted by the fit to the others
    (over the rows the candidate changes)."""
    touched = np.any(columns != 0, axis=1)
    columns, r, steps = columns[touched], r[touched], steps[touched]
    k = columns.shape[1]
    a_s = np.stack([np.stack([np.bincount(steps, columns[:, i] * columns[:, j], n_steps) for j in range(k)], -1)
                    for i in range(k)], -2)  # (n, k, k)
    b_s = np.stack([np.bincount(steps, columns[:, i] * r, n_steps) for i in range(k)], -1)  # (n, k)
    ss0 = np.bincount(steps, r * r, n_steps)
    a, b = a_s.sum(0), b_s.sum(0)
    held_out = 0.0
    for s in range(n_steps):
        try:
            theta = np.linalg.solve(a - a_s[s], b - b_s[s])
        except np.linalg.LinAlgError:
            theta = np.zeros(k)
        held_out += ss0[s] - 2 * theta @ b_s[s] + theta @ a_s[s] @ theta
    total = float(ss0.sum())
    return 1.0 - held_out / total if total > 0 else 0.0


@dataclass(frozen=True)
class Beside:
    """Effects already named, free to move beside a candidate: their residual's slopes S (rows x parameters) and
    (S'S)^+. What they could take up is taken out of the candidate's columns by least squares (Frisch-Waugh-Lovell),
    from the products C'S alone: a candidate is credited only with what it explains once they are refitted with
    it."""

    slopes: np.ndarray
    gram_inverse: np.ndarray

    @classmethod
    def of(cls, slopes: np.ndarray) -> Beside:
        return cls(slopes, np.linalg.pinv(slopes.T @ slopes))

    def out_of(self, rows: np.ndarray) -> np.ndarray:
        """``rows`` (a vector, or columns) less their least-squares fit by the slopes."""
        return rows - self.slopes @ (self.gram_inverse @ (self.slopes.T @ rows))


def dropped_dbic(without: np.ndarray, joint: np.ndarray, beside: Beside | None, lay: Layout, n_params: int) -> float:
    """A named effect's evidence once the others are named: the dBIC (over steps, as ``score`` counts it) of the
    joint model's whitened residual ``joint`` against ``without``, the one the model without the effect leaves,
    with the other named effects' slopes (``beside``) taken out of both, as a candidate is credited beside them.
    The backward step of stepwise selection (Miller 2002, chapter 3): an effect named while another was missing
    may carry that one's residual, and once the other is named explain nothing of its own."""
    if beside is not None:
        without, joint = beside.out_of(without), beside.out_of(joint)
    cells = lay.row_cells()
    return delta_bic(np.bincount(cells, without * without, lay.n_cells), np.bincount(cells, joint * joint, lay.n_cells),
                     n_params, lay.n_steps)


def _profiled_columns(signature: list[Column], lay: Layout) -> np.ndarray:
    """A candidate's signature columns with the nuisance profiled out and whitened (``Layout.profiled_rows``): of a
    signature that changes the depth alone only its depth rows, the first of every row (the others are zero)."""
    if all(len(column) == 2 and not np.any(column[1]) for column in signature):
        return np.column_stack([lay.profiled_depth(column[0]) for column in signature])
    return np.column_stack([lay.profiled_rows(*column) for column in signature])


def _normal_equations(signature: list[Column], lay: Layout, r: np.ndarray, beside: Beside | None
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]:
    """The least-squares fit of ``r`` by a candidate's signature columns: the columns (``_profiled_columns``: a
    depth signature's over the depth rows alone, every other row zero), C'C and C'r; with ``beside``, C'C of the
    columns less their fit by the named effects' slopes S, and C'S. C'r needs no such change: r is orthogonal to
    S."""
    columns = _profiled_columns(signature, lay)
    rows = slice(0, len(columns))
    a, b = columns.T @ columns, columns.T @ r[rows]
    cs = None
    if beside is not None:
        cs = columns.T @ beside.slopes[rows]
        a = a - cs @ beside.gram_inverse @ cs.T
    return columns, a, b, cs


def score(candidate: Candidate, ctx: Context, lay: Layout, r: np.ndarray, beside: Beside | None = None) -> Fit | None:
    """The candidate at its best grid point (None when no physically valid fit exists), its linear coefficients as
    the candidate may take them (``Candidate.clip``); with ``beside``, the named effects refitted beside it (``r``
    already has their slopes taken out, ``Beside.out_of``)."""
    n = lay.n_steps
    steps = lay.row_steps()
    cells = lay.row_cells()  # (step, family): each family's residuals of a step have their own scale
    rss0 = np.bincount(cells, r * r, lay.n_cells)
    best: tuple[float, np.ndarray, np.ndarray, Parameters, Any] | None = None
    for nonlinear in candidate.grid(ctx):
        # a grid point whose signature sends a compared bin dark holds rows of +-max float (``finite_difference``:
        # an infinite log ratio); its products overflow, and the point is passed over below
        with np.errstate(over="ignore", invalid="ignore"):
            columns, a, b, cs = _normal_equations(candidate.columns(ctx, nonlinear), lay, r, beside)
        rows = slice(0, len(columns))
        if not np.all(np.isfinite(a)) or np.linalg.matrix_rank(a) < a.shape[0]:
            continue
        coef = candidate.clip(np.linalg.solve(a, b))
        params = candidate.to_params(ctx, coef, nonlinear)
        if params is None:
            continue
        fitted = np.full(len(r), 0.0 if np.all(np.isfinite(coef)) else np.nan)  # (0 times an infinite one: NaN)
        fitted[rows] = columns @ coef
        if beside is not None:
            fitted = fitted - beside.slopes @ (beside.gram_inverse @ (cs.T @ coef))
        if np.all(np.isfinite(coef)):
            rss1 = cell_rss(r, fitted, fitted[:, None], rss0, lay, steps)
        else:  # 0 times an infinite coefficient is NaN: every row changes
            rss1 = np.bincount(cells, (r - fitted) ** 2, lay.n_cells)
        value = delta_bic(rss0, rss1, candidate.n_params, n)
        if best is None or value > best[0]:
            best = (value, coef, columns, params, nonlinear)
    if best is None:
        return None
    value, coef, columns, params, nonlinear = best
    if len(columns) < len(r):
        columns = np.concatenate([columns, np.zeros((len(r) - len(columns), columns.shape[1]))])
    if beside is not None:
        columns = beside.out_of(columns)
    rest = r - columns @ coef
    rss1 = float(rest @ rest)
    dof = max(len(r) - columns.shape[1], 1)
    cov = np.linalg.inv(columns.T @ columns) * rss1 / dof
    return Fit(candidate.name, params, value, float(rss0.sum()), rss1, loso_gain(columns, r, steps, n),
               [float(v) for v in np.sqrt(np.diag(cov))], columns @ coef, nonlinear)


#: the polished grid point's tolerance, as a share of the span between the best point's neighbours
POLISH_TOLERANCE = 1e-3


def polished(candidate: Candidate, fit: Fit, ctx: Context, lay: Layout, r: np.ndarray,
             beside: Beside | None = None) -> Parameters:
    """The candidate's parameters with its nonlinear parameter, where that is one number, searched between the grid
    points beside ``fit``'s (Brent's bounded search, Brent 1973, ch. 5, of the linear fit's whitened residual sum
    of squares, with ``beside`` as ``score`` takes it): the start of its fit on full re-simulations
    (``workflow.refine``), nearer the optimum than a grid point (the wiggling's period grid steps a quarter cycle
    over the compared ranges' span). ``fit``'s own parameters where the search finds nothing better or the
    candidate does not take its coefficients there."""
    grid = candidate.grid(ctx)
    if not all(isinstance(v, (int, float)) for v in grid) or fit.nonlinear not in grid or len(grid) < 2:
        return fit.params
    i = grid.index(fit.nonlinear)
    left, right = sorted((grid[max(i - 1, 0)], grid[min(i + 1, len(grid) - 1)]))

    def linear_fit(nonlinear: float) -> tuple[float, np.ndarray]:
        with np.errstate(over="ignore", invalid="ignore"):
            _, a, b, _ = _normal_equations(candidate.columns(ctx, nonlinear), lay, r, beside)
            if not np.all(np.isfinite(a)) or np.linalg.matrix_rank(a) < a.shape[0]:
                return math.inf, np.zeros(a.shape[0])
            coef = candidate.clip(np.linalg.solve(a, b))
            rss = float(r @ r - 2 * coef @ b + coef @ a @ coef)
        return (rss, coef) if math.isfinite(rss) else (math.inf, coef)

    found = optimize.minimize_scalar(lambda v: linear_fit(v)[0], bounds=(left, right), method="bounded",
                                     options={"xatol": POLISH_TOLERANCE * (right - left)})
    rss, coef = linear_fit(float(found.x))
    if not rss < linear_fit(fit.nonlinear)[0]:
        return fit.params
    return candidate.to_params(ctx, coef, float(found.x)) or fit.params
