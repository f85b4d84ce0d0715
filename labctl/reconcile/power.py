"""Minimum detectable effects: the amplitude of each library effect this campaign names with 90 % probability.

A candidate's signature per unit of its amplitude (the change of the whitened,
profiled residual rows, labctl/reconcile/candidates.py and score.py) is added
to each null replica (labctl/reconcile/null.py) in thought:

* the residual statistics: each step's mean square in family f (``StepFit.
  mean_square``, unclipped) grows by A^2 m_sf + 2 A c_sf, m_sf the mean square
  of the unwhitened signature over the step's bins (depth in mm, intensity in
  %, the statistics families in their units) and c_sf its mean product with
  the replica's own residual there (``goodness.residual_maps``). The cross
  term is not only noise: the residual of every replica holds what the model's
  prediction misses of the simulator alike, and a signature that runs against
  it adds less than its power (a wiggling at a 275 mm period on the test
  campaign: 0.025 of its 0.031 mm^2). The replica with the effect must then lie
  outside the other replicas' distribution (``NullCalibration.judge``'s rule,
  p <= alpha), or the round stops as "consistent";
* the dBIC: in every (step, family) cell c the residual sum of squares falls by
  the signal it carries, A^2 q_c, q_c = |u_c|^2 (the noncentrality of the fit),
  so dBIC(A) = dBIC_0 + sum_c ln(1 + A^2 q_c / RSS_c), with dBIC_0 the replica's
  own null dBIC of the candidate and RSS_c its cell's residual sum of squares;
  the cross term of signal and noise adds a normal spread of variance
  sum_c 4 A^2 q_c / (n_c RSS_c) (n_c rows; each logarithm linearized). The
  effect is named when dBIC(A) passes the critical value of the null replicas'
  best dBIC.

The detection probability at A is the mean over the replicas and over the
effect's directions (both signs; a two-part signature, a wiggling's sine and
cosine, at ``PHASES`` phases) of [outside the null] x P(dBIC(A) > critical
value); the amplitude where it
reaches ``POWER`` is found by bisection, at ``GRID_POINTS`` points spread evenly
over the candidate's grid of nonlinear parameters (a wiggling's period, a drift's
time constant). The
headline figure is the median over that grid; the detail gives the grid's
range and the parameters of the median point. The dBIC's gain counts a
two-part signature with its parts' mean power. What this does
not model: the ambiguity margin against a competing candidate, the leave-one-step-
out check and the materiality rule, which a named effect must pass as well; and
effects whose signature is built from the run's own residual (``fixed_pattern``)
have no amplitude to state.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from typing import Any

import numpy as np
from scipy.stats import norm

from labctl.reconcile.candidates import Candidate, Context, candidates_for
from labctl.reconcile.null import NullCalibration, critical_value, p_value, standardized_max
from labctl.reconcile.residuals import STATISTICS, Layout
from labctl.reconcile.results import MinimumDetectable

#: the probability of naming the effect the figure promises (the contract's 90 %)
POWER = 0.9
#: the coefficient used to read an amplitude off a candidate's parameters (small: inside every solver bound)
PROBE = 1e-6
#: grid points evaluated per candidate, evenly spread over its grid (set by hand: a wiggling's grid has 90 periods,
#: 15 of them keep the cost to seconds)
GRID_POINTS = 15
#: the phases a two-part signature (a wiggling) is evaluated at, evenly over the circle (set by hand: 8 resolve the
#: variation of a sampled sine's power with its phase at a few times the cost of one)
PHASES = 8


def _unit(candidate: Candidate, ctx: Context, nonlinear: Any, k: int, n: int) -> tuple[str, float] | None:
    """The amplitude parameter column ``k`` of the candidate moves and by how much per unit coefficient (None when
    the column moves no scalar parameter in proportion)."""
    values = []
    for scale in (PROBE, 2 * PROBE):
        coef = np.zeros(n)
        coef[k] = scale
        params = candidate.to_params(ctx, coef, nonlinear)
        if params is None:
            coef[k] = -scale
            params = candidate.to_params(ctx, coef, nonlinear)
        values.append(params)
    if values[0] is None or values[1] is None:
        return None
    for key, v in values[0].items():
        w = values[1].get(key)
        if isinstance(v, float) and isinstance(w, float) and v != 0 and math.isclose(w, 2 * v, rel_tol=1e-3):
            return key, abs(v) / PROBE
    return None


class _Signal:
    """A candidate's signature at one grid point per unit amplitude: its power per residual cell (averaged over its
    parts), and per (step id, family) its unwhitened change, a map per part (a wiggling's sine and cosine are two
    parts, most signatures one)."""

    def __init__(self, q: np.ndarray, rows: np.ndarray, maps: dict[tuple[str, str], list[np.ndarray]]) -> None:
        self.q, self.rows, self.maps = q, rows, maps
        self.parts = len(next(iter(maps.values()))) if maps else 1


def _signal(candidate: Candidate, ctx: Context, lay: Layout, nonlinear: Any) -> tuple[str, _Signal] | None:
    columns = candidate.columns(ctx, nonlinear)
    if not columns:
        return None
    cells = lay.row_cells()
    n_cells = int(cells.max()) + 1 if len(cells) else 0
    parts, key = [], None
    for k, column in enumerate(columns):
        unit = _unit(candidate, ctx, nonlinear, k, len(columns))
        if unit is None or (key is not None and unit[0] != key):
            continue
        key, per = unit
        parts.append(tuple(rows / per for rows in column))
    if not parts:
        return None
    q = np.zeros(n_cells)
    maps: dict[tuple[str, str], list[np.ndarray]] = {}
    for part in parts:
        w = lay.profiled_rows(*part)
        q += np.bincount(cells, w * w, n_cells) / len(parts)
        for family, values, _ in _family_rows(lay, part):
            for o, m in zip(ctx.observations, lay.unstack(values, lay.family_masks(family)), strict=True):
                if np.isfinite(m).any():
                    maps.setdefault((o.scene.step_id, family), []).append(m)
    return key, _Signal(q, np.bincount(cells, minlength=n_cells), maps)


def _family_rows(lay: Layout, column: tuple[np.ndarray, ...]) -> Iterator[tuple[str, np.ndarray, np.ndarray]]:
    """A signature column's change per residual family, in the unit of the family's step gaps (labctl/reconcile/
    goodness.py: mm; % of the intensity; % or percentage points of the statistics), with each row's step."""
    dz, di, *statistics = column
    yield "depth", lay.profile_z(dz), lay.z_step
    yield "intensity", 100 * lay.profile_i(di), lay.i_step
    if statistics:
        start = 0
        for family in STATISTICS:
            steps = lay.s_step.get(family, np.zeros(0, int))
            yield family, 100 * statistics[0][start:start + len(steps)], steps
            start += len(steps)


