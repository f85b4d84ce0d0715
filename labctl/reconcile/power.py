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
  p <= alpha, with its best dBIC, below, beside the statistics), or the round
  stops as "consistent";
* the dBIC: in every (step, family) cell c the fit takes up the signal the
  cell carries, so dBIC(A) = dBIC_0 + sum_c ln(1 + (A^2 q_c + 2 A x_c) /
  RSS_c), q_c = |u_c|^2 (the noncentrality of the fit), x_c = u_c . r_c the
  signature's product with the replica's whitened residual r_c there
  (``residual_rows``), RSS_c = |r_c|^2 (1 + ... is the cell's |r_c + A u_c|^2 /
  |r_c|^2), dBIC_0 the replica's own null dBIC of the candidate. The cross term
  is the replica's own, not a white-noise spread: a step's residual is not
  white. The effect must pass the critical value of the null replicas' best
  dBIC;
* the margin over a competitor: another candidate C fits of the effect's change
  u its projection w on C's signature columns (least squares, score.py), at the
  point of C's grid where that projection is largest. The two compete
  (``score.competing``) where the fitted changes correlate, |w| / |u| >=
  ``COMPETING_CORRELATION``, and then C's dBIC falls short of the effect's by
  what C cannot fit: dBIC(A) - dBIC_C(A) = dBIC_0 - dBIC_0,C + sum_c ln(1 +
  (A^2 |u_c - w_c|^2 + 2 A (u_c - w_c) . r_c) / RSS_c). A competitor built
  from the run's own residual (``fixed_pattern``: ``Candidate.rebind``) is
  rebuilt from the residual of a run carrying the effect (``_Rebuilt``). The
  effect is named only where the margin exceeds ``MARGIN`` against every
  competitor, the workflow's ambiguity rule (labctl/reconcile/workflow.py). A
  competitor whose signature reproduces the effect's, |w| = |u|, leaves no
  amplitude at which it is named: the effect is not separable from it in this
  campaign (``MinimumDetectable.rival``);
* materiality: fitting the effect away must remove at least
  ``MATERIAL_FRACTION`` of one residual statistic's excess over the null
  median (``NullCalibration.material``), here the replica's statistics with
  the effect back to its own.

The detection probability at A is the share of the replicas and of the
effect's directions (both signs; a two-part signature, a wiggling's sine and
cosine, at ``PHASES`` phases; one sign where the effect's parameter is bounded
at 0, an albedo or a level) in which the replica with the effect lies outside
the null, its dBIC passes the critical value, its margin over every
competitor ``MARGIN`` and fitting it is material; the amplitude where it
reaches ``POWER`` is found by bisection, at ``GRID_POINTS`` points spread evenly
over the candidate's grid of nonlinear parameters (a wiggling's period, a drift's
time constant). The
headline figure is the median over that grid; the detail gives the grid's
range and the parameters of the median point. What this does
not model: the separating steps' screen (labctl/reconcile/confounds.py) and the
leave-one-step-out check, which a named effect must pass as well; and
effects whose signature is built from the run's own residual (``fixed_pattern``)
have no amplitude to state.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from typing import Any

import numpy as np
from scipy import sparse

from labctl.reconcile.candidates import Candidate, Context, candidates_for
from labctl.reconcile.goodness import MATERIAL_FRACTION
from labctl.reconcile.null import NullCalibration, Replica, critical_value, p_values, standardized_max_rows
from labctl.reconcile.residuals import STATISTICS, Layout
from labctl.reconcile.results import MinimumDetectable
from labctl.reconcile.score import COMPETING_CORRELATION, MARGIN

#: the probability of naming the effect the figure promises (the contract's 90 %)
POWER = 0.9
#: the coefficient used to read an amplitude off a candidate's parameters (small: inside every solver bound)
PROBE = 1e-6
#: grid points evaluated per candidate, evenly spread over its grid (set by hand: a wiggling's grid has about 120
#: periods on the blaze-101's campaigns, 15 of them keep the cost to seconds)
GRID_POINTS = 15
#: the phases a two-part signature (a wiggling) is evaluated at, evenly over the circle (set by hand: 8 resolve the
#: variation of a sampled sine's power with its phase at a few times the cost of one)
PHASES = 8


