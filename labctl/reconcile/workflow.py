"""The reconcile workflow (docs/reconcile.md).

1. Observe the measured run (bin means of z and intensity, their variances,
   the frames' times; ``/sim`` is never read) and re-simulate every step with
   the current model on the bin grid (labctl/reconcile/predict.py).
2. Residuals with the lab's nuisance profiled out (labctl/reconcile/residuals.py).
3. Score every candidate effect not yet in the model (labctl/reconcile/score.py):
   dBIC over steps, leave-one-step-out gain, margin over the runner-up.
4. The winner, if its dBIC passes ``DBIC_THRESHOLD`` and it predicts held-out
   steps, is refined by nonlinear least squares on full re-simulations
   (scipy.optimize.least_squares), added to the model if it is material
   (``material``: on the steps it moves, it reduces their gap in units of
   their noise floors by at least ``MATERIAL_FRACTION`` of it and by at
   least ``FLOOR_FRACTION``; a winner that is not is passed over and the next
   candidate tried on the same residual, at most ``MAX_EFFECTS`` times; where
   no candidate passes alone, two that each pass beside the other are named
   together, labctl/reconcile/pairs.py), the named effects refitted together once there are two
   (``refine_jointly``), any named before that is no longer significant
   beside the others taken out (``_drop_redundant``, the backward step), and
   the run re-simulated; repeat until nothing passes,
   the residual is consistent with the noise (labctl/reconcile/goodness.py)
   or ``MAX_EFFECTS`` are named.
   A runner-up within ``MARGIN`` of the winner stops the search: "ambiguous
   between X and Y", with the capture the run does not hold that would
   separate them (labctl/reconcile/confounds.py). So does a competitor that
   reproduces the winner's change where the run's separating steps (a position
   seen again at another time, with another target or exposure) do not tell
   them apart; a winner whose change those steps contradict is not named, and
   the next candidate is tried.

5. The verdict: ``none`` or ``effect_found`` only when the final residual is
   consistent with the noise; otherwise ``unexplained``, with the residual
   characterized (labctl/reconcile/characterize.py) and, where it is
   structured, an empirical correction added to the model
   (labctl/reconcile/empirical.py). A run with fewer than ``MIN_STEPS``
   comparable steps is ``not_comparable``.

With null runs (``null_runs`` K, the CLI's ``--null-runs``, labctl/reconcile/null.py) the decisions "consistent
with the noise", "significant" and "material" are judged against K simulated null replicas of the measured
campaign, each with its p-value, and the first round states every candidate's minimum detectable amplitude
(labctl/reconcile/power.py). Without them the fixed thresholds decide: ``DBIC_THRESHOLD`` is calibrated on
simulated-vs-simulated runs with nothing hidden (``bench/reconcile_null.py`` prints the largest dBIC any
candidate reached over seeds and cameras; the threshold sits well above it).
"""

from __future__ import annotations

import math
import time
import tomllib
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import tomli_w
from scipy import optimize

from labctl.blas import one_blas_thread
from labctl.errors import InputError
from labctl.reconcile.candidates import (
    NOT_IDENTIFIABLE,
    Candidate,
    Context,
    candidates_for,
    changes_nothing,
    too_few_steps,
    why_unseen,
)
from labctl.reconcile.characterize import characterize, describe_statistics
from labctl.reconcile.confounds import Holdings, Separation, run_captures, screen, separating_capture
from labctl.reconcile.corners import (
    CornerComparison,
    CornerFit,
    CornerGoodness,
    corner_candidates,
    fit_corner_candidate,
    observe_corner_run,
)
from labctl.reconcile.empirical import FIRST_FORM, FORMS
from labctl.reconcile.false_positives import ALPHA, DEFAULT_NULL_RUNS
from labctl.reconcile.goodness import (
    FLOOR_FRACTION,
    MATERIAL_FRACTION,
    UNITS,
    Goodness,
    depth_residual_maps,
    goodness,
    material,
    residual_maps,
    rounded,
)
from labctl.reconcile.null import FixedThresholds, NullCalibration, simulate_null_runs
from labctl.reconcile.observe import Observation, observe_run
from labctl.reconcile.pairs import masked_pair
from labctl.reconcile.power import detectable, detectable_message
from labctl.reconcile.predict import Prediction, Predictor
from labctl.reconcile.residuals import (
    MIN_VALID_FRACTION,
    STAT_FLOORS,
    STATISTICS,
    Layout,
    layout,
    raw_residuals,
    raw_statistics,
    sampling_variance,
    step_rows,
)
from labctl.reconcile.results import (
    Ambiguity,
    CandidateScore,
    CornerCandidate,
    CornerRound,
    CornersSection,
    Correlation,
    Determination,
    EmpiricalCorrection,
    Evidence,
    ExcludedStep,
    FamilyDeparture,
    GoodnessOfFit,
    GoodnessSummary,
    MinimumDetectable,
    NamedEffect,
    NotComparable,
    Parameters,
    ReconcileDocument,
    ResidualFamily,
    RoundGoodness,
    SignificanceRule,
    Unexplained,
)
from labctl.reconcile.score import MARGIN, Beside, Fit, competing, dropped_dbic, polished, score
from labctl.run.store import RunReader
from sim.effects import EFFECTS, default_effects
from sim.model import SimModel, parse_model
from sim.profiles import PROFILES, get_profile

#: without null runs (``--null-runs 0``): the largest dBIC of any candidate on 200 null runs of the test campaign
#: was 3.87 (docs/reconcile.md, bench/reconcile_null.py); 30 keeps a wide margin above it
DBIC_THRESHOLD = 30.0
#: at most this many effects per reconcile (set by hand: the tests hide at most two)
MAX_EFFECTS = 4
MIN_STEPS = 2  # steps are the replications: one step cannot separate an effect from the lab's nuisance
POOR_RELATIVE_ERROR = 0.05  # a parameter whose standard error exceeds 5 % (2 sigma: 10 %) is poorly determined
POOR_ANGLE_ERROR_RAD = 0.05  # the same for phases (set by hand: 3 degrees)
POOR_CORRELATION = 0.95  # set by hand: two parameters this correlated trade off
BACKEND_PROFILES = {"blaze": "blaze101", "amt100": "amt100", "flexx2": "flexx2", "realsense": "d455"}
#: which procedures give the comparison something to work with (for ``not_comparable``): what each captures, and
#: how the effects that declare it as their procedure (``Observed.procedure``) are introduced
PROCEDURES = {
    "depth_sweep": ("a wall at several distances", "range effects: "),
    "offset_calibration": ("the same wall position at the start of the run (with a sweep: drift against distance)",
                           ""),
    "remission_angle": ("material plates on the robot circle at several angles", ""),
    "checkerboard": ("a checkerboard filling the view, at two or more distances", "corner positions: "),
}


def needed_procedures() -> dict[str, str]:
    """Per procedure of ``PROCEDURES``: what it captures and the effects it shows (in the registry's order)."""
    needed = {}
    for procedure, (what, label) in PROCEDURES.items():
        names = [e.name for e in EFFECTS.values() if e.observed is not None and e.observed.procedure == procedure]
        needed[procedure] = f"{what} ({label}{', '.join(names)})" if names else what
    return needed


@dataclass
class Iteration:
    """One round: the model compared, every candidate's fit, what was decided."""

    model_effects: list[str]
    gap_mm: float
    fits: list[Fit]
    decision: str  # "added NAME" (then "; took out NAME": ``_drop_redundant``), "none significant", "ambiguous",
    #                "consistent with noise", "NAME not material"
    residual_z: list[np.ndarray]  # per-step depth residual maps (nuisance removed, NaN outside the comparison)
    goodness: Goodness | None = None
    significance_p: float | None = None  # the best candidate's p-value against the null runs (with null runs)


@dataclass
class CornerStage:
    """The checkerboard corner comparison (labctl/reconcile/corners.py): goodness before and after, the effects it
    named, its rounds, an ambiguity."""

    before: CornerGoodness
    after: CornerGoodness
    named: list[NamedEffect]
    rounds: list[CornerRound]
    ambiguity: Ambiguity | None
    steps: list[str]

    def summary(self) -> CornersSection:
        """The ``corners`` section of reconcile.json."""
        return CornersSection(steps=self.steps, before=self.before.summary(), after=self.after.summary(),
                              named_effects=[e.name for e in self.named], rounds=self.rounds,
                              consistent_with_noise=self.after.consistent, ambiguity=self.ambiguity)