class _Replicas:
    """The null replicas as arrays: step mean squares (``StepFit.mean_square``) and floors over a common (step,
    family) list, cell residual sums of squares, and the statistics of ``null.step_statistics`` computed from
    them."""

    def __init__(self, null: NullCalibration, name: str, n_params: int, n_steps: int, threshold: float) -> None:
        self.alpha, self.threshold = null.alpha, threshold
        self.steps = sorted({(s.step_id, s.family) for r in null.replicas for s in r.steps})
        index = {k: i for i, k in enumerate(self.steps)}
        k, n = len(null.replicas), len(self.steps)
        self.square, self.floor = np.full((k, n), np.nan), np.full((k, n), np.nan)
        for j, r in enumerate(null.replicas):
            for s in r.steps:
                if math.isfinite(s.gap):
                    self.square[j, index[(s.step_id, s.family)]] = s.mean_square
                self.floor[j, index[(s.step_id, s.family)]] = s.floor
        self.families = sorted({f for _, f in self.steps})
        self.family_of = np.array([f for _, f in self.steps])
        self.rss = [np.asarray(r.cell_rss, float) for r in null.replicas]
        self.dbic0 = np.array([r.delta_bic.get(name, -n_params * math.log(n_steps)) for r in null.replicas])
        self.base = self.statistics(self.square)
        self.maps = [[r.maps.get(family, {}).get(step_id) for r in null.replicas] for step_id, family in self.steps]

    def statistics(self, square: np.ndarray) -> np.ndarray:
        """(replicas, statistics): per family the signed root of the mean of the step mean squares, then the largest
        step ratio (gap = the root of the mean square clipped at 0)."""
        with np.errstate(invalid="ignore", divide="ignore"):
            mean = [np.nanmean(np.where(self.family_of == f, square, np.nan), axis=1) for f in self.families]
            columns = [np.sign(m) * np.sqrt(np.abs(m)) for m in mean]
            ratio = np.sqrt(np.maximum(square, 0.0)) / self.floor
            columns.append(np.nanmax(np.where(np.isfinite(ratio), ratio, np.nan), axis=1))
        return np.stack(columns, axis=1)

    def outside(self, moved: np.ndarray) -> np.ndarray:
        """Per replica j: is its statistics row with the effect, ``moved[j]``, outside the distribution of the K
        replicas (``standardized_max`` and ``p_value`` of labctl/reconcile/null.py, as the measured run is judged;
        replica j's own noise-only row stays among the K)?"""
        base = [dict(enumerate(row)) for row in self.base]
        out = np.zeros(len(base), bool)
        for j, row in enumerate(moved):
            t = standardized_max([dict(enumerate(row)), *base])
            out[j] = p_value(t[0], t[1:]) <= self.alpha
        return out

    def crossing(self, signal: _Signal) -> tuple[np.ndarray, np.ndarray]:
        """Per (step, family) of ``steps``: the signature parts' mean products over the step's bins, (steps, P, P),
        and per replica their mean products with its residual there, (replicas, steps, P). The step mean square
        of a replica carrying the effect at amplitude A along parts a is its own plus A^2 a'Ma + 2 A a'C: the
        second term is the cross of the signature with the replica's residual, which holds, besides noise, what
        the model misses in every replica alike (the prediction's own approximation), and may add to the signal
        or take from it."""
        parts = signal.parts
        power = np.zeros((len(self.steps), parts, parts))
        cross = np.zeros((len(self.base), len(self.steps), parts))
        for i, step in enumerate(self.steps):
            maps = signal.maps.get(step)
            if maps is None:
                continue
            seen = np.isfinite(maps[0])
            values = np.stack([m[seen] for m in maps])  # (P, bins)
            power[i] = values @ values.T / seen.sum()
            for j, residual in enumerate(self.maps[i]):
                if residual is None:
                    continue
                r = residual[seen].astype(float)
                both = np.isfinite(r)
                if both.any():
                    cross[j, i] = values[:, both] @ r[both] / both.sum()
        return power, cross

    def probability(self, amplitude: float, signal: _Signal, crossed: tuple[np.ndarray, np.ndarray]) -> float:
        """The probability that a replica carrying the effect at ``amplitude``, over the directions of ``phases``
        (each equally likely), is judged outside the null and the effect's dBIC passes the threshold."""
        power, cross = crossed
        named = self.named(amplitude, signal)
        directions = phases(signal.parts)
        hits = 0.0
        for a in directions:
            added = amplitude**2 * np.einsum("sab,a,b->s", power, a, a) + 2 * amplitude * cross @ a
            hits += float(np.sum(named[self.outside(self.statistics(self.square + added))]))
        return hits / (len(self.base) * len(directions))

    def named(self, amplitude: float, signal: _Signal) -> np.ndarray:
        """Per replica, the probability that the effect's dBIC at ``amplitude`` passes the threshold (the same in
        every direction: the gain counts the parts' mean power)."""
        q, use = signal.q, signal.q > 0
        out = np.zeros(len(self.base))
        for j in range(len(self.base)):
            rss = np.maximum(np.resize(self.rss[j], len(q)), 1e-300)
            gain = float(np.sum(np.log1p(amplitude**2 * q[use] / rss[use])))
            var = float(np.sum(4 * amplitude**2 * q[use] / (np.maximum(signal.rows[use], 1) * rss[use])))
            dbic = self.dbic0[j] + gain
            out[j] = float(norm.cdf((dbic - self.threshold) / math.sqrt(var))) if var > 0 else float(
                dbic > self.threshold)
        return out