def _unit(candidate: Candidate, ctx: Context, nonlinear: Any, k: int,
          n: int) -> tuple[str, float, tuple[float, ...]] | None:
    """The amplitude parameter column ``k`` of the candidate moves, by how much per unit coefficient, and the signs
    of the coefficient the candidate accepts (one where the parameter is bounded at 0; None when the column moves
    no scalar parameter in proportion)."""
    def params(scale: float) -> Any:
        coef = np.zeros(n)
        coef[k] = scale
        return candidate.to_params(ctx, coef, nonlinear)

    signs = tuple(sign for sign in (1.0, -1.0) if params(sign * PROBE) is not None)
    if not signs:
        return None
    values = [params(signs[0] * scale) for scale in (PROBE, 2 * PROBE)]
    if values[1] is None:
        return None
    for key, v in values[0].items():
        w = values[1].get(key)
        if isinstance(v, float) and isinstance(w, float) and v != 0 and math.isclose(w, 2 * v, rel_tol=1e-3):
            return key, abs(v) / PROBE, signs
    return None


class _Signal:
    """A candidate's signature at one grid point per unit amplitude: its whitened, profiled rows per part ``u``
    (parts, rows), their products per residual cell (``gram``, (cells, parts, parts)), per (step id, family) its
    unwhitened change, a map per part (a wiggling's sine and cosine are two parts, most signatures one), and the
    signs its amplitude may take."""

    def __init__(self, u: np.ndarray, cells: np.ndarray, maps: dict[tuple[str, str], list[np.ndarray]],
                 signs: tuple[float, ...], depth: list[np.ndarray] | None = None) -> None:
        self.u, self.cells, self.maps, self.signs = u, cells, maps, signs
        self.depth = depth or []  # per part its unwhitened stacked depth rows (mm), before the nuisance is profiled
        self.rows = np.bincount(cells, minlength=int(cells.max()) + 1 if len(cells) else 0)
        self.parts = len(u)
        self.gram = self.cell_gram(u)

    def cell_gram(self, v: np.ndarray) -> np.ndarray:
        """(cells, parts, parts): the products of the rows ``v`` (parts, rows) per residual cell."""
        n_cells = len(self.rows)
        on = np.flatnonzero(np.any(v != 0, axis=0))  # most signatures change the depth rows alone
        cells, v = self.cells[on], v[:, on]
        return np.stack([np.stack([np.bincount(cells, a * b, n_cells) for b in v], -1) for a in v], -2)


def _signal(candidate: Candidate, ctx: Context, lay: Layout, nonlinear: Any) -> tuple[str, _Signal] | None:
    columns = candidate.columns(ctx, nonlinear)
    if not columns:
        return None
    parts, key, signs = [], None, (1.0, -1.0)
    for k, column in enumerate(columns):
        unit = _unit(candidate, ctx, nonlinear, k, len(columns))
        if unit is None or (key is not None and unit[0] != key):
            continue
        key, per, signs = unit
        parts.append(tuple(rows / per for rows in column))
    if not parts:
        return None
    maps: dict[tuple[str, str], list[np.ndarray]] = {}
    for part in parts:
        for family, values, _ in _family_rows(lay, part):
            for o, m in zip(ctx.observations, lay.unstack(values, lay.family_masks(family)), strict=True):
                if np.isfinite(m).any():
                    maps.setdefault((o.scene.step_id, family), []).append(m)
    u = np.stack([lay.profiled_rows(*part) for part in parts])
    return key, _Signal(u, lay.row_cells(), maps, signs, [part[0] for part in parts])