@dataclass
class ReconcileResult:
    """Everything reconcile found: the verdict, the named effects, the gaps, the corrected model, and what the
    report plots (observations, rounds, residual maps)."""

    verdict: str
    named: list[NamedEffect]
    candidates: list[CandidateScore]
    gap_before: float
    gap_after: float
    intensity_gap_before: float
    intensity_gap_after: float
    model: SimModel
    observations: list[Observation]
    iterations: list[Iteration]
    residual_after: list[np.ndarray]
    notes: list[str] = field(default_factory=list)
    ambiguity: Ambiguity | None = None
    goodness_before: Goodness | None = None
    goodness_after: Goodness | None = None  # the final model (with any empirical correction)
    goodness_physical: Goodness | None = None  # the named physical effects only
    rule: FixedThresholds | NullCalibration = field(default_factory=lambda: FixedThresholds(DBIC_THRESHOLD))
    minimum_detectable: dict[str, MinimumDetectable] | None = None
    unexplained: Unexplained | None = None
    empirical: list[EmpiricalCorrection] = field(default_factory=list)
    not_comparable: NotComparable | None = None
    corners: CornerStage | None = None
    excluded: list[ExcludedStep] = field(default_factory=list)
    not_tested: dict[str, str] = field(default_factory=dict)  # effect -> why this run cannot test it

    def model_toml(self) -> str:
        """The corrected model as a model file."""
        return tomli_w.dumps(self.model.model_dump(mode="json", exclude_defaults=False))


def run_camera(info: dict[str, Any]) -> tuple[str, str]:
    """The measured run's camera backend and the simulated profile that stands for it."""
    try:
        backend = tomllib.loads(info["campaign_toml"] or "")["devices"]["camera"]["backend"]
    except (tomllib.TOMLDecodeError, KeyError, TypeError):
        backend = info.get("backend", "")
    return backend, BACKEND_PROFILES.get(backend, backend)


def camera_mismatch(info: dict[str, Any], model: SimModel) -> str | None:
    """A warning when ``model`` simulates another camera than the measured run's (None when they agree or the
    run's camera has no profile): the comparison then measures the difference of two cameras."""
    backend, profile_name = run_camera(info)
    if profile_name not in PROFILES or profile_name == model.camera:
        return None
    return (f"the model simulates camera {model.camera!r} but the run was taken with backend {backend!r} (profile "
            f"{profile_name!r}): what is found is the difference between two cameras; give a {profile_name} model, "
            "or no --model for the camera's built-in one")


def base_model(info: dict[str, Any]) -> SimModel:
    """The camera's built-in model at the run's sensor size and reported FOV (without ``--model``)."""
    backend, profile_name = run_camera(info)
    try:
        profile = get_profile(profile_name)
    except KeyError:
        raise InputError(f"the run's camera backend {backend!r} has no built-in profile; "
                         "give the simulation model with --model MODEL.toml") from None
    overrides: dict[str, Any] = {}
    if (info["width"], info["height"]) != (profile.width, profile.height):
        overrides.update(width=info["width"], height=info["height"])
    if tuple(info["fov_deg"]) != (profile.fov_h_deg, profile.fov_v_deg):
        overrides.update(fov_h_deg=info["fov_deg"][0], fov_v_deg=info["fov_deg"][1])
    return parse_model(tomli_w.dumps({"camera": profile_name, "camera_overrides": overrides,
                                      "effects": default_effects(profile)}), "built-in model")


def with_effect(model: SimModel, name: str, params: Parameters) -> SimModel:
    """A copy of ``model`` with effect ``name`` on (validated like a model file)."""
    return _with_effects(model, lambda effects: {**effects, name: params}, f"model with {name}")


def without_effect(model: SimModel, name: str) -> SimModel:
    """A copy of ``model`` with effect ``name`` off."""
    return _with_effects(model, lambda effects: {k: v for k, v in effects.items() if k != name},
                         f"model without {name}")


def _with_effects(model: SimModel, change: Callable[[dict[str, Any]], dict[str, Any]], what: str) -> SimModel:
    """A copy of ``model`` with its effects as ``change`` makes them, validated like a model file (``what`` names
    the copy in an error)."""
    data = model.model_dump(mode="json")
    data["effects"] = change(data["effects"])
    return parse_model(tomli_w.dumps(data), what)


class Simulation:
    """Re-simulates the measured steps; renders are shared across models with the same geometry."""

    def __init__(self, observations: list[Observation], info: dict[str, Any]) -> None:
        self.observations = observations
        self.info = info
        self.cache: dict[tuple[str, ...], Any] = {}
        self.t0_s = min((float(o.times_s[0]) for o in observations if len(o.times_s)), default=0.0)

    def predictor(self, model: SimModel) -> Predictor:
        return Predictor(model, self.info["width"], self.info["height"], self.info["bin_px"], self.cache)

    def predict(self, model: SimModel) -> list[Prediction]:
        """Every measured step as ``model`` predicts it (``Predictor.predict_run``)."""
        return self.predictor(model).predict_run(self.observations, self.t0_s)


@dataclass
class _Fitted:
    """A least-squares fit of named effects: the solver's result, the map from its parameter vector to the model, the
    whitened residual it minimized (``Layout.profiled``) and the parameters' bounds."""

    result: optimize.OptimizeResult
    build: Callable[[np.ndarray], SimModel]
    residual: Callable[[np.ndarray], np.ndarray]
    bounds: tuple[np.ndarray, np.ndarray]
    blocks: list[slice]  # each effect's parameters in the vector, in the order fitted

    def secant_jacobian(self, steps: np.ndarray) -> np.ndarray:
        """The residual's slope in each parameter over +-``steps`` around the fit (central differences; one-sided
        where a bound is nearer than the step). The prediction is piecewise constant at the solver's own finite
        difference (a relative 1.5e-8: the camera's roundings are averaged over finitely many positions on their
        grids, ``noise_model``), so a derivative taken there reads a rounding's jump as a slope; over the
        parameter's own uncertainty the jumps average out, and that slope is the one its error propagates by."""
        x, (lo, hi) = self.result.x, self.bounds
        f0 = self.result.fun
        jac = np.zeros((len(f0), len(x)))
        for i, h in enumerate(steps):
            up, down = x.copy(), x.copy()
            up[i], down[i] = min(x[i] + h, hi[i]), max(x[i] - h, lo[i])
            f_up = self.residual(up) if up[i] > x[i] else f0
            f_down = self.residual(down) if down[i] < x[i] else f0
            if up[i] > down[i]:
                jac[:, i] = (f_up - f_down) / (up[i] - down[i])
        return jac


#: a fit stops at a step that lowers the whitened sum of squares by less than this share of it (scipy's ``ftol``,
#: 1e-8 by default). Near the optimum each step lowers it by about the square of the one before; on the complete
#: blaze-101 campaign (932042 for about 1e6 residuals, where a parameter's standard error moves it by about 1) the
#: step that stops the fit lowers it by 0.055, and the one after, which the default took, by 7e-7, moving the
#: wiggling's period by 9e-6 mm and its phase by 6e-8 rad (standard errors 1.5 mm and 0.010 rad), at four more
#: re-simulations of the campaign.
FIT_FTOL = 1e-7
#: seconds between two progress lines of a fit (a fit of the complete campaign re-simulates it for about 10 s)
FIT_PROGRESS_S = 2.0


def _fit_effects(found: list[tuple[Candidate, Parameters]], model: SimModel, sim: Simulation, lay: Layout,
                 max_nfev: int, say: Callable[[str], None] | None = None) -> _Fitted:
    """Nonlinear least squares of the parameters of ``found`` (added to ``model``) on full re-simulations; ``say``
    hears, at most every ``FIT_PROGRESS_S``, how many re-simulations the fit has made and the least whitened sum
    of squares so far."""
    vectors = [c.vector(p) for c, p in found]
    x0 = np.concatenate([v[0] for v in vectors])
    lo = np.concatenate([v[1][0] for v in vectors])
    hi = np.concatenate([v[1][1] for v in vectors])
    x0 = np.clip(x0, lo + 1e-9 * (hi - lo), hi - 1e-9 * (hi - lo))
    sizes = np.cumsum([0] + [len(v[0]) for v in vectors])

    def build(x: np.ndarray) -> SimModel:
        trial = model
        for (candidate, _), a, b in zip(found, sizes[:-1], sizes[1:], strict=True):
            trial = with_effect(trial, candidate.name, candidate.from_vector(x[a:b]))
        return trial

    def residual(x: np.ndarray) -> np.ndarray:
        return whitened_residual(sim, lay, build(x))

    names = " and ".join(c.name for c, _ in found)
    made, least, last = 0, math.inf, time.monotonic()

    def reported(x: np.ndarray) -> np.ndarray:
        nonlocal made, least, last
        r = residual(x)
        made, least = made + 1, min(least, float(r @ r))
        if say is not None and time.monotonic() - last >= FIT_PROGRESS_S:
            last = time.monotonic()
            say(f"fitting {names}: {made} re-simulations, whitened sum of squares {least:.6g}")
        return r

    jacobian = _ForwardJacobian(reported, (lo, hi))
    result = optimize.least_squares(jacobian.residual, x0, jac=jacobian, bounds=(lo, hi), x_scale="jac", ftol=FIT_FTOL,
                                    max_nfev=max_nfev)
    return _Fitted(result, build, residual, (lo, hi), [slice(a, b) for a, b in zip(sizes[:-1], sizes[1:])])


