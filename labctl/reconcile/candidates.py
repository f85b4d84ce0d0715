"""Candidate effects and their signatures: what each would change in the simulated output.

The candidates are built from the effects' own declarations (``EFFECT.observed``
in each sim/effects module): the signature form (``FORMS``), the parameters
the fit sets, the steps that show the effect and how many it needs. The
solver's bounds are the parameters' valid ranges (``bounds``), or the bounds
the effect states for its solver. An effect whose declaration names no
signature is not a candidate; its ``why_not`` is noted (``NOT_IDENTIFIABLE``).

A signature is the change of the binned prediction per unit of the effect's
linear parameter, per step, in depth (mm) and in log intensity. Effects that
act after the render have closed-form signatures from the base prediction
(the formulas of their sim/effects modules, linearized where needed); effects
that move the geometry are differentiated by re-simulating with the effect
switched on (finite difference, the ``resimulated`` form, which suits any
effect linear in one parameter; in the residual families the effect's
declaration names, ``Observed.families``: an effect on the noise, such as
``ambient_light``, changes the predicted temporal noise and valid fraction,
and is scored and fitted on those families like any other). Nonlinear parameters (a wiggling period, a
disparity bias period, a drift time constant, a multipath extra path, a
bouncing plane and its distance) are searched on a grid, the linear ones
solved for at each grid point. A candidate with ``bind`` is built from the run itself (its signature
depends on the run's residual: ``fixed_pattern``; or its form is chosen by
it: the number of ``temperature_drift`` time constants).

``fixed_pattern`` has a range offset per pixel: far more parameters than the
comparison can determine. It is fitted as a column profile (one value per
bin column) plus a row profile (one per bin row), the additive fit of the
residual over all steps; its mean is the constant offset the nuisance takes.
A step's signature is the profiles fitted to the other steps (out of sample),
with two linear parameters, the gains of the two profiles. What it can see:
the bin means of column and row structure that is the same at every distance
and pose. What it cannot: a single column's own offset (it averages with the
other columns of its bin), a per-pixel random map (it averages out within a
bin), bins never compared (the image border, edges: their offset is left 0),
and structure that is neither a column nor a row pattern.

``radial_distortion`` corrected in the cloud (``cloud = false``) and
``fov_error`` leave depth and the point cloud right (the camera's calibration
knows its optics); only feature positions in the intensity image move, which
the checkerboard corners show (labctl/reconcile/corners.py).
"""

from __future__ import annotations

import math
import typing
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from labctl.reconcile.observe import Observation
from labctl.reconcile.predict import Prediction, Predictor, pixels_damping
from labctl.reconcile.residuals import STATISTICS, Layout, raw_residuals, step_rows
from labctl.reconcile.results import Parameters
from sim.effects import EFFECTS, Effect, valid_range
from sim.effects.floor_multipath import PLANES
from sim.materials import get_material
from sim.model import SimModel
from sim.render import C_MM_PER_S
from sim.scenes.targets import PLATE_MATERIALS
from sim.tof import reference_amplitude

#: change of the stacked depth rows and log-intensity rows (Layout order), and optionally of the statistics rows
#: (``Layout.stack_statistics``: ln noise, valid fraction, ln correlation)
Column = tuple[np.ndarray, ...]
_T = typing.TypeVar("_T")