class _Rivalry:
    """What a competitor C leaves of a signature (labctl/reconcile/score.py fits C's columns by least squares):
    its rows per part, u - w (P, rows), w the projection of u on C's columns, and per residual cell their products,
    (cells, P, P), made when first asked for (only a competitor that competes in some direction needs them); and
    the parts' products over all rows of u and of w, (P, P)."""

    def __init__(self, name: str, left: np.ndarray, signal: _Signal, u: np.ndarray, w: np.ndarray) -> None:
        self.name, self.left, self.u, self.w = name, left, u, w
        self._signal = signal
        self._rest: np.ndarray | None = None
        self.crossed: np.ndarray | None = None  # (replicas, P, cells): u - w with each replica's residual

    @property
    def rest(self) -> np.ndarray:
        """(cells, P, P): the products of u - w per residual cell."""
        if self._rest is None:
            self._rest = self._signal.cell_gram(self.left)
        return self._rest

    def competing(self, directions: np.ndarray) -> np.ndarray:
        """Per row a of ``directions``: does C's fit correlate with the effect's in direction a (``score.competing``:
        |w| / |u|)?"""
        total = np.einsum("dp,pq,dq->d", directions, self.u, directions)
        return (total > 0) & (np.einsum("dp,pq,dq->d", directions, self.w, directions)
                              >= COMPETING_CORRELATION**2 * total)

    def share(self) -> float:
        """The fraction of the signature's power C reproduces, over its parts."""
        return float(np.trace(self.w) / np.trace(self.u)) if np.trace(self.u) > 0 else 0.0


class _Rebuilt:
    """A competitor built from the run's own depth residual (``Candidate.rebind``: ``fixed_pattern``). In a run
    carrying the effect at amplitude A in direction a its columns are those of the residual r + A a.u, and they are
    linear in the residual, so its whitened, profiled columns are X_r + A sum_k a_k X_k: X_r built from this run's
    residual, X_k from part k of the signature alone. What it leaves of the effect's change follows with A: little
    where the run's own residual dominates its profiles, all that is not a column or row pattern where the effect
    does. Everything an amplitude and direction need is kept as products of the rows M = [u_1 .. u_P, X_r, X_1 ..
    X_P]: over all rows, per residual cell, and per cell with each replica's residual; what the fit leaves, u.a -
    x beta, is M v for a short vector v."""

    def __init__(self, candidate: Candidate, ctx: Context, lay: Layout, signal: _Signal,
                 replicas: _Replicas) -> None:
        assert candidate.rebind is not None
        self.name = candidate.name
        columns = [self._columns(candidate, ctx, lay)]
        columns += [self._columns(candidate.rebind(ctx, rows), ctx, lay) for rows in signal.depth]
        self.width = columns[0].shape[0]
        rows = np.vstack([signal.u, *columns])  # M', (P + 2 + 2 P, rows)
        self.gram = rows @ rows.T
        self.cell_gram = signal.cell_gram(rows)
        self.crossed = replicas.crosses(rows, signal.cells, len(signal.rows))
        self.parts = signal.parts

    @staticmethod
    def _columns(candidate: Candidate, ctx: Context, lay: Layout) -> np.ndarray:
        return np.vstack([lay.profiled_rows(*column) for column in candidate.columns(ctx, None)])

    def _left(self, a: np.ndarray, own: float, scale: float) -> tuple[np.ndarray, float, float]:
        """v with M v = u.a - x beta, x = own X_r + scale sum_k a_k X_k fitted to u.a by least squares; and |u.a|^2,
        |x beta|^2."""
        p, m = self.parts, self.width
        mix = np.zeros((len(self.gram), m))  # x = M mix
        for i, weight in enumerate([own, *(scale * a)]):
            mix[p + i * m:p + (i + 1) * m] = weight * np.eye(m)
        ua = np.concatenate([a, np.zeros(len(self.gram) - p)])
        beta = np.linalg.lstsq(mix.T @ self.gram @ mix, mix.T @ self.gram @ ua, rcond=None)[0]
        fitted = mix @ beta
        return ua - fitted, float(ua @ self.gram @ ua), float(fitted @ self.gram @ fitted)

    def left(self, amplitude: float, a: np.ndarray) -> np.ndarray | None:
        """v with M v what its least-squares fit leaves of the change ``a``.u at ``amplitude`` (per cell and per
        replica through ``cell_gram`` and ``crossed``), where the two compete (|w| / |u| >=
        ``COMPETING_CORRELATION``, ``score.competing``); None where they do not."""
        v, power, taken = self._left(a, 1.0, amplitude)
        return None if power == 0 or taken < COMPETING_CORRELATION**2 * power else v

    def share(self) -> float:
        """The fraction of the signature's power it reproduces where the effect dominates the run's residual (its
        columns built from the signature alone), over the signature's directions."""
        shares = []
        for a in phases(self.parts, (1.0, -1.0)):
            _, power, taken = self._left(a, 0.0, 1.0)
            shares.append(taken / power if power > 0 else 0.0)
        return float(np.mean(shares))