class _ForwardJacobian:
    """A fit's residual and its Jacobian by forward differences, as ``least_squares`` takes it by default
    ('2-point'), except at the point where the solver stops for ``FIT_FTOL`` (the step there lowered the cost by
    less than that share of it): the solver takes a Jacobian at every point it moves to before it checks whether
    it stops, a re-simulation per parameter that only the fitted parameters' slopes' steps (``_slopes``) would
    use, and the previous point's gives them as well. Should the solver go on from there after all (the step's
    predicted reduction was more than 4 times what it achieved), its next point gets its own."""

    def __init__(self, fun: Callable[[np.ndarray], np.ndarray], bounds: tuple[np.ndarray, np.ndarray]) -> None:
        self.fun = fun
        self.bounds = bounds
        self.last: tuple[np.ndarray, np.ndarray] | None = None  # the last point the solver evaluated, its residual
        self.taken: tuple[float, np.ndarray] | None = None  # the cost where the last Jacobian was taken, and it
        self.held = False  # the last Jacobian was handed on at a point the solver was expected to stop at

    def residual(self, x: np.ndarray) -> np.ndarray:
        f = self.fun(x)
        self.last = (x.copy(), f)
        return f

    def __call__(self, x: np.ndarray) -> np.ndarray:
        f = self.last[1] if self.last is not None and np.array_equal(self.last[0], x) else self.fun(x)
        cost = 0.5 * float(f @ f)
        if self.taken is not None and not self.held and self.taken[0] - cost < FIT_FTOL * self.taken[0]:
            self.held = True
            return self.taken[1]
        self.held = False
        self.taken = (cost, forward_differences(self.fun, x, f, self.bounds))
        return self.taken[1]