def unique_columns(a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The distinct columns of the 2-d array ``a``, sorted, and the index of each column of ``a`` among them: what
    ``np.unique(a, axis=1, return_inverse=True)`` gives, by one lexicographic sort of the rows."""
    order = np.lexsort(a[::-1])
    ordered = a[:, order]
    first = np.ones(a.shape[1], dtype=bool)
    first[1:] = np.any(ordered[:, 1:] != ordered[:, :-1], axis=0)
    inverse = np.empty(a.shape[1], dtype=np.intp)
    inverse[order] = np.cumsum(first) - 1
    return ordered[:, first], inverse


@dataclass
class Context:
    """Everything a signature may use: the run's observations and the current model's predictions."""

    observations: list[Observation]
    predictions: list[Prediction]
    model: SimModel
    make_predictor: Callable[[SimModel], Predictor]
    t0_s: float
    lay: Layout
    _stacks: dict[str, Any] = field(default_factory=dict)

    @property
    def technology(self) -> str:
        return self.model.profile().technology

    def z_rows(self, attr: str) -> np.ndarray:
        """A prediction map stacked over the depth rows (cached)."""
        if attr not in self._stacks:
            self._stacks[attr] = self.lay.stack_z([np.broadcast_to(getattr(p, attr), p.z.shape)
                                                  for p in self.predictions])
        return self._stacks[attr]

    def z_rows_of_map(self, image: np.ndarray) -> np.ndarray:
        """A map of the bin grid (the same for every step) stacked over the depth rows."""
        return self.lay.stack_z([np.broadcast_to(image, p.z.shape) for p in self.predictions])

    def points(self) -> np.ndarray:
        """(3, rows) camera-frame point of every depth row: the predicted range along the bin's ray (cached)."""
        if "points" not in self._stacks:
            optics = self.make_predictor(self.model).sensor.geometry.optics
            rays = optics.directions(*optics.pixel_grid())
            ranges = np.nan_to_num(self.z_rows("range_mm"))
            self._stacks["points"] = np.stack([self.z_rows_of_map(rays[i]) * ranges for i in range(3)])
        return self._stacks["points"]

    def mirrored_points(self, axis: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The distinct points among ``points`` and their mirror images across the camera's plane normal to its
        axis ``axis`` (0: x, 1: y; that coordinate's sign flipped), (3, n), with the index among them of each
        depth row's point and of its mirror image (cached). Steps that see the same surface where they share a
        bin share a point (a plate of each material at one robot angle), and the points of a wall square to the
        optical axis are mirror images of each other."""
        key = f"mirrored {axis}"
        if key not in self._stacks:
            points = self.points()
            mirror = points.copy()
            mirror[axis] = -mirror[axis]
            union, inverse = unique_columns(np.concatenate([points, mirror], axis=1))
            self._stacks[key] = union
            self._stacks[f"{key} rows"], self._stacks[f"{key} images"] = np.split(inverse, 2)
        return self._stacks[key], self._stacks[f"{key} rows"], self._stacks[f"{key} images"]

    def cached(self, key: str, compute: Callable[[], _T]) -> _T:
        """``compute()``, once per context and ``key``."""
        if key not in self._stacks:
            self._stacks[key] = compute()
        return self._stacks[key]

    def per_step(self, values: np.ndarray) -> np.ndarray:
        """One value per step spread over that step's depth rows."""
        return np.asarray(values)[self.lay.z_step]

    def no_intensity(self) -> np.ndarray:
        return np.zeros(len(self.lay.i_step))

    def finite_difference(self, name: str, params: Parameters, step_filter: Callable[[Observation], bool],
                          scale: float, families: tuple[str, ...] = ("depth", "intensity")) -> Column:
        """(prediction with the effect switched on - current prediction) / ``scale``, on the steps it touches, in
        ``families`` (the statistics families' rows are added when one of them is named)."""
        effects = {**self.model.effects, name: params}
        predictor = self.make_predictor(self.model.model_copy(update={"effects": effects}))
        zeros = [np.zeros_like(p.z) for p in self.predictions]
        dz, di = list(zeros), list(zeros)
        stats = {f: list(zeros) for f in STATISTICS if f in families}
        shifts = predictor.wall_shifts(self.observations, self.t0_s)
        for s, (obs, base) in enumerate(zip(self.observations, self.predictions, strict=True)):
            if not step_filter(obs):
                continue
            p = predictor.predict(obs.scene, obs.times_s - self.t0_s, shifts.get(obs.scene.step_id, 0.0))
            with np.errstate(invalid="ignore", divide="ignore"):
                if "depth" in families:
                    dz[s] = np.nan_to_num((p.z - base.z) / scale)
                if "intensity" in families:
                    di[s] = np.nan_to_num((np.log(p.intensity) - np.log(base.intensity)) / scale)
                changes = {"noise": np.log(p.noise_mm) - np.log(base.noise_mm), "validity": p.valid_rate - base.valid_rate,
                           "correlation": np.log(p.correlation) - np.log(base.correlation)}
            for f in stats:
                stats[f][s] = np.nan_to_num(changes[f] / scale)
        if stats:
            return self.lay.stack_z(dz), self.lay.stack_i(di), self.lay.stack_statistics(stats)
        return self.lay.stack_z(dz), self.lay.stack_i(di)


@dataclass(frozen=True)
class Candidate:
    """One effect of the library as the reconcile workflow tests it."""

    name: str
    technologies: tuple[str, ...]
    n_params: int  # free parameters (linear and nonlinear), for the BIC penalty
    grid: Callable[[Context], list[Any]]  # nonlinear parameter values (None: a purely linear candidate)
    columns: Callable[[Context, Any], list[Column]]
    to_params: Callable[[Context, np.ndarray, Any], Parameters | None]
    vector: Callable[[Parameters], tuple[np.ndarray, tuple[np.ndarray, np.ndarray]]]
    from_vector: Callable[[np.ndarray], Parameters]
    applies: Callable[[Context], bool] = field(default=lambda ctx: True)
    bind: Callable[[Context], Candidate] | None = None  # builds the candidate from the run (its signatures)
    #: a candidate whose signature is the run's depth residual (``fixed_pattern``): the candidate built from other
    #: stacked depth residual rows instead (the minimum detectable effect builds it from an effect's change)
    rebind: Callable[[Context, np.ndarray], Candidate] | None = None
    #: the linear coefficients as the fit may take them (``score``): a single coefficient beyond its bound held at
    #: the bound, which for one parameter is the least-squares optimum within the bounds
    clip: Callable[[np.ndarray], np.ndarray] = field(default=lambda c: c)


def _none(_: Context) -> list[float | None]:
    return [None]


def _depth(ctx: Context, rows: np.ndarray) -> Column:
    return np.nan_to_num(rows), ctx.no_intensity()


def bounds(effect: Effect, key: str) -> tuple[float, float]:
    """The solver's bounds of parameter ``key``: the effect's ``solver_bounds``, else its valid range."""
    if key in effect.observed.solver_bounds:
        return effect.observed.solver_bounds[key]
    return valid_range(effect.params, key)


def _wrap(angle: float) -> float:
    """An angle in [-pi, pi)."""
    return float((angle + math.pi) % (2 * math.pi) - math.pi)


# one linear parameter: the fitted coefficient is the parameter, held within its bounds (a signature linearized at
# zero can overshoot a bound it would not reach on full re-simulation: a strong barrel distortion's corners), and
# ``fixed`` set beside it; held at a bound of zero it is no effect at all, and no fit
def _linear(effect: Effect, columns: Callable[[Context, Any], list[Column]],
            applies: Callable[[Context], bool] = lambda ctx: True) -> Candidate:
    key, fixed = effect.observed.fitted[0], dict(effect.observed.fixed)
    lo, hi = bounds(effect, key)
    return Candidate(
        effect.name, effect.technologies, 1, _none, columns,
        lambda ctx, c, _: {key: float(c[0]), **fixed} if lo <= c[0] <= hi and c[0] != 0 else None,
        lambda p: (np.array([p[key]]), (np.array([lo]), np.array([hi]))),
        lambda x: {key: float(x[0]), **fixed},
        applies=applies,
        clip=lambda c: np.clip(c, lo, hi),
    )


# several linear parameters: the fitted coefficients are the parameters (each within its bounds)
def _linear_terms(effect: Effect, columns: Callable[[Context, Any], list[Column]]) -> Candidate:
    keys = effect.observed.fitted
    lo, hi = (np.array(v) for v in zip(*(bounds(effect, k) for k in keys)))
    return Candidate(
        effect.name, effect.technologies, len(keys), _none, columns,
        lambda ctx, c, _: dict(zip(keys, map(float, c))) if np.all((lo <= c) & (c <= hi)) else None,
        lambda p: (np.array([p[k] for k in keys]), (lo, hi)),
        lambda x: dict(zip(keys, map(float, x))),
    )


# proportional_range: r' = r (1 + scale)  ->  dz = z per unit scale
def _proportional_range(effect: Effect) -> Candidate:
    return _linear(effect, lambda ctx, _: [_depth(ctx, ctx.z_rows("z"))])


# inverse_light: dr = e A_ref / A (light before vignetting)
def _inverse_light_columns(ctx: Context, _: float | None) -> list[Column]:
    a_ref = reference_amplitude(ctx.model.profile())
    light = ctx.z_rows("light")
    with np.errstate(divide="ignore", invalid="ignore"):
        return [_depth(ctx, np.where(light > 0, a_ref / light, 0.0) * ctx.z_rows("z_per_range"))]


def _inverse_light(effect: Effect) -> Candidate:
    return _linear(effect, _inverse_light_columns)


# log_light_polynomial: dr = sum_i c_i x^i, x = log10(A / A_ref) (light before vignetting), one coefficient per
# fitted parameter (i = 1, 2, ...)
def _log_light_polynomial(effect: Effect) -> Candidate:
    def columns(ctx: Context, _: Any) -> list[Column]:
        light = ctx.z_rows("light")
        with np.errstate(divide="ignore", invalid="ignore"):
            x = np.where(light > 0, np.log10(light / reference_amplitude(ctx.model.profile())), 0.0)
        ratio = ctx.z_rows("z_per_range")
        return [_depth(ctx, x ** (i + 1) * ratio) for i in range(len(effect.observed.fitted))]

    return _linear_terms(effect, columns)


# log_cos_alpha: ln A' = ln A + exponent ln cos(alpha)
def _log_cos_alpha_columns(ctx: Context, _: float | None) -> list[Column]:
    log_cos = ctx.lay.stack_i([np.broadcast_to(np.log(p.cos_alpha), p.z.shape) for p in ctx.predictions])
    return [(np.zeros(len(ctx.lay.z_step)), log_cos)]


def _log_cos_alpha(effect: Effect) -> Candidate:
    return _linear(effect, _log_cos_alpha_columns)


# resimulated: the change of the prediction with the effect switched on at ``probe``, on the steps that show it
def _translucent(o: Observation) -> bool:
    material = o.scene.target if o.scene.target in PLATE_MATERIALS else None
    names = [material] if material else {"boehler_star": ["ptfe"], "face_mask": ["silicone"]}.get(o.scene.target, [])
    return any(get_material(n).subsurface_bias_mm != 0 for n in names)


def _on_robot(o: Observation) -> bool:
    return o.scene.target in PLATE_MATERIALS


#: which steps show an effect (``Observed.steps``), and those steps as the notes name them
STEPS: dict[str, tuple[Callable[[Observation], bool], str]] = {
    "all": (lambda o: True, "steps"), "translucent": (_translucent, "steps of translucent targets"),
    "robot_plates": (_on_robot, "steps of the material plates on the robot")}


def _steps_shown(effect: Effect, ctx: Context) -> int:
    """How many of the run's steps show the effect (``Observed.steps``)."""
    shows, _ = STEPS[effect.observed.steps]
    return sum(shows(o) for o in ctx.observations)


def _resimulated(effect: Effect) -> Candidate:
    seen = effect.observed
    (shows, _), probe = STEPS[seen.steps], {seen.fitted[0]: seen.probe, **seen.fixed}
    return _linear(
        effect, lambda ctx, _: [ctx.cached(f"finite difference {effect.name}", lambda: ctx.finite_difference(
            effect.name, probe, shows, seen.probe, seen.families))],
        applies=lambda ctx: _steps_shown(effect, ctx) >= seen.min_steps,
    )


# A periodic candidate's period is searched at even steps of its frequency 1/P, a quarter cycle over the span S of
# the value it acts on in the compared rows apart: a grid point then slips at most an eighth of a cycle against the
# true period from one end of the span to the other, and its linear fit keeps sinc(1/8) = 0.97 of the change's
# amplitude where the values spread evenly over the span. A grid even in log P slips most at the short periods,
# whose peak is narrowest (its width about P / S of P).
#: grid steps per cycle of slip over the span (a quarter cycle apart: 4)
STEPS_PER_CYCLE = 4
#: a grid's end within this share of the searched range's end is taken as reaching it (rounding of the steps)
END_TOLERANCE = 1e-9


def even_frequency_periods(shortest: float, longest: float, span: float, anchor: float) -> list[float]:
    """The periods from ``shortest`` to ``longest`` at even steps of 1/P, 1 / (``STEPS_PER_CYCLE`` ``span``) apart,
    ``anchor`` among them (where it lies between), ascending; ``shortest`` and ``longest`` themselves where the
    steps miss them, so that no period between lies more than half a step from the grid."""
    step = 1.0 / (STEPS_PER_CYCLE * span)
    lo, hi, at = 1.0 / longest, 1.0 / shortest, 1.0 / anchor
    frequencies = at + step * np.arange(math.ceil((lo - at) / step), math.floor((hi - at) / step) + 1)
    if not frequencies.size or frequencies[0] > lo * (1 + END_TOLERANCE):
        frequencies = np.concatenate([[lo], frequencies])
    if frequencies[-1] < hi * (1 - END_TOLERANCE):
        frequencies = np.concatenate([frequencies, [hi]])
    return [float(1.0 / f) for f in frequencies[::-1]]


# periodic_range: dr = a sin(2 pi r / P) + b cos(2 pi r / P), each bin the mean over its pixels (``pixels_damping``
# of the range's slopes across the bin); the period searched from SHORTEST_RANGE_PERIOD_MM to the span of the
# compared rows' ranges (at least LONGEST_RANGE_PERIOD_MM), even steps of 1/P. The seed 44417 of ``python -m
# bench.reconcile_sbc 40 --pairs 40 --seed 2`` (3.04 mm at 312 mm on the test campaign) scored dBIC 27 at the
# nearest point of the earlier grid (90 periods even in log P over every reported bin's ranges, 0.4-10.5 m where
# the compared rows span 0.4-4.9 m: 2.2 % off) and 138 at its own period.
#: the shortest period searched, mm (set by hand: under the c / (8 f_mod) = 375 mm the blaze-101 aliases its
#: modulation's harmonics to, and the shortest the library's calibration draws, bench/reconcile_sbc.py)
SHORTEST_RANGE_PERIOD_MM = 150.0
#: the longest period searched however short the span, mm (set by hand: twice the shortest)
LONGEST_RANGE_PERIOD_MM = 300.0


def _span(values: np.ndarray) -> float:
    """The span of the finite ``values`` (the compared rows' value a periodic candidate acts on), 0 without any."""
    values = values[np.isfinite(values)]
    return float(values.max() - values.min()) if values.size else 0.0


def _periodic_range_grid(ctx: Context) -> list[float]:
    span = _span(ctx.z_rows("range_mm"))
    longest = max(span, LONGEST_RANGE_PERIOD_MM)
    return even_frequency_periods(SHORTEST_RANGE_PERIOD_MM, longest, max(span, 1.0), longest)


def _periodic_range_columns(ctx: Context, period: float | None) -> list[Column]:
    k = 2 * math.pi / float(period)
    phase = k * ctx.z_rows("range_mm")
    across_pixels = pixels_damping(k, (ctx.z_rows("range_slope_down"), ctx.z_rows("range_slope_across")),
                                   ctx.observations[0].bin_px)
    ratio = ctx.z_rows("z_per_range") * across_pixels
    return [_depth(ctx, np.sin(phase) * ratio), _depth(ctx, np.cos(phase) * ratio)]


def _periodic_range(effect: Effect) -> Candidate:
    keys = effect.observed.fitted  # amplitude, period, phase
    (a_lo, a_hi), (p_lo, p_hi), (f_lo, f_hi) = (bounds(effect, k) for k in keys)

    def to_params(ctx: Context, c: np.ndarray, period: float | None) -> Parameters | None:
        amplitude = float(np.hypot(c[0], c[1]))
        return {keys[0]: amplitude, keys[1]: float(period), keys[2]: float(math.atan2(c[1], c[0]))} \
            if amplitude <= a_hi else None

    return Candidate(
        effect.name, effect.technologies, 3, _periodic_range_grid, _periodic_range_columns, to_params,
        lambda p: (np.array([p[k] for k in keys]), (np.array([a_lo, p_lo, f_lo]), np.array([a_hi, p_hi, f_hi]))),
        lambda x: {keys[0]: float(x[0]), keys[1]: float(x[1]), keys[2]: _wrap(x[2])},
    )


# warm_up: dr = delta exp(-t / tau) (+ delta_2 exp(-t / tau_2)), t since the run's first frame.
# A second time constant is scored only where the run asks for it: the candidate is bound to the run by
# comparing the best one- and two-term fits with Schwarz's criterion over steps (as score.py counts it);
# if two terms win by TWO_TERM_EVIDENCE (strong evidence on the Kass & Raftery 1995 scale is > 6), the
# candidate is the two-term form with its 4 parameters, otherwise the one-term form with 2.
TWO_TERM_EVIDENCE = 10.0
TWO_TERM_MIN_RATIO = 2.0  # the two time constants must differ by this factor
#: the shortest warm-up time constant the grid searches (48 points in log up to the bound's upper end), set by
#: hand: a faster drift has settled before the first steps of a campaign are captured
SHORTEST_TAU_SEARCHED_S = 10.0


def _drift_rows(ctx: Context, tau: float) -> np.ndarray:
    """The frames' mean exp(-t / tau) of each step, spread over its depth rows (range -> z)."""
    factor = [float(np.mean(np.exp(-(o.times_s - ctx.t0_s) / float(tau)))) if len(o.times_s) else 0.0
              for o in ctx.observations]
    return ctx.per_step(factor) * ctx.z_rows("z_per_range")


def _drift_columns(ctx: Context, taus: Any) -> list[Column]:
    return [_depth(ctx, _drift_rows(ctx, tau)) for tau in (taus if isinstance(taus, tuple) else (taus,))]


def _warm_up(effect: Effect) -> Candidate:
    delta_key, tau_key, terms_key = effect.observed.fitted
    d_lo, d_hi = bounds(effect, delta_key)
    t_lo, t_hi = bounds(effect, tau_key)

    def grid(_: Context) -> list[Any]:
        return list(np.geomspace(SHORTEST_TAU_SEARCHED_S, t_hi, 48))

    def outside(c: np.ndarray) -> bool:
        return bool(np.any((c < d_lo) | (c > d_hi)))

    def to_params(_: Context, c: np.ndarray, taus: Any) -> Parameters | None:
        taus = taus if isinstance(taus, tuple) else (taus,)
        if outside(c):
            return None
        params: Parameters = {delta_key: float(c[0]), tau_key: float(taus[0])}
        if len(taus) > 1:
            params[terms_key] = [{delta_key: float(c[1]), tau_key: float(taus[1])}]
        return params

    def vector(p: Parameters) -> tuple[np.ndarray, tuple[np.ndarray, np.ndarray]]:
        terms = [(p[delta_key], p[tau_key])] + [(t[delta_key], t[tau_key]) for t in p.get(terms_key, [])]
        x = np.array([v for delta, tau in terms for v in (delta, math.log(tau))])
        lo = np.tile([d_lo, math.log(t_lo)], len(terms))
        hi = np.tile([d_hi, math.log(t_hi)], len(terms))
        return x, (lo, hi)

    def from_vector(x: np.ndarray) -> Parameters:
        params: Parameters = {delta_key: float(x[0]), tau_key: float(math.exp(x[1]))}
        if len(x) > 2:
            params[terms_key] = [{delta_key: float(x[i]), tau_key: float(math.exp(x[i + 1]))}
                                 for i in range(2, len(x), 2)]
        return params

    def bind(ctx: Context) -> Candidate:
        """The one- or two-term candidate, whichever the run's depth residual supports."""
        lay = ctx.lay
        dz, di = raw_residuals(ctx.observations, ctx.predictions)
        r = np.nan_to_num(lay.profiled(dz, di))[:len(lay.z_step)]  # the depth rows (drift leaves intensity alone)
        taus = grid(ctx)
        cols = np.column_stack([lay.profile_z(_drift_rows(ctx, tau)) * np.sqrt(lay.z_weight) for tau in taus])
        per_step = step_rows(lay.z_step, lay.n_steps)
        gram = np.stack([cols[k].T @ cols[k] for k in per_step])
        cross = np.stack([cols[k].T @ r[k] for k in per_step])
        rss0 = np.array([r[k] @ r[k] for k in per_step])
        used = rss0 > 0

        def log_rss(idx: list[int]) -> float | None:
            """Sum over steps of ln RSS with the drift terms ``idx`` fitted (None: no valid fit)."""
            g = gram[:, idx][:, :, idx]
            try:
                theta = np.linalg.solve(g.sum(0), cross[:, idx].sum(0))
            except np.linalg.LinAlgError:
                return None
            if outside(theta):
                return None
            rss = rss0 - 2 * cross[:, idx] @ theta + np.einsum("i,sij,j->s", theta, g, theta)
            return float(np.sum(np.log(np.maximum(rss[used], 1e-300))))

        singles = [v for v in (log_rss([i]) for i in range(len(taus))) if v is not None]
        pairs = [((taus[i], taus[j]), log_rss([i, j])) for i in range(len(taus)) for j in range(i + 1, len(taus))
                 if taus[j] / taus[i] >= TWO_TERM_MIN_RATIO]
        pairs = [(p, v) for p, v in pairs if v is not None]
        if singles and pairs:
            best_pair, best_two = min(pairs, key=lambda pv: pv[1])
            if min(singles) - best_two - 2 * math.log(max(lay.n_steps, 2)) > TWO_TERM_EVIDENCE:
                return Candidate(effect.name, effect.technologies, 4, lambda _: [best_pair], _drift_columns,
                                 to_params, vector, from_vector)
        return Candidate(effect.name, effect.technologies, 2, grid, _drift_columns, to_params, vector, from_vector)

    return Candidate(effect.name, effect.technologies, 2, grid, _drift_columns, to_params, vector, from_vector,
                     bind=bind)


# mean_phasor: dr ~ s Im(M e^{jkL} / (A e^{jkr})) / k for a small strength s (M: mean phasor of the image)
def _wavenumber(ctx: Context) -> float:
    return 4 * math.pi * ctx.model.profile().modulation_mhz * 1e6 / C_MM_PER_S


def _mean_phasor_grid(ctx: Context) -> list[float | None]:
    period = 2 * math.pi / _wavenumber(ctx)
    return list(np.linspace(period / 36, period, 36))


def _mean_phasor_columns(ctx: Context, extra_path: float | None) -> list[Column]:
    k = _wavenumber(ctx)
    mean = ctx.per_step(np.array([p.phasor_mean for p in ctx.predictions]))
    amplitude = ctx.z_rows("intensity")
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = mean * np.exp(1j * k * (float(extra_path) - np.nan_to_num(ctx.z_rows("range_dom")))) / amplitude
    return [_depth(ctx, np.where(amplitude > 0, ratio.imag / k, 0.0) * ctx.z_rows("z_per_range"))]


def _mean_phasor(effect: Effect) -> Candidate:
    keys = effect.observed.fitted  # strength, extra path
    (s_lo, s_hi), (p_lo, p_hi) = (bounds(effect, k) for k in keys)

    def to_params(ctx: Context, c: np.ndarray, extra_path: float | None) -> Parameters | None:
        strength, path = float(c[0]), float(extra_path)
        if strength < 0:  # -s e^{jkL} = s e^{jk(L + period / 2)}
            period = 2 * math.pi / _wavenumber(ctx)
            strength, path = -strength, (path + period / 2) % period or period
        return {keys[0]: strength, keys[1]: path} if strength <= s_hi else None

    return Candidate(
        effect.name, effect.technologies, 2, _mean_phasor_grid, _mean_phasor_columns, to_params,
        lambda p: (np.array([p[k] for k in keys]), (np.array([s_lo, p_lo]), np.array([s_hi, p_hi]))),
        lambda x: {keys[0]: float(x[0]), keys[1]: float(x[1])},
    )


# column_row_profile: dr = C(u) + R(v), a column and a row profile at the bin resolution. The profiles are the
# additive fit of the residual over all steps (what stays the same at every distance); a step's signature is
# the profiles fitted to the other steps only, so the score is out of sample and its two linear parameters
# (the column and the row profile's gain) cannot fit a step's own noise.
PATTERN_GAIN_LIMIT = 10.0


def _additive_profiles(weighted: np.ndarray, weight: np.ndarray,
                       iterations: int = 4) -> tuple[np.ndarray, np.ndarray]:
    """Weighted least squares of res[s, v, u] = C[u] + R[v] by alternating weighted means (both zero-mean), from
    the sums over the steps s of weight x res (``weighted``) and of the weight, (v, u) each."""
    col = np.zeros(weight.shape[1])
    row = np.zeros(weight.shape[0])
    col_weight, row_weight = weight.sum(0), weight.sum(1)
    with np.errstate(invalid="ignore", divide="ignore"):
        for _ in range(iterations):
            col = np.nan_to_num((weighted - row[:, None] * weight).sum(0) / col_weight)
            row = np.nan_to_num((weighted - col[None, :] * weight).sum(1) / row_weight)
    seen_col, seen_row = col_weight > 0, row_weight > 0
    col = np.where(seen_col, col - (col[seen_col].mean() if seen_col.any() else 0.0), 0.0)
    row = np.where(seen_row, row - (row[seen_row].mean() if seen_row.any() else 0.0), 0.0)
    return col, row


def _held_out_sums(values: np.ndarray) -> np.ndarray:
    """For every step s of ``values`` (steps first), the sum over the other steps: the steps before s plus those
    after it (not the total minus step s, which would leave a rounding residue where only s contributes)."""
    out = np.zeros_like(values)
    out[1:] += np.cumsum(values[:-1], axis=0)
    out[:-1] += np.cumsum(values[:0:-1], axis=0)[::-1]
    return out


def _pattern_residual(ctx: Context, dz_rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(steps, h, w) depth residual in range units with the nuisance removed, from the stacked depth residual rows
    ``dz_rows`` (mm), and its weights (0 where unused)."""
    flat = ctx.lay.profile_z(np.nan_to_num(dz_rows)) / ctx.z_rows("z_per_range")
    shape = (len(ctx.lay.z_masks),) + ctx.observations[0].z.shape
    res, weight = np.zeros(shape), np.zeros(shape)
    start = 0
    for s, mask in enumerate(ctx.lay.z_masks):
        n = int(mask.sum())
        res[s][mask] = flat[start:start + n]
        weight[s][mask] = ctx.lay.z_weight[start:start + n]
        start += n
    return res, weight


def _column_row_profile(effect: Effect) -> Candidate:
    col_key, row_key = effect.observed.fitted

    def bind(ctx: Context) -> Candidate:
        """The candidate with the profiles of this run's residual."""
        return rebind(ctx, ctx.lay.stack_z([o.z - p.z for o, p in zip(ctx.observations, ctx.predictions,
                                                                       strict=True)]))

    def rebind(ctx: Context, dz_rows: np.ndarray) -> Candidate:
        """The candidate with the profiles of the depth residual rows ``dz_rows``: its columns are linear in them
        (weighted means over the steps and the bins)."""
        res, weight = _pattern_residual(ctx, dz_rows)
        weighted = weight * res
        col, row = _additive_profiles(weighted.sum(0), weight.sum(0))
        held_out_col, held_out_row = [], []
        for others, others_weight in zip(_held_out_sums(weighted), _held_out_sums(weight), strict=True):
            c, r = _additive_profiles(others, others_weight)
            held_out_col.append(np.broadcast_to(c[None, :], res.shape[1:]))
            held_out_row.append(np.broadcast_to(r[:, None], res.shape[1:]))
        norms = (float(col @ col), float(row @ row))

        def columns(c: Context, _: Any) -> list[Column]:
            ratio = c.z_rows("z_per_range")
            return [_depth(c, c.lay.stack_z(held_out_col) * ratio), _depth(c, c.lay.stack_z(held_out_row) * ratio)]

        def from_vector(x: np.ndarray) -> Parameters:
            return {col_key: [float(v) for v in x[0] * col], row_key: [float(v) for v in x[1] * row]}

        def to_params(_: Context, c: np.ndarray, __: Any) -> Parameters | None:
            return from_vector(c) if np.all(np.abs(c) <= PATTERN_GAIN_LIMIT) and min(norms) > 0 else None

        def vector(p: Parameters) -> tuple[np.ndarray, tuple[np.ndarray, np.ndarray]]:
            x = np.array([np.dot(p[col_key], col) / norms[0], np.dot(p[row_key], row) / norms[1]])
            return x, (np.full(2, -PATTERN_GAIN_LIMIT), np.full(2, PATTERN_GAIN_LIMIT))

        return Candidate(effect.name, effect.technologies, 2, _none, columns, to_params, vector, from_vector,
                         rebind=rebind)

    return Candidate(  # bound to a run's residual by candidates_for
        effect.name, effect.technologies, 2, _none, lambda ctx, _: [], lambda ctx, c, _: None,
        lambda p: (np.zeros(0), (np.zeros(0), np.zeros(0))), lambda x: {}, bind=bind, rebind=rebind,
    )


# plane_bounce: dr ~ q sin(k (R' - r) / 2) / k per unit reflectance (first order); plane_phasor: dr ~ Im(m) / k per
# unit of the linear parameter, m the bounce's phasor relative to the direct light (the effect's ``formula``).
# The plane and its distance from the optical axis are searched on a grid. The plane is coded into the distance
# parameter of the refit (PLANE_CODE_MM per plane), whose bounds keep the solver on the plane the grid found.
PLANE_CODE_MM = 20000.0
# distances searched per plane, 100 ... 3000 mm evenly in log: the specular bounce's phase k (R' - r) / 2 turns
# quickly with the distance (24: 16 % apart); the diffuse bounce averages it over the lit patches and changes
# smoothly (12: 36 % apart), its refit then sets the distance
SPECULAR_DISTANCES = 24
DIFFUSE_DISTANCES = 12
#: per camera axis (``PLANES``: 0 x, 1 y) the plane on its positive side
POSITIVE_SIDE = {axis: plane for plane, (axis, side) in PLANES.items() if side > 0}


def _plane_candidate(effect: Effect, first_order: Callable[[Context, np.ndarray, str, float], np.ndarray],
                     distances: int, pointwise: bool = False) -> Candidate:
    """The candidate of a bounce off a plane: ``first_order(ctx, points, plane, distance)`` is the range change per
    unit of the linear parameter at the rows' points, searched at ``distances`` distances per plane. A
    ``pointwise`` first order (compiled, each point on its own: the same value wherever the point sits in the
    array; and depending on the plane through its axis and side in ``PLANES`` alone, so that the plane on one
    side at a point is the plane on the other side at the point's mirror image) is evaluated once per axis and
    distance, for the plane of the positive side on the distinct points of the rows and their mirror images
    (``Context.mirrored_points``), and serves both planes of the axis."""
    plane_key, distance_key, linear_key = effect.observed.fitted
    planes = typing.get_args(effect.params.model_fields[plane_key].annotation)
    d_lo, d_hi = bounds(effect, distance_key)
    r_lo, r_hi = bounds(effect, linear_key)

    def grid(_: Context) -> list[Any]:
        return [(plane, float(d)) for plane in planes for d in np.geomspace(100.0, 3000.0, distances)]

    def columns(ctx: Context, where: Any) -> list[Column]:
        plane, distance = where
        if pointwise:
            axis, side = PLANES[plane]
            union, rows, images = ctx.mirrored_points(axis)
            on_union = ctx.cached(f"{effect.name} {axis} {distance!r}",
                                  lambda: first_order(ctx, union, POSITIVE_SIDE[axis], distance))
            change = on_union[rows if side > 0 else images]
        else:
            change = first_order(ctx, ctx.points(), plane, distance)
        return [_depth(ctx, change * ctx.z_rows("z_per_range"))]

    def to_params(ctx: Context, c: np.ndarray, where: Any) -> Parameters | None:
        plane, distance = where
        return {plane_key: plane, distance_key: distance, linear_key: float(c[0])} \
            if r_lo < c[0] <= r_hi else None

    def vector(p: Parameters) -> tuple[np.ndarray, tuple[np.ndarray, np.ndarray]]:
        code = planes.index(p[plane_key]) * PLANE_CODE_MM
        return (np.array([p[linear_key], code + p[distance_key]]),
                (np.array([r_lo, code + d_lo]), np.array([r_hi, code + d_hi])))

    def from_vector(x: np.ndarray) -> Parameters:
        index = int(x[1] // PLANE_CODE_MM)
        return {plane_key: planes[index], distance_key: float(x[1] - index * PLANE_CODE_MM),
                linear_key: float(x[0])}

    return Candidate(effect.name, effect.technologies, 3, grid, columns, to_params, vector, from_vector)


def _plane_bounce(effect: Effect) -> Candidate:
    bounce = effect.observed.formula

    def first_order(ctx: Context, points: np.ndarray, plane: str, distance: float) -> np.ndarray:
        k = _wavenumber(ctx)
        ratio, half_extra = bounce(*points, plane, distance)
        return ratio * np.sin(k * half_extra) / k

    return _plane_candidate(effect, first_order, SPECULAR_DISTANCES)


# The grid's signature integrates the bounce with a smaller quadrature rule than the simulation's (``nodes``; the
# refit re-simulates with the effect's own): on a 0.4-4 m sweep's points, 8 nodes keep Im m within 0.5 % (RMS)
# of the 16-node rule for planes 150-600 mm from the axis (5 % at 2 m, where the bounce is weak) at a quarter of
# the cost, which the grid pays at every trial plane of every round and null replica (tests/sim/test_effects.py
# checks it against a fine patch sum).
SIGNATURE_NODES = 8


def _plane_phasor(effect: Effect) -> Candidate:
    phasor = effect.observed.formula

    def first_order(ctx: Context, points: np.ndarray, plane: str, distance: float) -> np.ndarray:
        """Im(m) / k: the imaginary part of the effect's formula (the diffuse bounce's ``bounce_phasor``, its
        imaginary part alone)."""
        sensor = ctx.make_predictor(ctx.model).sensor
        m = phasor(*points, plane, distance, sensor, nodes=SIGNATURE_NODES, imag_only=True)
        return m.imag / sensor.wavenumber

    return _plane_candidate(effect, first_order, DIFFUSE_DISTANCES, pointwise=True)


# periodic_disparity: dz = -z^2 / (f b) * (a sin(2 pi d / P) + b cos(2 pi d / P)), d = f b / z in the matcher's
# pixels; the period P searched between DISPARITY_PERIOD_RANGE_PX (the bounds set by hand around the 1 px of
# sub-pixel interpolation) at even steps of its frequency 1/P over the compared rows' disparity span
# (``even_frequency_periods``). An octave grid (19 % steps) slipped up to 0.6 cycle over the 14 px of the test
# campaign's compared bins on the D455 and scored a 0.045 px bias at 1.57 px 7.5 instead of 53.
DISPARITY_PERIOD_RANGE_PX = (0.5, 4.0)


def _disparity_rows(ctx: Context) -> tuple[np.ndarray, np.ndarray]:
    """(d, dz/dd) of every depth row: the disparity in the matcher's pixels and -z^2 / (f b)."""
    focal_baseline = ctx.make_predictor(ctx.model).sensor.matching_focal_baseline
    z = np.nan_to_num(ctx.z_rows("z"), nan=1.0)
    return focal_baseline / z, -z * z / focal_baseline


def _disparity_period_grid(ctx: Context) -> list[float]:
    """The periods searched: even steps of 1/P (``even_frequency_periods``) over the span of the compared rows'
    disparity, 1 px among them."""
    z = ctx.z_rows("z")
    span = _span(_disparity_rows(ctx)[0][np.isfinite(z) & (z > 0)])
    return even_frequency_periods(*DISPARITY_PERIOD_RANGE_PX, max(span, 1.0), 1.0)


def _periodic_disparity_columns(ctx: Context, period: Any) -> list[Column]:
    d, slope = _disparity_rows(ctx)
    phase = 2 * math.pi * d / float(period)
    return [_depth(ctx, slope * np.sin(phase)), _depth(ctx, slope * np.cos(phase))]


def _periodic_disparity(effect: Effect) -> Candidate:
    keys = effect.observed.fitted  # amplitude, period, phase
    (a_lo, a_hi), (p_lo, p_hi), (f_lo, f_hi) = (bounds(effect, k) for k in keys)

    def to_params(ctx: Context, c: np.ndarray, period: Any) -> Parameters | None:
        amplitude = float(np.hypot(c[0], c[1]))
        return {keys[0]: amplitude, keys[1]: float(period), keys[2]: float(math.atan2(c[1], c[0]))} \
            if amplitude <= a_hi else None

    return Candidate(
        effect.name, effect.technologies, 3, _disparity_period_grid, _periodic_disparity_columns,
        to_params,
        lambda p: (np.array([p[k] for k in keys]), (np.array([a_lo, p_lo, f_lo]), np.array([a_hi, p_hi, f_hi]))),
        lambda x: {keys[0]: float(x[0]), keys[1]: float(x[1]), keys[2]: _wrap(x[2])},
    )


# disparity_offset: z' = f b / (d + delta) -> dz = -z^2 / (f b) per px of delta
def _disparity_offset(effect: Effect) -> Candidate:
    return _linear(effect, lambda ctx, _: [_depth(ctx, _disparity_rows(ctx)[1])])


#: the signature forms an effect can declare (``Observed.signature``)
FORMS: dict[str, Callable[[Effect], Candidate]] = {
    "proportional_range": _proportional_range,
    "periodic_range": _periodic_range,
    "warm_up": _warm_up,
    "inverse_light": _inverse_light,
    "log_cos_alpha": _log_cos_alpha,
    "mean_phasor": _mean_phasor,
    "column_row_profile": _column_row_profile,
    "plane_bounce": _plane_bounce,
    "plane_phasor": _plane_phasor,
    "periodic_disparity": _periodic_disparity,
    "disparity_offset": _disparity_offset,
    "log_light_polynomial": _log_light_polynomial,
    "resimulated": _resimulated,
}

#: the library's effects the comparison cannot see, and why
NOT_IDENTIFIABLE = {e.name: e.observed.why_not for e in EFFECTS.values()
                    if e.observed is not None and e.observed.signature is None}


def candidate(effect: Effect) -> Candidate:
    """The candidate of an effect whose ``observed`` names a signature form."""
    return FORMS[effect.observed.signature](effect)


def _testable(ctx: Context) -> Iterator[Effect]:
    """The effects with a signature that the camera's technology shows and the model does not hold yet."""
    for effect in list(EFFECTS.values()):
        if effect.observed is not None and effect.observed.signature is not None \
                and ctx.technology in effect.technologies and effect.name not in ctx.model.effects:
            yield effect


def candidates_for(ctx: Context) -> Iterator[Candidate]:
    """The candidates that apply to this run and are not yet in the model."""
    for effect in _testable(ctx):
        c = candidate(effect)
        if c.applies(ctx):
            yield c.bind(ctx) if c.bind is not None else c


def too_few_steps(ctx: Context) -> dict[str, str]:
    """The effects this run cannot test for want of the steps that show them (``Observed.min_steps``), and why."""
    out = {}
    for effect in _testable(ctx):
        if not candidate(effect).applies(ctx):
            seen = effect.observed
            out[effect.name] = (f"it needs {seen.min_steps} or more {STEPS[seen.steps][1]}"
                                + (f" (procedure {seen.procedure})" if seen.procedure else "")
                                + f"; the run holds {_steps_shown(effect, ctx)}")
    return out


def why_unseen(name: str) -> str:
    """Why a candidate that ``changes_nothing`` is not tested, for the notes."""
    steps = EFFECTS[name].observed.steps
    where = "" if steps == "all" else f" (the {STEPS[steps][1]})"
    return f"it changes no compared bin of this run: the steps that show it{where} hold none away from edges"


def changes_nothing(candidate: Candidate, ctx: Context) -> bool:
    """Whether the candidate's signature leaves every compared row of this run unchanged once the lab's nuisance
    is profiled out (at its first grid point): e.g. the steps that show it hold no compared bin, a plate narrower
    than a bin away from its edges."""
    with np.errstate(over="ignore", invalid="ignore"):  # rows of +-max float (``score``) change something too
        return not any(np.any(ctx.lay.profiled_rows(*column))
                       for column in candidate.columns(ctx, candidate.grid(ctx)[0]))