class _Bases:
    """A candidate's orthonormal bases at consecutive points of its grid whose columns change the same rows: those
    rows' indices, the bases side by side over them (rows, all the points' columns) and where each point's
    columns start."""

    def __init__(self, rows: np.ndarray, bases: list[np.ndarray]) -> None:
        self.rows = rows
        self.stacked = np.hstack(bases)
        self.bounds = np.cumsum([0, *(b.shape[1] for b in bases)])

    def basis(self, k: int) -> np.ndarray:
        """Point ``k``'s basis, (rows, its columns)."""
        return self.stacked[:, self.bounds[k]:self.bounds[k + 1]]

    def projected(self, u: np.ndarray) -> np.ndarray:
        """Per point, the squared norm of the projection on its basis of the parts ``u`` (P, rows), summed over
        the parts: one product for all the points."""
        return np.add.reduceat(np.sum((self.stacked.T @ u.T) ** 2, axis=1), self.bounds[:-1])


def _bases(candidate: Candidate, ctx: Context, lay: Layout) -> list[_Bases]:
    """Orthonormal bases of the candidate's whitened, profiled columns at every point of its grid where score.py
    can fit them (finite, of full rank), each on the rows the columns change (most change only the depth rows),
    consecutive points on the same rows together."""
    found: list[tuple[np.ndarray, np.ndarray]] = []
    for nonlinear in candidate.grid(ctx):
        columns = candidate.columns(ctx, nonlinear)
        if not columns:
            continue
        x = np.column_stack([lay.profiled_rows(*column) for column in columns])
        if np.all(np.isfinite(x)) and np.linalg.matrix_rank(x) == x.shape[1]:
            rows = np.flatnonzero(np.any(x != 0, axis=1))
            found.append((rows, np.linalg.qr(x[rows])[0]))
    out: list[_Bases] = []
    start = 0
    for end in range(1, len(found) + 1):
        if end == len(found) or not np.array_equal(found[end][0], found[start][0]):
            out.append(_Bases(found[start][0], [q for _, q in found[start:end]]))
            start = end
    return out


def _rivalries(signal: _Signal, bases: dict[str, list[_Bases]]) -> list[_Rivalry]:
    """Per other candidate, what it leaves of ``signal`` at the point of its grid that reproduces most of it (the
    first such point)."""
    out = []
    power = signal.u @ signal.u.T
    for name, groups in bases.items():
        best: tuple[float, _Bases, int] | None = None
        for group in groups:
            scores = group.projected(signal.u[:, group.rows])
            k = int(np.argmax(scores))
            if best is None or scores[k] > best[0]:
                best = (float(scores[k]), group, k)
        if best is None:
            continue
        _, group, k = best
        q, rows = group.basis(k), group.rows
        w = np.zeros_like(signal.u)
        w[:, rows] = (q @ (q.T @ signal.u[:, rows].T)).T
        out.append(_Rivalry(name, signal.u - w, signal, power, w @ w.T))
    return out


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


def residual_rows(null: NullCalibration, lay: Layout, step_ids: list[str]) -> np.ndarray:
    """(replicas, rows): each replica's residual maps (``Replica.maps``: goodness.residual_maps, the nuisance
    profiled out, in the families' units) on this run's rows of ``Layout.profiled_rows`` (steps ``step_ids``),
    whitened with this run's weights; 0 at a bin the replica did not compare. Laid out row by row (its transpose
    is contiguous): ``_Replicas.crosses`` takes every replica's value of a row at once, and each effect's
    ``_Replicas`` then shares this array instead of copying it."""
    def per_step(replica: Replica, family: str) -> list[np.ndarray]:
        maps = replica.maps.get(family, {})
        return [np.nan_to_num(np.asarray(maps[i], float)) if i in maps else np.zeros(m.shape)
                for i, m in zip(step_ids, lay.family_masks(family), strict=True)]

    return np.stack([lay.whitened(lay.stack_z(per_step(r, "depth")), lay.stack_i(per_step(r, "intensity")) / 100,
                                  lay.stack_statistics({f: per_step(r, f) for f in STATISTICS
                                                        if lay.family_masks(f)}) / 100)
                     for r in null.replicas], axis=1).T