def phases(parts: int) -> list[np.ndarray]:
    """The directions an effect of amplitude A takes in its signature's parts, equally likely: both signs of a
    one-part signature (a range error of either sign); ``PHASES`` phases of a two-part one (a wiggling's sine
    and cosine: cos phi, sin phi); both signs of each part otherwise."""
    if parts == 2:
        return [np.array([math.cos(phi), math.sin(phi)]) for phi in 2 * math.pi * np.arange(PHASES) / PHASES]
    return [sign * row for row in np.eye(parts) for sign in (1.0, -1.0)]


def _amplitude(signal: _Signal, replicas: _Replicas) -> float:
    """The amplitude detected with probability ``POWER`` (inf when none within 1e6 times the first guess)."""
    total = float(np.sum(signal.q))
    if not total > 0:
        return math.inf
    crossed = replicas.crossing(signal)
    lo, hi = 0.0, 1.0 / math.sqrt(total)
    while replicas.probability(hi, signal, crossed) < POWER:
        lo, hi = hi, hi * 2
        if hi > 1e6 / math.sqrt(total):
            return math.inf
    for _ in range(12):  # the bracket [hi / 2, hi] to 0.03 % of the amplitude
        mid = 0.5 * (lo + hi)
        lo, hi = (lo, mid) if replicas.probability(mid, signal, crossed) >= POWER else (mid, hi)
    return hi