def forward_differences(fun: Callable[[np.ndarray], np.ndarray], x: np.ndarray, f: np.ndarray,
                        bounds: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
    """The Jacobian of ``fun`` at ``x`` (``f``: its value there) by forward differences (Nocedal & Wright 2006, 8.1)
    with the steps ``least_squares`` takes by default: sqrt(eps) max(1, |x_i|) towards x_i's sign (up at 0), the
    other way where that leaves the bounds, and where neither side has room, the whole way to the further bound."""
    lo, hi = bounds
    step = np.sqrt(np.finfo(float).eps) * np.where(x >= 0, 1.0, -1.0) * np.maximum(1.0, np.abs(x))
    below, above = x - lo, hi - x
    room = np.abs(step) <= np.maximum(below, above)
    step = np.where(room & ((x + step < lo) | (x + step > hi)), -step, step)
    step = np.where(room, step, np.where(above >= below, above, -below))
    columns = np.empty((len(x), len(f)))  # one parameter's column a row: the Jacobian is their transpose, as scipy's
    for i in range(len(x)):
        moved = x.copy()
        moved[i] = x[i] + step[i]
        columns[i] = (fun(moved) - f) / ((x[i] + step[i]) - x[i])
    return columns.T


def whitened_residual(sim: Simulation, lay: Layout, model: SimModel) -> np.ndarray:
    """The whitened residual ``model`` leaves on the run (``Layout.profiled``, every family)."""
    preds = sim.predict(model)
    dz, di = raw_residuals(sim.observations, preds)
    return np.nan_to_num(lay.profiled(dz, di, raw_statistics(sim.observations, preds)))


def _step_covariance(jac: np.ndarray, fun: np.ndarray, steps: np.ndarray, n_steps: int,
                     shared: np.ndarray | None = None) -> np.ndarray:
    """Covariance of least-squares parameters with the steps as the independent replications: the
    delete-one-step jackknife (CR3; MacKinnon & White 1985, Bell & McCaffrey 2002), (n - 1) / n B (sum_s
    c_s c_s') B with B = (J'J)^-1 and c_s = J'J (J'J - J_s'J_s)^-1 J_s' f_s, the score of step s as the fit
    without that step would see it (the cluster-robust sandwich of Liang & Zeger 1986 uses J_s' f_s itself,
    and understates the scatter where a few precise steps carry the fit).

    ``jac`` is the Jacobian of the residual with ``shared`` (the whitened design of a nuisance the steps share,
    ``Layout.shared_nuisance``) profiled out, ``fun`` that residual. Leaving a step out re-estimates that
    nuisance too, so the jackknife is taken over the parameters and the nuisance together ([shared, jac]: the
    same fit and residual, Frisch-Waugh-Lovell) and the parameters' block returned; over ``jac`` alone a step
    that carries the nuisance (the nearest, most precise wall carries the depth offset) would count only its
    leverage on the parameters."""
    k = jac.shape[1]
    if shared is not None and shared.shape[1]:
        jac = np.hstack([shared, jac])
    info = jac.T @ jac
    bread = np.linalg.pinv(info)
    rows = step_rows(steps, n_steps)
    scores = []
    for r in rows:
        if not len(r):
            continue
        js = jac[r]
        gs = js.T @ fun[r]
        if not np.any(gs):
            continue
        scores.append(info @ np.linalg.pinv(info - js.T @ js) @ gs)
    used = max(len(scores), jac.shape[1] + 1)
    meat = np.zeros(info.shape)
    for c in scores:
        meat += np.outer(c, c)
    return (bread @ meat @ bread * (used - 1) / used)[-k:, -k:]


def _reference_covariance(jac: np.ndarray, directions: list[tuple[float, np.ndarray]]) -> np.ndarray:
    """The parameters' covariance from each step's reference uncertainty of its own (``Layout.reference_directions``:
    a laser-referenced wall's, the laser's repeatability on its readings), a Type B component (JCGM 100:2008, 4.3.3
    and 5.1): B (sum_s u_s^2 a_s a_s') B with a_s = J' e_s, e_s the whitened rows 1 mm of step s's reference moves.
    The jackknife over the steps counts the same errors as they happened to fall; where a few near walls carry
    the fit its estimate rests on few effective replications and scatters (on four d455 draws 0.25 to 4 times this
    component), while this one is known from the instrument."""
    bread = np.linalg.pinv(jac.T @ jac)
    middle = np.zeros(bread.shape)
    for var, rows in directions:
        a = jac.T @ rows
        middle += var * np.outer(a, a)
    return bread @ middle @ bread


def _combined_covariance(external: np.ndarray, internal: np.ndarray) -> np.ndarray:
    """The larger of the external and the internal standard error of each parameter (Birge 1932; the scale factor
    of the Particle Data Group's averages): ``external`` the jackknife's scatter over the steps, ``internal`` what
    the declared errors give (the weights' variances, floors included, and each step's reference uncertainty).
    The jackknife's correlations are kept, each parameter's row and column scaled up where the internal error is
    the larger; where the jackknife sees no scatter at all, the internal covariance."""
    ext, inner = np.sqrt(np.maximum(np.diag(external), 0.0)), np.sqrt(np.maximum(np.diag(internal), 0.0))
    if not np.all(ext > 0):
        return internal
    scale = np.maximum(1.0, inner / ext)
    return external * np.outer(scale, scale)


def determination(candidate: Candidate, params: Parameters, x: np.ndarray, cov: np.ndarray,
                  capture: str) -> tuple[dict[str, float], Determination]:
    """Standard errors of the named parameters, 95 % intervals, correlations, and whether the run determines
    them (relative error at most ``POOR_RELATIVE_ERROR``, angles within ``POOR_ANGLE_ERROR_RAD``, no pair
    correlated beyond ``POOR_CORRELATION``); when not, the capture that would."""
    sigma = np.sqrt(np.maximum(np.diag(cov), 0.0))
    keys = [k for k, v in candidate.from_vector(x).items() if isinstance(v, float)]
    stderr: dict[str, float] = {}
    interval: dict[str, list[float]] = {}
    for i in range(len(x)):
        for sign in (-1.96, 1.96):
            moved = candidate.from_vector(x + sign * sigma[i] * np.eye(len(x))[i])
            for key in keys:
                if moved[key] != params[key]:
                    lo, hi = interval.get(key, [params[key], params[key]])
                    interval[key] = [min(lo, moved[key]), max(hi, moved[key])]
                    stderr[key] = max(stderr.get(key, 0.0), abs(moved[key] - params[key]) / 1.96)
    problems = []
    for key, err in stderr.items():
        limit = POOR_ANGLE_ERROR_RAD if key.endswith("_rad") else POOR_RELATIVE_ERROR * abs(params[key])
        if err > limit:
            problems.append(f"{key} is uncertain by {err:.3g} (standard error)")
    with np.errstate(invalid="ignore", divide="ignore"):
        corr = cov / np.outer(sigma, sigma)
    correlations: list[Correlation] = []
    for i in range(len(x)):
        for j in range(i + 1, len(x)):
            if i < len(keys) and j < len(keys) and np.isfinite(corr[i, j]):
                correlations.append(Correlation(between=[keys[i], keys[j]], correlation=round(float(corr[i, j]), 3)))
                if abs(corr[i, j]) > POOR_CORRELATION:
                    problems.append(f"{keys[i]} and {keys[j]} trade off (correlation {corr[i, j]:.2f})")
    info = Determination(well_determined=not problems, interval_95=interval, correlations=correlations,
                         problems=problems, capture=capture if problems else None)
    return stderr, info


def capture_hint(name: str, params: Parameters, obs: list[Observation], t0_s: float) -> str:
    """The capture that would determine an effect's parameters better (the effect's ``Observed.capture``, asked
    what the run already holds so that it names a capture the run lacks)."""
    observed = EFFECTS[name].observed
    if observed is not None and observed.capture is not None:
        return observed.capture(params, Holdings(run_captures(obs, t0_s)))
    return "more steps of the procedure where the effect shows most"


#: a candidate refined (``refine``): its parameters, standard errors, determination, whitened RSS and slopes
Refinement = tuple[Parameters, dict[str, float], Determination, float, np.ndarray | None]


def refine(candidate: Candidate, fit: Fit, model: SimModel, sim: Simulation, lay: Layout,
           say: Callable[[str], None] | None = None, start: Parameters | None = None) -> Refinement:
    """The candidate's parameters refined on full re-simulations, starting from its linear fit (or ``start``:
    ``_State.start``).

    Returns the parameters, their standard errors (the larger of the delete-one-step jackknife's and the declared
    errors', docs/reconcile.md *Parameter uncertainty*), how well the run determines them (``determination``),
    the whitened RSS and the residual's slope in each parameter there (``_Fitted.secant_jacobian``; None where it
    could not be taken). ``say``: the fit's progress (``_fit_effects``).
    """
    fitted = _fit_effects([(candidate, start or fit.params)], model, sim, lay, max_nfev=25, say=say)
    result = fitted.result
    params = candidate.from_vector(result.x)
    rss = float(result.fun @ result.fun)
    hint = capture_hint(candidate.name, params, sim.observations, sim.t0_s)
    jac = None
    try:
        jac = _slopes(fitted)
        stderr, info = determination(candidate, params, result.x, _covariance(jac, result.fun, lay), hint)
    except (np.linalg.LinAlgError, ValueError, OverflowError):  # overflow: an error beyond any parameter's range
        stderr, info = {}, Determination(well_determined=False, problems=["no covariance"], capture=hint)
    return params, stderr, info, rss, jac


def _covariance(jac: np.ndarray, fun: np.ndarray, lay: Layout) -> np.ndarray:
    """The fitted parameters' covariance from the residual ``fun`` and its slopes ``jac`` there (``_slopes``): the
    larger of the steps' jackknife and the declared errors' (docs/reconcile.md *Parameter uncertainty*)."""
    external = _step_covariance(jac, fun, lay.row_steps(), lay.n_steps, lay.shared_nuisance())
    internal = np.linalg.pinv(jac.T @ jac) + _reference_covariance(jac, lay.reference_directions())
    return _combined_covariance(external, internal)


def _slopes(fitted: _Fitted) -> np.ndarray:
    """The residual's slope in each parameter over its standard error with the others held (1 / sqrt of the
    solver's J'J diagonal: the change that moves the whitened RSS by 1), ``_Fitted.secant_jacobian``."""
    result = fitted.result
    with np.errstate(divide="ignore"):
        step = 1.0 / np.sqrt(np.sum(result.jac**2, axis=0))
    return fitted.secant_jacobian(np.where(np.isfinite(step), step, 1e-8 * np.maximum(1.0, np.abs(result.x))))


@dataclass
class Joint:
    """The named effects refitted together (``refine_jointly``)."""

    model: SimModel
    slopes: np.ndarray | None  # the residual's slope in each of their parameters (``_slopes``; None: not taken)
    #: each effect's standard errors and determination from the joint covariance (its block: what it shares with
    #: the others included), in the order fitted; None where the covariance could not be taken
    determinations: list[tuple[dict[str, float], Determination]] | None


def refine_jointly(found: list[tuple[Candidate, Parameters]], model: SimModel, sim: Simulation, lay: Layout,
                   say: Callable[[str], None] | None = None) -> Joint:
    """All effects named in this reconcile refitted together (an effect fitted while another was still
    missing carries some of the other's residual), each one's errors taken from their joint covariance: an
    effect's interval then holds what trading off with the others leaves uncertain, which its own fit, the
    others held, does not. ``say``: the fit's progress (``_fit_effects``)."""
    fitted = _fit_effects(found, model, sim, lay, max_nfev=20, say=say)
    x = fitted.result.x
    try:
        slopes = _slopes(fitted)
    except (ValueError, OverflowError):
        return Joint(fitted.build(x), None, None)
    try:
        cov = _covariance(slopes, fitted.result.fun, lay)
    except (np.linalg.LinAlgError, ValueError, OverflowError):
        return Joint(fitted.build(x), slopes, None)
    determinations = []
    for (candidate, _), block in zip(found, fitted.blocks, strict=True):
        params = candidate.from_vector(x[block])
        hint = capture_hint(candidate.name, params, sim.observations, sim.t0_s)
        determinations.append(determination(candidate, params, x[block], cov[block, block], hint))
    return Joint(fitted.build(x), slopes, determinations)


def _comparable_steps(lay: Layout) -> int:
    return int(sum(int(z.sum()) >= 2 or int(i.sum()) >= 2 for z, i in zip(lay.z_masks, lay.i_masks, strict=True)))


def _not_comparable(observations: list[Observation], model: SimModel, notes: list[str], why: str) -> ReconcileResult:
    """The result for a run with nothing (or too little) the simulator can re-create, with what would help."""
    procedures = sorted({o.scene.procedure for o in observations})
    every = needed_procedures()
    needed = {k: v for k, v in every.items() if k not in procedures}
    detail = NotComparable(reason=why, comparable_steps=[o.scene.step_id for o in observations],
                           procedures_needed=needed or every,
                           not_compared="edge sharpness is evaluated by labctl evaluate, not compared here")
    nan = math.nan
    return ReconcileResult("not_comparable", [], [], nan, nan, nan, nan, model, observations, [], [],
                           notes + [f"not comparable: {why}"], not_comparable=detail)


class _State:
    """The model under test and its residuals."""

    def __init__(self, sim: Simulation, lay: Layout, model: SimModel) -> None:
        self.sim, self.lay = sim, lay
        #: the whitened residual's slope in the named effects' parameters at ``model`` (one column each): the
        #: candidates are scored with the named effects free to move along it (``beside``)
        self.named_slopes: np.ndarray | None = None
        #: the candidates whose signature changes no compared row of this run (``candidates.changes_nothing``)
        self.unseen: set[str] = set()
        self.set(model)

    def set(self, model: SimModel) -> None:
        self.model = model
        self.preds = self.sim.predict(model)
        self.dz, self.di = raw_residuals(self.sim.observations, self.preds)
        self.stats = raw_statistics(self.sim.observations, self.preds)
        self.good = goodness(self.lay, self.sim.observations, self.dz, self.di, model.profile().technology,
                             self.preds, self.stats)
        self._context: Context | None = None
        self._whitened: np.ndarray | None = None

    def context(self) -> Context:
        """The signatures' context of the model under test, one per model: what it caches (the rows' points, a
        bounce's values at a trial plane) serves the scoring and the minimum detectable amplitudes alike."""
        if self._context is None:
            self._context = Context(self.sim.observations, self.preds, self.model, self.sim.predictor,
                                    self.sim.t0_s, self.lay)
        return self._context

    def whitened(self) -> np.ndarray:
        """The whitened residual of the model under test (``Layout.profiled``), once per model, read-only."""
        if self._whitened is None:
            self._whitened = np.nan_to_num(self.lay.profiled(self.dz, self.di, self.stats))
            self._whitened.flags.writeable = False
        return self._whitened

    def beside(self, leaving_out: slice | None = None) -> Beside | None:
        """The named effects as the candidates are scored beside them (``score.Beside``; None before any is named):
        an effect fitted while another was missing carries some of that other's residual, and the other would
        otherwise be judged on what is left of it. ``leaving_out``: one named effect's columns of the slopes, to
        judge it beside the others (``redundant``)."""
        slopes = self.named_slopes
        if slopes is None or not slopes.size or not np.all(np.isfinite(slopes)):
            return None
        if leaving_out is not None:
            slopes = np.delete(slopes, leaving_out, axis=1)
        return Beside.of(slopes) if slopes.size else None

    def scored_residual(self, beside: Beside | None) -> np.ndarray:
        """The whitened residual the candidates are scored on: with the named effects' slopes taken out."""
        r = self.whitened()
        return beside.out_of(r) if beside is not None else r

    def start(self, candidate: Candidate, fit: Fit, beside: Beside | None) -> Parameters:
        """Where the fit of a candidate scored as ``fit`` (``beside`` the named effects) on full re-simulations
        starts: its linear fit at the best point of its grid, that point polished (``score.polished``)."""
        return polished(candidate, fit, self.context(), self.lay, self.scored_residual(beside), beside)


def _resimulated(state: _State, fit: Fit, candidate: Candidate, beside: Beside | None,
                 say: Callable[[str], None] | None = None) -> tuple[Fit, Refinement]:
    """``fit`` with the change of its full re-simulation as its signature: the candidate refined (``refine``, its
    progress to ``say``) and the whitened residual its model leaves taken from the one it is scored on (the named
    effects' slopes taken out of both, ``_State.scored_residual``); and the refinement, for naming it."""
    refinement = refine(candidate, fit, state.model, state.sim, state.lay, say, state.start(candidate, fit, beside))
    change = state.whitened() - whitened_residual(state.sim, state.lay,
                                                  with_effect(state.model, fit.name, refinement[0]))
    if beside is not None:
        change = beside.out_of(change)
    left = state.scored_residual(beside) - change
    return replace(fit, params=refinement[0], rss1=float(left @ left), signature=change), refinement


def _resimulating(state: _State, fits: list[tuple[Fit, Candidate]], beside: Beside | None,
                  refined: dict[str, Refinement], say: Callable[[str], None]) -> Callable[[Fit], Fit]:
    """``_resimulated`` for the screen of a round's ``fits``, keeping each refinement in ``refined``."""
    def resimulated(fit: Fit) -> Fit:
        say(f"re-simulating {fit.name} at its fitted strength")
        full, refined[fit.name] = _resimulated(state, fit, next(c for f, c in fits if f is fit), beside, say)
        return full
    return resimulated


def _add_masked_pair(state: _State, fits: list[tuple[Fit, Candidate]], rule: FixedThresholds | NullCalibration,
                     found: list[tuple[Candidate, Parameters]], named: list[NamedEffect], iteration: Iteration,
                     start_model: SimModel, say: Callable[[str], None]) -> Joint | None:
    """Two candidates of a round none of whose candidates is significant alone, each significant beside the other
    (``pairs.masked_pair``), refitted together with the named effects ``found`` and named when material; the joint
    fit (None: no such pair, ``state`` as it was). ``found``, ``named`` and ``iteration`` take the pair."""
    in_play = {f.name for f, _ in fits}
    pair = masked_pair(fits, state.context(), state.lay, state.whitened(), state.named_slopes,
                       lambda fit: rule.significance(fit, in_play)[0], say)
    if pair is None:
        return None
    (a, a_candidate), (b, b_candidate) = pair.first, pair.second
    say(f"fitting {a.name} and {b.name} together")
    r = state.whitened()
    before, previous, rss_before = state.good, state.model, float(r @ r)
    joint = refine_jointly([*found, (a_candidate, a.params), (b_candidate, b.params)], start_model, state.sim,
                           state.lay, say)
    state.set(joint.model)
    if not rule.material(before, state.good):
        iteration.decision = (f"{a.name} and {b.name} together not material (gap {before.gap_mm:.3f} -> "
                              f"{state.good.gap_mm:.3f} mm)")
        state.set(previous)
        return None
    r = state.whitened()
    rss_after = float(r @ r)
    for i, (fit, _) in enumerate((pair.first, pair.second)):
        stderr, info = joint.determinations[len(found) + i] if joint.determinations is not None else \
            ({}, Determination(well_determined=False, problems=["no covariance"]))
        named.append(NamedEffect(name=fit.name, parameters=dict(state.model.effects[fit.name]), evidence=Evidence(
            delta_bic=round(fit.score, 2), loso_gain=round(fit.loso_gain, 4), runner_up=None, runner_up_delta_bic=None,
            stderr=stderr, determination=info, rss_before=rss_before, rss_after=rss_after,
            gap_before_mm=before.gap_mm, gap_after_mm=state.good.gap_mm,
            intensity_gap_before_pct=before.intensity_gap_pct, intensity_gap_after_pct=state.good.intensity_gap_pct,
            steps=state.lay.n_steps, p_value=rule.significance(fit, in_play)[1], null_runs=rule.null_runs or None)))
    found[:] = [(c, dict(state.model.effects[c.name])) for c in [*(c for c, _ in found), a_candidate, b_candidate]]
    state.named_slopes = joint.slopes
    iteration.decision = (f"added {a.name} and {b.name} together: neither significant alone, each beside the other "
                          f"(dBIC {a.score:.1f} and {b.score:.1f})")
    return joint


def redundant(state: _State, found: list[tuple[Candidate, Parameters]], keep: set[str],
              rule: FixedThresholds | NullCalibration) -> tuple[str, float, float] | None:
    """The weakest of the named effects ``found`` (all in ``state.model``, fitted together; ``keep`` not tested)
    that is no longer significant beside the others (``score.dropped_dbic`` under the dBIC the rule asks of the
    best of those tested, ``threshold``): its name, dBIC and that threshold; None when each still is."""
    tested = [(i, c) for i, (c, _) in enumerate(found) if c.name not in keep]
    if not tested:
        return None
    threshold = rule.threshold({c.name for _, c in tested})
    sizes = np.cumsum([0] + [len(c.vector(p)[0]) for c, p in found])
    # a named effect whose slopes could not be taken leaves the others' columns unknown: judged without them
    matched = state.named_slopes is not None and state.named_slopes.shape[1] == sizes[-1]
    weakest = None
    for i, candidate in tested:
        beside = state.beside(np.s_[sizes[i]:sizes[i + 1]]) if matched else None
        without = whitened_residual(state.sim, state.lay, without_effect(state.model, candidate.name))
        value = dropped_dbic(without, state.whitened(), beside, state.lay, candidate.n_params)
        if value < threshold and (weakest is None or value < weakest[1]):
            weakest = (candidate.name, value, threshold)
    return weakest


def _drop_redundant(state: _State, found: list[tuple[Candidate, Parameters]], named: list[NamedEffect],
                    keep: set[str], rule: FixedThresholds | NullCalibration, start_model: SimModel,
                    iteration: Iteration, taken_out: set[str], notes: list[str],
                    say: Callable[[str], None]) -> Joint | None:
    """The backward step after a joint refit: each named effect the others have made redundant (``redundant``),
    the weakest first, taken out of ``found``, ``named`` and the model (into ``taken_out``, and said in the
    ``iteration``'s decision and the ``notes``) and the rest refitted together, until each left is significant
    beside the others. The last refit (None: nothing taken out)."""
    dropped: list[str] = []
    joint = None
    while len(found) > 1:
        weakest = redundant(state, found, keep, rule)
        if weakest is None:
            break
        name, value, threshold = weakest
        say(f"taking out {name}: redundant beside the other named effects")
        notes.append(f"{name} taken out: named before, it is not significant beside "
                     f"{' and '.join(c.name for c, _ in found if c.name != name)} (dBIC {value:.1f} < {threshold:.1f})")
        dropped.append(name)
        named[:] = [e for e in named if e.name != name]
        found[:] = [(c, p) for c, p in found if c.name != name]
        joint = refine_jointly(found, start_model, state.sim, state.lay, say)
        state.set(joint.model)
        state.named_slopes = joint.slopes
        found[:] = [(c, dict(state.model.effects[c.name])) for c, _ in found]
    if dropped:
        iteration.decision += f"; took out {' and '.join(dropped)}"
        taken_out.update(dropped)
    return joint


def _add_empirical(state: _State, carrying: str | None, rule: FixedThresholds | NullCalibration,
                   say: Callable[[str], None]) -> list[EmpiricalCorrection]:
    """Empirical corrections added to ``state`` while each is material (the carrying axis's form first)."""
    order = sorted(FORMS, key=lambda name: name != FIRST_FORM.get(carrying or "", ""))
    added = []
    for name in order:
        if state.good.means_consistent or rule.consistent(state.good):
            break
        say(f"fitting {name}")
        params = FORMS[name](state.context(), state.whitened())
        before = state.good
        trial = with_effect(state.model, name, params)
        keep = state.model
        state.set(trial)
        if not rule.material(before, state.good):
            state.set(keep)
            continue
        added.append(EmpiricalCorrection(name=name, parameters=params, gap_before_mm=before.gap_mm,
                                         gap_after_mm=state.good.gap_mm))
    return added


CORNER_CAPTURE = ("the checkerboard at two or more distances (a FOV error scales the corners alike at every "
                  "distance, a board distance error by 1 / Z), filling the image to its corners (a radial "
                  "distortion grows with the radius squared)")


def _corner_determination(fit: CornerFit, start: np.ndarray) -> Determination:
    """Whether the corners determine the fitted parameters: every standard error at most
    ``POOR_RELATIVE_ERROR`` of the parameters' largest departure from the model they started from."""
    x = fit.x
    scale = float(np.max(np.abs(x - start))) if len(x) else 0.0
    problems = [f"{k} is uncertain by {e:.3g} (standard error)" for k, e in fit.stderr.items()
                if not e <= POOR_RELATIVE_ERROR * scale]
    interval = {k: [float(v - 1.96 * fit.stderr[k]), float(v + 1.96 * fit.stderr[k])]
                for k, v in zip(fit.stderr, x) if k in fit.stderr}
    return Determination(well_determined=not problems, interval_95=interval, problems=problems,
                         capture=CORNER_CAPTURE if problems else None)


def _corner_stage(comparison: CornerComparison, model: SimModel,
                  say: Callable[[str], None]) -> tuple[CornerStage, SimModel]:
    """Name and fit the effects the checkerboard corners show (``corner_candidates``), as the depth rounds do:
    the best candidate by Schwarz's criterion over the corner axes, above ``DBIC_THRESHOLD``, no competing
    runner-up within ``MARGIN``, material on the corner families (``material``); until the corners are
    consistent with their noise."""
    good = before = comparison.goodness(model)
    named: list[NamedEffect] = []
    rounds: list[CornerRound] = []
    ambiguity = None
    candidates = corner_candidates()
    for _ in candidates:
        entry = CornerRound(model_effects=sorted(model.effects), gap=rounded(good.gap_mm),
                            gap_floor=rounded(good.gap_floor_mm), decision="none significant")
        rounds.append(entry)
        if good.consistent:
            entry.decision = "consistent with noise"
            break
        fits: list[CornerFit] = []
        for candidate in candidates:
            if candidate.name not in model.effects:
                say(f"fitting {candidate.name} to the checkerboard corners")
                fit = fit_corner_candidate(candidate, comparison, model, with_effect)
                if fit is not None:
                    fits.append(fit)
        fits.sort(key=lambda f: -f.score)
        entry.candidates = [CornerCandidate(name=f.name, score=round(f.score, 2), parameters=f.params) for f in fits]
        if not fits or fits[0].score < DBIC_THRESHOLD:
            break
        best, runner = fits[0], (fits[1] if len(fits) > 1 else None)
        if runner is not None and runner.score > best.score - MARGIN and competing(best, runner):
            entry.decision = "ambiguous"
            ambiguity = Ambiguity(between=[best.name, runner.name], scores=[best.score, runner.score],
                                  separating_capture=CORNER_CAPTURE)
            break
        trial = with_effect(model, best.name, best.params)
        after = comparison.goodness(trial)
        if not material(good, after):
            entry.decision = (f"{best.name} not material (corner gap {good.gap_mm:.3f} -> {after.gap_mm:.3f} mm, "
                                 f"floor {good.gap_floor_mm:.3f} mm)")
            break
        candidate = next(c for c in candidates if c.name == best.name)
        named.append(NamedEffect(name=best.name, parameters=best.params, evidence=Evidence(
            family="corners", delta_bic=round(best.score, 2), loso_gain=None,
            runner_up=runner.name if runner else None,
            runner_up_delta_bic=round(runner.score, 2) if runner else None,
            stderr=best.stderr, determination=_corner_determination(best, candidate.start(model)),
            rss_before=best.rss0, rss_after=best.rss1,
            gap_before_mm=good.gap_mm, gap_after_mm=after.gap_mm,
            gap_before_px=good.gap_px, gap_after_px=after.gap_px, steps=len(comparison.obs))))
        entry.decision = f"added {best.name}"
        model, good = trial, after
    stage = CornerStage(before, good, named, rounds, ambiguity, [o.step_id for o in comparison.obs])
    return stage, model


def _scored(state: _State, say: Callable[[str], None], beside: Beside | None = None) -> list[tuple[Fit, Candidate]]:
    """Every candidate not yet in the model scored against the current residual, best first; with ``beside``, the
    named effects refitted beside each (``score.Beside``)."""
    r = state.scored_residual(beside)
    ctx = state.context()
    fits = []
    for candidate in candidates_for(ctx):
        say(f"scoring {candidate.name}")
        fit = score(candidate, ctx, state.lay, r, beside)
        if fit is not None:
            fits.append((fit, candidate))
        elif candidate.name not in state.unseen and changes_nothing(candidate, ctx):  # once: its columns again
            state.unseen.add(candidate.name)
    fits.sort(key=lambda fc: -fc[0].score)
    return fits


def first_round(observations: list[Observation], info: dict[str, Any],
                model: SimModel) -> tuple[Goodness, list[Fit], np.ndarray, dict[str, dict[str, np.ndarray]]]:
    """The first round's comparison of ``observations`` with ``model``: the goodness of fit, every candidate's fit,
    the whitened residual sum of squares per (step, family) cell and per family the residual maps by step
    (``goodness.residual_maps``). What a null replica is judged by (labctl/reconcile/null.py)."""
    sim = Simulation(observations, info)
    lay = layout(observations, sim.predict(model), model.profile().technology)
    state = _State(sim, lay, model)
    r = state.whitened()
    cells = lay.row_cells()
    maps = {family: {o.scene.step_id: m.astype(np.float32) for o, m in zip(observations, by_step, strict=True)}
            for family, by_step in residual_maps(lay, state.dz, state.di, state.stats).items()}
    return state.good, [f for f, _ in _scored(state, lambda _: None)], np.bincount(cells, r * r), maps


def _calibrate(null_runs: int, workers: int | None, info: dict[str, Any], model: SimModel, lay: Layout,
               observations: list[Observation], notes: list[str],
               say: Callable[[str], None]) -> FixedThresholds | NullCalibration:
    """The decision rule: ``null_runs`` null replicas of the measured campaign (labctl/reconcile/null.py), or the
    fixed thresholds without them (or when the run file holds no campaign to replicate)."""
    fixed = FixedThresholds(DBIC_THRESHOLD)
    if null_runs <= 0:
        return fixed
    if not info.get("campaign_toml"):
        notes.append("null calibration: the run file holds no campaign to replicate; fixed thresholds used")
        return fixed
    from labctl.batch.cluster import machine_workers

    if 1 / (null_runs + 1) > ALPHA:
        notes.append(f"null calibration: {null_runs} null runs cannot give a p-value of {ALPHA} or less (at least "
                     f"{DEFAULT_NULL_RUNS} are needed): no residual is found outside the null distribution and no "
                     "effect significant")
    compared = [o.scene.step_id for o, z, i in zip(observations, lay.z_masks, lay.i_masks, strict=True)
                if z.any() or i.any()]
    return simulate_null_runs(info["campaign_toml"], model, info, compared, null_runs,
                              workers or machine_workers(), say, first_round)


@one_blas_thread
def reconcile(path: str | Path, model: SimModel | None = None, progress: Callable[[str], None] | None = None,
              warn: Callable[[str], None] | None = None, null_runs: int = 0,
              workers: int | None = None, null: NullCalibration | None = None) -> ReconcileResult:
    """Name, fit and add the effects the model is missing to explain the measured run at ``path``; ``warn``
    hears what is legal but likely a mistake (a model of another camera), which the notes keep as well.
    ``null_runs`` K > 0 judges every decision against K null replicas of the campaign (labctl/reconcile/null.py),
    simulated on ``workers`` processes (default: one per core); 0 uses the fixed thresholds. ``null``: replicas
    simulated before (of the same campaign and model, e.g. for several runs of one campaign) instead."""
    say = progress or (lambda _: None)
    say("reading the measured run")
    with RunReader(path) as run:  # its steps' attributes read once for both observations
        observations, info, notes = observe_run(run)
        fov = (float(info["fov_deg"][0]), float(info["fov_deg"][1]))
        corner_obs, corner_notes = observe_corner_run(run, fov)
    mismatch = camera_mismatch(info, model) if model is not None else None
    if mismatch is not None:
        notes.append(f"camera mismatch: {mismatch}")
        if warn is not None:
            warn(mismatch)
    model = model or base_model(info)
    notes += corner_notes
    corners = None
    if corner_obs:
        say(f"comparing the corners of {len(corner_obs)} checkerboard step(s)")
        corners, model = _corner_stage(CornerComparison(corner_obs, info["width"], info["height"], fov), model, say)
    if not observations:
        why = ("the run holds no step the simulator can re-create (walls, charts, boards, stars, masks, "
               "material plates)")
        return _corner_result(observations, model, notes, why, corners) if corners else \
            _not_comparable(observations, model, notes, why)
    sim = Simulation(observations, info)
    say(f"re-simulating {len(observations)} steps")
    preds = sim.predict(model)
    lay = layout(observations, preds, model.profile().technology)
    if _comparable_steps(lay) < MIN_STEPS:
        why = (f"{_comparable_steps(lay)} step(s) with compared bins; at least {MIN_STEPS} are needed to tell an "
               "effect from the lab's nuisance")
        return _corner_result(observations, model, notes, why, corners) if corners else \
            _not_comparable(observations, model, notes, why)
    state = _State(sim, lay, model)
    rule = null or _calibrate(null_runs, workers, info, model, lay, observations, notes, say)
    good_before = state.good
    gap_before, igap_before = good_before.gap_mm, good_before.intensity_gap_pct
    iterations: list[Iteration] = []
    named: list[NamedEffect] = []
    ambiguity = None
    first_candidates: list[CandidateScore] = []
    start_model = model
    found: list[tuple[Candidate, Parameters]] = []
    minimum_detectable = None
    captures = run_captures(observations, sim.t0_s)
    retry: list[tuple[Fit, Candidate]] | None = None  # a round's other candidates, after its winner was not material
    joint_errors: list[tuple[dict[str, float], Determination]] | None = None  # the named effects' from their joint fit
    immaterial = 0
    taken_out: set[str] = set()  # named, then redundant beside later ones (``_drop_redundant``): not named again
    while len(found) < MAX_EFFECTS:
        # beside the named effects where a candidate may be named. A later round already consistent with the noise
        # names nothing and is not scored; the first round always is: its scores are the run's candidates (and a
        # null replica's statistics, ``first_round``)
        consistent = rule.consistent(state.good)
        if retry is not None:
            fits = retry
        elif consistent and iterations:
            fits = []
        else:
            fits = [fc for fc in _scored(state, say, None if consistent else state.beside())
                    if fc[0].name not in taken_out]
        if not iterations:  # the first round's candidates are judged with the residual (``NullCalibration.judge``)
            state.good = good_before = replace(state.good, candidate_scores={f.name: f.score for f, _ in fits})
            consistent = rule.consistent(state.good)
        retry = None
        if isinstance(rule, NullCalibration) and not iterations:
            say("minimum detectable amplitudes")
            minimum_detectable = detectable(state.context(), lay, rule)
        iteration = Iteration(sorted(state.model.effects), state.good.gap_mm, [f for f, _ in fits], "none significant",
                              depth_residual_maps(lay, state.dz), state.good)
        iterations.append(iteration)
        if not first_candidates:
            first_candidates = [CandidateScore(name=f.name, score=round(f.score, 2)) for f, _ in fits]
        if consistent:
            iteration.decision = "consistent with noise"
            break
        beside = state.beside()
        separation = Separation(lay, captures, state.scored_residual(beside))
        scored = [f for f, _ in fits]
        refined: dict[str, Refinement] = {}  # candidates re-simulated to judge a contradiction, by name
        contradicted, confound = screen(scored, separation, rule.threshold({f.name for f in scored}), MARGIN,
                                        _resimulating(state, fits, beside, refined, say))
        notes += [f"{c.winner} not named: {c.reason}" for c in contradicted]
        fits = [fc for fc in fits if fc[0].name not in {c.winner for c in contradicted}]
        if not fits:
            break
        significant, iteration.significance_p = rule.significance(fits[0][0], {f.name for f, _ in fits})
        if not significant or fits[0][0].loso_gain <= 0:
            together = _add_masked_pair(state, fits, rule, found, named, iteration, start_model, say) \
                if len(found) + 2 <= MAX_EFFECTS else None
            if together is None:
                break
            joint_errors = together.determinations
            refit = _drop_redundant(state, found, named, {c.name for c, _ in found[-2:]}, rule, start_model,
                                    iteration, taken_out, notes, say)
            joint_errors = refit.determinations if refit is not None else joint_errors
            continue
        best, candidate = fits[0]
        runner = fits[1][0] if len(fits) > 1 else None
        if runner is not None and runner.score > best.score - MARGIN and competing(best, runner):
            ambiguity = Ambiguity(between=[best.name, runner.name], scores=[best.score, runner.score],
                                  separating_capture=separating_capture(best.name, runner.name, captures,
                                                                        separation.steps_apart(best, runner)))
        elif confound is not None:
            other = next(f for f in scored if f.name == confound.competitor)
            notes.append(f"{best.name} not named: {confound.reason}")
            ambiguity = Ambiguity(between=[best.name, other.name], scores=[best.score, other.score],
                                  separating_capture=confound.capture)
        if ambiguity is not None:
            iteration.decision = "ambiguous"
            break
        say(f"fitting {best.name}")
        params, stderr, info_det, rss, slopes = refined.get(best.name) or refine(
            candidate, best, state.model, sim, lay, say, state.start(candidate, best, beside))
        before, previous, previous_slopes = state.good, state.model, state.named_slopes
        state.set(with_effect(state.model, best.name, params))
        joint: Joint | None = None  # the named effects refitted with it
        if found and not rule.material(before, state.good):  # scored with the named effects free: judged so too
            say(f"refitting the named effects with {best.name}")
            joint = refine_jointly([*found, (candidate, params)], start_model, sim, lay, say)
            state.set(joint.model)
        if not rule.material(before, state.good):
            iteration.decision = (f"{best.name} not material (gap {before.gap_mm:.3f} -> {state.good.gap_mm:.3f} mm, "
                                  f"floor {before.gap_floor_mm:.3f} mm)")
            state.set(previous)
            immaterial += 1
            if immaterial > MAX_EFFECTS:
                break
            retry = fits[1:]  # the next candidate, on the same residual: the winner's score may come from another
            continue          # hidden effect's residual that its form cannot follow
        state.named_slopes = slopes if previous_slopes is None or slopes is None else np.hstack([previous_slopes,
                                                                                                  slopes])
        found.append((candidate, params))
        named.append(NamedEffect(name=best.name, parameters=params, evidence=Evidence(
            delta_bic=round(best.score, 2), loso_gain=round(best.loso_gain, 4),
            runner_up=runner.name if runner else None,
            runner_up_delta_bic=round(runner.score, 2) if runner else None,
            stderr=stderr, determination=info_det, rss_before=best.rss0, rss_after=rss,
            gap_before_mm=before.gap_mm, gap_after_mm=state.good.gap_mm,
            intensity_gap_before_pct=before.intensity_gap_pct,
            intensity_gap_after_pct=state.good.intensity_gap_pct, steps=lay.n_steps,
            p_value=iteration.significance_p, null_runs=rule.null_runs or None)))
        iteration.decision = f"added {best.name}"
        if len(found) > 1:  # before the next round: what one effect carried of another's residual is not left over
            if joint is None:
                say("refitting the named effects together")
                joint = refine_jointly(found, start_model, sim, lay, say)
                state.set(joint.model)
            state.named_slopes = joint.slopes
            found = [(c, dict(state.model.effects[c.name])) for c, _ in found]
            joint_errors = joint.determinations
            refit = _drop_redundant(state, found, named, {best.name}, rule, start_model, iteration, taken_out,
                                    notes, say)
            joint_errors = refit.determinations if refit is not None else joint_errors
    for i, effect in enumerate(named):
        effect.parameters = dict(state.model.effects[effect.name])
        if joint_errors is not None and effect.evidence is not None:
            effect.evidence.stderr, effect.evidence.determination = joint_errors[i]
    good_physical = state.good
    residual_physical = depth_residual_maps(lay, state.dz)
    unexplained, empirical = None, []
    physical_consistent = rule.consistent(good_physical)
    if not physical_consistent:
        say("characterizing the unexplained residual")
        if good_physical.means_consistent:
            unexplained = Unexplained(axes=[], carrying_axis=None, spatial_map_mm=[],
                                      description="the bin means of depth and intensity agree with the model within "
                                                  "their noise")
        else:
            unexplained = characterize(observations, state.preds, residual_physical, sim.t0_s)
            empirical = _add_empirical(state, unexplained.carrying_axis, rule, say)
        unexplained.families = [_describe_family(family, state, lay)
                                for family in good_physical.inconsistent_statistics]
    gap_after, igap_after = state.good.gap_mm, state.good.intensity_gap_pct
    if corners is not None:
        named = corners.named + named
        ambiguity = ambiguity or corners.ambiguity
    corners_consistent = corners is None or corners.after.consistent
    if physical_consistent and corners_consistent:
        verdict = "effect_found" if named else "none"
    elif ambiguity is not None:
        verdict = "ambiguous"
    else:
        verdict = "unexplained"
    if not corners_consistent:
        notes.append(_corner_unexplained(corners))
    if unexplained is not None:
        unexplained.message = _unexplained_message(named, good_physical, unexplained, empirical)
    if verdict == "none" and minimum_detectable:
        notes.append(detectable_message(minimum_detectable))
    corner_names = {c.name for c in corner_candidates()} if corners is not None else set()
    not_tested = {name: why for name, why in NOT_IDENTIFIABLE.items() if name not in corner_names}
    not_tested |= too_few_steps(state.context()) | {name: why_unseen(name) for name in sorted(state.unseen)}
    notes += [f"{name} is not tested: {why}" for name, why in not_tested.items()]
    excluded = info.get("skipped", []) + excluded_steps(observations, state.preds, lay)
    return ReconcileResult(verdict, named, first_candidates, gap_before, gap_after, igap_before, igap_after,
                           state.model, observations, iterations, depth_residual_maps(lay, state.dz), notes, ambiguity,
                           good_before, state.good, good_physical, rule, minimum_detectable, unexplained, empirical,
                           corners=corners, excluded=excluded, not_tested=not_tested)


def _describe_family(family: str, state: _State, lay: Layout) -> FamilyDeparture:
    """What a statistics family's residual follows (``describe_statistics``) with its gap and floor."""
    obs, preds = state.sim.observations, state.preds
    maps, weights = [], []
    for o, p, r, mask in zip(obs, preds, state.stats[family], lay.s_masks[family], strict=True):
        maps.append(np.where(mask, r, np.nan))
        weights.append(1.0 / (sampling_variance(o, p)[family] + STAT_FLOORS[family] ** 2))
    found = describe_statistics(family, obs, preds, maps, weights, state.sim.t0_s)
    gap, floor = state.good.family_gap(family)
    return replace(found, gap=rounded(gap), floor=rounded(floor))


def excluded_steps(observations: list[Observation], preds: list[Prediction], lay: Layout) -> list[ExcludedStep]:
    """The steps each residual family leaves out (fewer than two compared bins), with the reason."""
    out: list[ExcludedStep] = []
    for s, (o, p) in enumerate(zip(observations, preds, strict=True)):
        seen = np.isfinite(p.z) & p.reported & ~p.edge
        n_seen = int(seen.sum())
        full = int((o.valid_fraction[seen] >= MIN_VALID_FRACTION).sum())
        fill = 100 * float(np.mean(o.valid_rate[seen])) if n_seen else 0.0
        if int(lay.z_masks[s].sum()) < 2:
            reason = ("the model sees no surface away from depth and reflectance edges" if n_seen < 2 else
                      f"too few valid pixels: {full} of {n_seen} bins hold at least {100 * MIN_VALID_FRACTION:.0f} % "
                      f"valid pixels ({fill:.0f} % of the pixel-frames valid)" if full < n_seen / 2 else
                      "no bin away from the measured depth edges")
            out.append(ExcludedStep(step=o.scene.step_id, family="depth", reason=reason))
        if int(lay.i_masks[s].sum()) < 2 and int(lay.z_masks[s].sum()) >= 2:
            out.append(ExcludedStep(step=o.scene.step_id, family="intensity",
                                    reason="no compared bin with smooth simulated light"))
        for family in STATISTICS:
            if int(lay.s_masks[family][s].sum()) >= 2:
                continue
            if family == "validity":
                reason = ("neither the run nor the model has a valid pixel away from depth and reflectance edges "
                          "(outside the camera's measurement range)" if n_seen >= 2 else
                          "the model sees no surface away from depth and reflectance edges")
            elif n_seen and not np.isfinite(p.noise_mm[seen]).any():
                reason = ("the predicted noise is below half the camera's output step: rounding makes it depend on "
                          "where the depth sits on the step, which the model cannot know")
            elif n_seen and not np.isfinite(o.noise_mm[seen]).any():
                reason = f"too few pixels valid in every frame ({fill:.0f} % of the pixel-frames valid)"
            else:
                reason = "no bin where both the run and the model give the noise"
            out.append(ExcludedStep(step=o.scene.step_id, family=family, reason=reason))
    return out


def _corner_unexplained(corners: CornerStage) -> str:
    """What the user reads when the corners stay above their noise."""
    g = corners.after
    after = " after " + ", ".join(e.name for e in corners.named) if corners.named else ""
    return (f"checkerboard corners: a residual of {g.gap_mm:.3f} mm in the board plane ({g.gap_px:.3f} px in the "
            f"image) remains{after} (floor {g.gap_floor_mm:.3f} mm, {g.gap_floor_px:.3f} px) that neither "
            + " nor ".join(c.name for c in corner_candidates()) + " explains")


def _corner_result(observations: list[Observation], model: SimModel, notes: list[str], why: str,
                   corners: CornerStage) -> ReconcileResult:
    """The result of a run whose only comparison is its checkerboard corners: their gap (mm in the board
    plane) is the run's gap, and the depth comparison's absence is said with the procedures it would need."""
    procedures = sorted({o.scene.procedure for o in observations})
    every = needed_procedures()
    needed = {k: v for k, v in every.items() if k not in procedures}
    notes = notes + [f"depth and intensity not compared: {why}; range effects would need "
                     + ", ".join(needed or every)]
    if corners.ambiguity is not None:
        verdict = "ambiguous"
    elif not corners.after.consistent:
        verdict = "unexplained"
        notes.append(_corner_unexplained(corners))
    else:
        verdict = "effect_found" if corners.named else "none"
    nan = math.nan
    return ReconcileResult(verdict, corners.named, [], corners.before.gap_mm, corners.after.gap_mm, nan, nan, model,
                           observations, [], [], notes, corners.ambiguity, corners=corners)


def _unexplained_message(named: list[NamedEffect], good: Goodness, found: Unexplained,
                         empirical: list[EmpiricalCorrection]) -> str:
    """What the user reads: what remains, what it follows, and what the empirical correction is; and which of
    the noise's statistics (noise, validity, correlation) depart from the model's, along which axis."""
    families = "; ".join(f"{f.family}: {f.description} (gap {f.gap}, floor {f.floor} {UNITS[f.family]})"
                         for f in found.families or [])
    after = " after " + ", ".join(e.name for e in named) if named else ""
    if good.means_consistent:
        return (f"the mean depth agrees with the model (gap {good.gap_mm:.3f} mm, floor {good.gap_floor_mm:.3f} mm)"
                f"{after}, but the noise's statistics do not, and no library effect explains it: {families}.")
    text = _means_message(named, good, found, empirical)
    return text + (f" The noise's statistics depart as well: {families}." if families else "")


def _means_message(named: list[NamedEffect], good: Goodness, found: Unexplained,
                   empirical: list[EmpiricalCorrection]) -> str:
    """What remains of the bin means, what it follows, and the empirical correction."""
    worst = good.worst_step
    text = (f"a residual of {good.gap_mm:.3f} mm remains (noise floor {good.gap_floor_mm:.3f} mm"
            + (f"; step {worst.step_id} {worst.ratio:.1f} x its floor in {worst.family}" if worst else "") + ")"
            + (" after " + ", ".join(e.name for e in named) if named else "")
            + f" that no library effect explains: {found.description}.")
    if empirical:
        text += (" Added to the model as an EMPIRICAL correction (" + ", ".join(e.name for e in empirical)
                 + "), which closes the gap without naming a cause.")
    else:
        text += " No empirical correction closed it materially."
    return text


def _families(result: ReconcileResult) -> dict[str, ResidualFamily]:
    """Every residual family compared, its gap and floor before and after (the final model), unit and
    consistency: depth, intensity, noise, validity, correlation and the checkerboard corners."""
    out: dict[str, ResidualFamily] = {}
    before, after = result.goodness_before, result.goodness_after
    if before is not None and after is not None:
        for family, entry in after.family_summary().items():
            gap_before, _ = before.family_gap(family)
            out[family] = ResidualFamily(gap_before=rounded(gap_before), gap_after=entry.gap, floor=entry.floor,
                                         unit=entry.unit, consistent=entry.consistent, steps=entry.steps)
    if result.corners is not None:
        c = result.corners
        out["corners"] = ResidualFamily(gap_before=rounded(c.before.gap_mm), gap_after=rounded(c.after.gap_mm),
                                        floor=rounded(c.after.gap_floor_mm), unit="mm", consistent=c.after.consistent,
                                        steps=len(c.steps))
    return out


def json_document(result: ReconcileResult, model_path: Path) -> ReconcileDocument:
    """reconcile.json (docs/reconcile.md): verdict, named effects and gaps, with the gap floor and consistency,
    per-round goodness of fit, the unexplained residual's characterization, empirical corrections, and what a
    not-comparable run would need."""
    after = result.goodness_after
    corners = result.corners
    corner_floor = rounded(corners.after.gap_floor_mm) if corners else None
    corners_ok = corners.after.consistent if corners else True
    rule = result.rule

    def judged(good: Goodness | None) -> GoodnessSummary | None:
        if good is None:
            return None
        return replace(good.summary(), consistent_with_noise=rule.consistent(good), null=rule.judge(good))
    return ReconcileDocument(
        verdict=result.verdict,
        named_effects=result.named,
        candidates=result.candidates,
        gap_before=rounded(result.gap_before),
        gap_after=rounded(result.gap_after),
        model_toml=str(model_path),
        gap_floor=rounded(after.gap_floor_mm) if after else corner_floor,
        consistent_with_noise=(rule.consistent(after) if after else True) and corners_ok if after or corners else None,
        gap_after_physical=rounded(result.goodness_physical.gap_mm) if result.goodness_physical else None,
        intensity_gap_before=rounded(result.intensity_gap_before),
        intensity_gap_after=rounded(result.intensity_gap_after),
        intensity_gap_floor=rounded(after.intensity_gap_floor_pct) if after else None,
        goodness_of_fit=GoodnessOfFit(
            before=judged(result.goodness_before),
            rounds=[RoundGoodness(model_effects=it.model_effects, decision=it.decision, goodness=judged(it.goodness),
                                  candidate_p_value=it.significance_p) for it in result.iterations],
            after_physical=judged(result.goodness_physical),
            after=judged(after),
        ),
        significance_rule=SignificanceRule(material_fraction=MATERIAL_FRACTION, floor_fraction=FLOOR_FRACTION,
                                           dbic_threshold=DBIC_THRESHOLD),
        empirical_corrections=result.empirical,
        notes=result.notes,
        not_tested=result.not_tested,
        families=_families(result),
        excluded_steps=result.excluded,
        corners=corners.summary() if corners is not None else None,
        unexplained=result.unexplained,
        not_comparable=result.not_comparable,
        ambiguity=result.ambiguity,
        calibration=rule.name,
        null_calibration=replace(rule.summary(), minimum_detectable=result.minimum_detectable),
        minimum_detectable={k: v.amplitude for k, v in result.minimum_detectable.items()}
        if result.minimum_detectable is not None else None,
    )