class _Replicas:
    """The null replicas as arrays: step mean squares (``StepFit.mean_square``) and floors over a common (step,
    family) list, cell residual sums of squares, their residual rows, and the statistics of
    ``null.combined_statistics`` computed from them."""

    def __init__(self, null: NullCalibration, name: str, null_dbic: dict[str, np.ndarray], null_best: np.ndarray,
                 residual: np.ndarray, maps: list[tuple[np.ndarray, np.ndarray] | None] | None = None) -> None:
        self.alpha, self.threshold = null.alpha, critical_value(list(null_best), null.alpha)
        self.null_best = null_best  # each replica's best dBIC among the candidates in play
        # (rows, replicas): ``residual_rows`` transposed (a view of the array it returns, a copy of any other)
        self.residual_by_row = np.ascontiguousarray(residual.T)
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
        family_of = np.array([f for _, f in self.steps])
        self.family_columns = [np.flatnonzero(family_of == f) for f in self.families]
        self.rss = [np.asarray(r.cell_rss, float) for r in null.replicas]
        self._cell_rss: dict[int, np.ndarray] = {}
        self.null_dbic = null_dbic
        self.dbic0 = null_dbic[name]
        self.own = self.statistics(self.square)
        self.base = np.column_stack([self.own, null_best])
        self.median = np.nanmedian(_reported(self.own), axis=0)
        # per (step, family): the replicas' residual maps stacked (``maps``: those of another effect's arrays)
        self.residual_maps = maps if maps is not None else [
            _replica_maps([r.maps.get(family, {}).get(step_id) for r in null.replicas]) for step_id, family in self.steps]

    def statistics(self, square: np.ndarray) -> np.ndarray:
        """(..., replicas, statistics) of step mean squares (..., replicas, steps): per family the mean of the step
        mean squares, then the largest step ratio (gap = the root of the mean square clipped at 0)."""
        with np.errstate(invalid="ignore", divide="ignore"):
            columns = [np.nanmean(square[..., family], axis=-1) for family in self.family_columns]
            ratio = np.sqrt(np.maximum(square, 0.0)) / self.floor
            columns.append(np.nanmax(np.where(np.isfinite(ratio), ratio, np.nan), axis=-1))
        return np.stack(columns, axis=-1)

    def outside(self, moved: np.ndarray) -> np.ndarray:
        """Per replica j (and per leading index of ``moved``): is its row with the effect, ``moved[..., j, :]``
        (the statistics, then the best dBIC), outside the distribution of the K replicas (``standardized_max`` and
        ``p_value`` of labctl/reconcile/null.py, as the measured run is judged; replica j's own noise-only row
        stays among the K)?"""
        rows = moved.reshape(-1, moved.shape[-1])
        pools = np.concatenate([rows[:, None, :], np.broadcast_to(self.base, (len(rows), *self.base.shape))], axis=1)
        t = standardized_max_rows(pools)
        return (p_values(t) <= self.alpha).reshape(moved.shape[:-1])

    def material(self, moved: np.ndarray) -> np.ndarray:
        """Per replica j: would fitting the effect away be material (``NullCalibration.material``): its statistics
        with the effect, ``moved[j]`` (``statistics``), back to its own remove at least ``MATERIAL_FRACTION`` of
        one statistic's excess over the replicas' median (each family's as its signed root, as reconcile judges
        it)? An effect significant in its dBIC alone, whose change moves no statistic beyond the median, is not
        named (a vignetting of exponent 0.0024 on the test campaign: dBIC 7.3 against a critical 2.7, 0.05 % of
        the light at the image's corners)."""
        before, after = _reported(moved), _reported(self.own)
        excess = before - self.median
        with np.errstate(invalid="ignore"):
            return np.any((excess > 0) & (before - after >= MATERIAL_FRACTION * excess), axis=-1)

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
            stacked = self.residual_maps[i]
            if stacked is None:
                continue
            replicas, residual = stacked
            r = residual[:, seen]  # (replicas with a map, bins), NaN where the replica did not compare
            both = np.isfinite(r)
            counts = both.sum(axis=1)
            with np.errstate(invalid="ignore", divide="ignore"):
                crossed = np.where(both, r, 0.0) @ values.T / counts[:, None]
            compared = counts > 0
            cross[replicas[compared], i] = crossed[compared]
        return power, cross

    def crosses(self, v: np.ndarray, cells: np.ndarray, n_cells: int) -> np.ndarray:
        """(replicas, parts, ``n_cells``): the products of the rows ``v`` (parts, rows) with each replica's whitened
        residual (``residual_rows``), summed per residual cell: a signal's cross term with a replica's residual,
        which holds the replica's noise and what the model misses in every replica alike. A step's residual is
        not white (the reference's error moves all its bins, the spatially correlated noise its neighbours), so
        this cross term spreads far wider than the white noise's sum_c 4 A^2 q_c / (n_c RSS_c) (a temperature
        drift's dBIC over six seeds: 10.0-19.6)."""
        out = np.empty((len(self.base), len(v), n_cells))
        on = np.flatnonzero(np.any(v != 0, axis=0))
        for k, part in enumerate(v[:, on]):
            # the part's rows gathered per cell (a sparse (cells, rows) matrix, each cell's rows in order) times
            # every replica's residual at once: each cell's sum taken in the rows' order, as a bincount takes it
            per_cell = sparse.csr_array((part, (cells[on], on)), shape=(n_cells, self.residual_by_row.shape[0]))
            out[:, k] = (per_cell @ self.residual_by_row).T
        return out

    def probability(self, amplitude: float, signal: _Signal, crossed: tuple[np.ndarray, np.ndarray, np.ndarray],
                    rivals: list[_Rivalry], rebuilt: list[_Rebuilt]) -> float:
        """The probability that a replica carrying the effect at ``amplitude``, over the directions of ``phases``
        (each equally likely), is judged outside the null, the effect's dBIC passes the threshold and its margin
        over every competitor ``MARGIN``, and fitting it is material (``material``). ``crossed``: the statistics'
        power and cross terms (``crossing``) and the signature's cross terms with the replicas' residual rows
        (``crosses``)."""
        power, cross, dbic_cross = crossed
        a = np.array(phases(signal.parts, signal.signs))  # (directions, P)
        added = (amplitude**2 * np.einsum("sab,da,db->ds", power, a, a)[:, None, :]
                 + 2 * amplitude * np.einsum("jsp,dp->djs", cross, a))  # (directions, replicas, steps)
        gain = self.gain(amplitude, signal.gram, dbic_cross, a)  # (directions, replicas)
        chance = (self.dbic0 - self.threshold + gain > 0) & self.separated(amplitude, signal, a, rivals, rebuilt)
        moved = self.statistics(self.square + added)
        best = np.maximum(self.null_best, self.dbic0 + gain)
        hits = np.sum(chance & self.outside(np.concatenate([moved, best[..., None]], axis=-1)) & self.material(moved))
        return float(hits) / chance.size

    def separated(self, amplitude: float, signal: _Signal, a: np.ndarray, rivals: list[_Rivalry],
                  rebuilt: list[_Rebuilt]) -> np.ndarray:
        """Per replica (and per direction, where ``a`` holds one per row), whether the effect's dBIC in direction
        ``a`` exceeds every competitor's by ``MARGIN``: by its own null dBIC's excess over the competitor's and the
        gain of what the competitor cannot fit (those built from the run's residual, ``rebuilt``, at
        ``amplitude``)."""
        directions = np.atleast_2d(a)
        out = np.ones((len(directions), len(self.base)), bool)
        n_cells = len(signal.rows)
        for rival in rivals:
            competing = rival.competing(directions)
            if not competing.any():
                continue
            if rival.crossed is None:
                rival.crossed = self.crosses(rival.left, signal.cells, n_cells)
            gain = self.gain(amplitude, rival.rest, rival.crossed, directions[competing])
            out[competing] &= self.dbic0 - self.null_dbic[rival.name] - MARGIN + gain > 0
        for other in rebuilt:
            for d, direction in enumerate(directions):
                v = other.left(amplitude, direction)
                if v is not None:
                    gain = self.gain(amplitude, other.cell_gram, other.crossed, v)
                    out[d] &= self.dbic0 - self.null_dbic[other.name] - MARGIN + gain > 0
        return out if a.ndim > 1 else out[0]

    def cell_rss(self, cells: int) -> np.ndarray:
        """(replicas, ``cells``): each replica's residual sum of squares per cell, repeated to ``cells``, at least
        1e-300."""
        if cells not in self._cell_rss:
            self._cell_rss[cells] = np.stack([np.maximum(np.resize(r, cells), 1e-300) for r in self.rss])
        return self._cell_rss[cells]

    def gain(self, amplitude: float, gram: np.ndarray, crossed: np.ndarray, a: np.ndarray) -> np.ndarray:
        """Per replica j, sum_c ln(1 + (A^2 p_c + 2 A x_jc) / RSS_jc) for the signal a . rows, of rows whose
        products are ``gram`` per cell (cells, P, P) and ``crossed`` with each replica's residual (``crosses``,
        (replicas, P, cells)): p_c its power in cell c, x_jc its cross term with the replica's residual there. The
        fall of the cells' log residual sum of squares when a fit takes up that signal: 1 + (A^2 p + 2 A x) / RSS
        is the cell's |r + A u|^2 / |r|^2 (at least 0; kept above 1e-300 where the whitening of this run and the
        replica's differ). ``a`` may hold one direction per row: then per direction and replica."""
        power = np.einsum("cab,...a,...b->...c", gram, a, a)[..., None, :]
        cross = np.einsum("jpc,...p->...jc", crossed, a)
        rss = self.cell_rss(gram.shape[0])
        return np.sum(np.log(np.maximum(1 + (amplitude**2 * power + 2 * amplitude * cross) / rss, 1e-300)), axis=-1)