def detectable(ctx: Context, lay: Layout, null: NullCalibration) -> dict[str, MinimumDetectable]:
    """Per candidate effect of the first round: the amplitude parameter, the amplitude named with probability
    ``POWER`` (median over the candidate's grid), the grid's range of it and the parameters at the median point."""
    in_play = {n for r in null.replicas for n in r.delta_bic}
    threshold = critical_value(null.null_best(in_play), null.alpha)
    out: dict[str, MinimumDetectable] = {}
    for candidate in candidates_for(ctx):
        replicas = _Replicas(null, candidate.name, candidate.n_params, lay.n_steps, threshold)
        found = []
        grid = candidate.grid(ctx)
        for nonlinear in [grid[int(i)] for i in np.unique(np.linspace(0, len(grid) - 1, GRID_POINTS).round())]:
            signal = _signal(candidate, ctx, lay, nonlinear)
            if signal is None:
                continue
            key, s = signal
            amplitude = _amplitude(s, replicas)
            found.append((amplitude, key, nonlinear))
        if not found:
            continue
        found.sort(key=lambda f: f[0])
        amplitude, key, nonlinear = found[(len(found) - 1) // 2]
        finite = [f[0] for f in found if math.isfinite(f[0])]
        at = candidate.to_params(ctx, np.eye(len(candidate.columns(ctx, nonlinear)))[0] * PROBE, nonlinear) or {}
        out[candidate.name] = MinimumDetectable(
            parameter=key, amplitude=_round(amplitude),
            grid_min=_round(min(finite)) if finite else None, grid_max=_round(max(finite)) if finite else None,
            grid_points=len(found), at={k: v for k, v in at.items() if k != key and not isinstance(v, list)})
    return out


def _round(value: float) -> float | None:
    return float(f"{value:.3g}") if math.isfinite(value) else None


def detectable_message(found: dict[str, MinimumDetectable]) -> str:
    """What a ``none`` verdict promises: no effect above its minimum detectable amplitude."""
    parts = [f"{name} above {d.amplitude:g} ({d.parameter})" for name, d in sorted(found.items())
             if d.amplitude is not None]
    return ("with 90 % probability this campaign would have named: no " + ", no ".join(parts)
            + " (minimum detectable amplitudes, the median over each effect's searched nonlinear parameters)"
            if parts else "no minimum detectable amplitude could be stated")