def _replica_maps(maps: list[np.ndarray | None]) -> tuple[np.ndarray, np.ndarray] | None:
    """The replicas that hold a residual map of one (step, family), by index, and their maps stacked as float64,
    (replicas, bins); None where none does."""
    present = [j for j, m in enumerate(maps) if m is not None]
    if not present:
        return None
    return np.array(present), np.stack([np.asarray(maps[j], float) for j in present])


def _reported(statistics: np.ndarray) -> np.ndarray:
    """``_Replicas.statistics`` as reconcile.json reports them (``null.step_statistics``): each family's mean of
    its steps' mean squares as its signed root, the largest step ratio as it is."""
    families = statistics[..., :-1]
    return np.concatenate([np.sign(families) * np.sqrt(np.abs(families)), statistics[..., -1:]], axis=-1)


def phases(parts: int, signs: tuple[float, ...] = (1.0, -1.0)) -> list[np.ndarray]:
    """The directions an effect of amplitude A takes in its signature's parts, equally likely: the ``signs`` of a
    one-part signature (a range error of either sign; one where the parameter is bounded at 0); ``PHASES``
    phases of a two-part one (a wiggling's sine and cosine: cos phi, sin phi); both signs of each part
    otherwise."""
    if parts == 2:
        return [np.array([math.cos(phi), math.sin(phi)]) for phi in 2 * math.pi * np.arange(PHASES) / PHASES]
    if parts == 1:
        return [np.array([sign]) for sign in signs]
    return [sign * row for row in np.eye(parts) for sign in (1.0, -1.0)]


def _amplitude(signal: _Signal, replicas: _Replicas, rivals: list[_Rivalry], rebuilt: list[_Rebuilt]) -> float:
    """The amplitude detected with probability ``POWER`` (inf when none within 1e6 times the first guess)."""
    total = float(np.einsum("cpp->", signal.gram)) / signal.parts  # the parts' mean power
    if not total > 0 or not math.isfinite(replicas.threshold):
        return math.inf  # no signature, or too few replicas for any dBIC to pass (K + 1 < 1 / alpha): never named
    crossed = (*replicas.crossing(signal), replicas.crosses(signal.u, signal.cells, len(signal.rows)))
    lo, hi = 0.0, 1.0 / math.sqrt(total)
    while replicas.probability(hi, signal, crossed, rivals, rebuilt) < POWER:
        lo, hi = hi, hi * 2
        if hi > 1e6 / math.sqrt(total):
            return math.inf
    for _ in range(12):  # the bracket [hi / 2, hi] to 0.03 % of the amplitude
        mid = 0.5 * (lo + hi)
        lo, hi = (lo, mid) if replicas.probability(mid, signal, crossed, rivals, rebuilt) >= POWER else (mid, hi)
    return hi


def detectable(ctx: Context, lay: Layout, null: NullCalibration) -> dict[str, MinimumDetectable]:
    """Per candidate effect of the first round: the amplitude parameter, the amplitude named with probability
    ``POWER`` (median over the candidate's grid), the grid's range of it and the parameters at the median point."""
    in_play = {n for r in null.replicas for n in r.delta_bic}
    null_best = np.array(null.null_best(in_play))
    candidates = list(candidates_for(ctx))
    residual = residual_rows(null, lay, [o.scene.step_id for o in ctx.observations])
    null_dbic = {c.name: np.array([r.delta_bic.get(c.name, -c.n_params * math.log(lay.n_steps))
                                   for r in null.replicas]) for c in candidates}
    bases = {c.name: _bases(c, ctx, lay) for c in candidates if c.rebind is None}
    from_residual = [c for c in candidates if c.rebind is not None]
    out: dict[str, MinimumDetectable] = {}
    maps = None
    for candidate in candidates:
        replicas = _Replicas(null, candidate.name, null_dbic, null_best, residual, maps)
        maps = replicas.residual_maps
        found = []
        grid = candidate.grid(ctx)
        for nonlinear in [grid[int(i)] for i in np.unique(np.linspace(0, len(grid) - 1, GRID_POINTS).round())]:
            signal = _signal(candidate, ctx, lay, nonlinear)
            if signal is None:
                continue
            key, s = signal
            rivals = _rivalries(s, {n: b for n, b in bases.items() if n != candidate.name})
            rebuilt = [_Rebuilt(c, ctx, lay, s, replicas) for c in from_residual
                       if c.name != candidate.name and s.depth]
            amplitude = _amplitude(s, replicas, rivals, rebuilt)
            shares = [(r.share(), r.name) for r in [*rivals, *rebuilt]]
            closest = max(shares, default=(0.0, None))
            rival = closest[1] if closest[0] >= COMPETING_CORRELATION**2 else None
            found.append((amplitude, key, nonlinear, rival))
        if not found:
            continue
        found.sort(key=lambda f: f[0])
        amplitude, key, nonlinear, rival = found[(len(found) - 1) // 2]
        finite = [f[0] for f in found if math.isfinite(f[0])]
        at = candidate.to_params(ctx, np.eye(len(candidate.columns(ctx, nonlinear)))[0] * PROBE, nonlinear) or {}
        out[candidate.name] = MinimumDetectable(
            parameter=key, amplitude=_round(amplitude),
            grid_min=_round(min(finite)) if finite else None, grid_max=_round(max(finite)) if finite else None,
            grid_points=len(found), at={k: v for k, v in at.items() if k != key and not isinstance(v, list)},
            rival=rival)
    return out


def _round(value: float) -> float | None:
    return float(f"{value:.3g}") if math.isfinite(value) else None


def detectable_message(found: dict[str, MinimumDetectable]) -> str:
    """What a ``none`` verdict promises: no effect above its minimum detectable amplitude; and the effects this
    campaign cannot tell from a competitor at any amplitude."""
    parts = [f"{name} above {d.amplitude:g} ({d.parameter})" for name, d in sorted(found.items())
             if d.amplitude is not None]
    apart = [f"{name} from {d.rival}" for name, d in sorted(found.items()) if d.amplitude is None and d.rival]
    message = ("with 90 % probability this campaign would have named: no " + ", no ".join(parts)
               + " (minimum detectable amplitudes, the median over each effect's searched nonlinear parameters)"
               if parts else "no minimum detectable amplitude could be stated")
    return message + ("; not separable in this campaign at any amplitude: " + ", ".join(apart) if apart else "")
