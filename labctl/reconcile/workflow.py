"""The reconcile workflow (DESIGN "Reconcile", CONTRACTS §6).

1. Observe the measured run (bin means of z and intensity, their variances,
   the frames' times; ``/sim`` is never read) and re-simulate every step with
   the current model on the bin grid (labctl/reconcile/predict.py).
2. Residuals with the lab's nuisance profiled out (labctl/reconcile/residuals.py).
3. Score every candidate effect not yet in the model (labctl/reconcile/score.py):
   dBIC over steps, leave-one-step-out gain, margin over the runner-up.
4. The winner, if its dBIC passes ``DBIC_THRESHOLD`` and it predicts held-out
   steps, is refined by nonlinear least squares on full re-simulations
   (scipy.optimize.least_squares), added to the model, and the run
   re-simulated; repeat until nothing passes (at most ``MAX_EFFECTS``).
   A runner-up within ``MARGIN`` of the winner stops the search: "ambiguous
   between X and Y", with the step where their predictions differ most
   (the capture that would separate them).

``DBIC_THRESHOLD`` is calibrated on simulated-vs-simulated runs with nothing
hidden (``bench/reconcile_null.py`` prints the largest dBIC any candidate
reached over seeds and cameras; the threshold sits well above it).
"""

from __future__ import annotations

import math
import tomllib
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import tomli_w
from scipy import optimize

from labctl.errors import InputError
from labctl.reconcile.candidates import NOT_IDENTIFIABLE, Candidate, Context, candidates_for
from labctl.reconcile.observe import Observation, observe_run
from labctl.reconcile.predict import Prediction, Predictor
from labctl.reconcile.residuals import Layout, depth_gap_mm, intensity_gap_pct, layout, raw_residuals
from labctl.reconcile.score import Fit, score
from sim.model import SimModel, parse_model
from sim.profiles import default_effects, get_profile

DBIC_THRESHOLD = 30.0
MARGIN = 10.0
COMPETING_CORRELATION = 0.5
MAX_EFFECTS = 4
BACKEND_PROFILES = {"blaze": "blaze101", "amt100": "amt100", "flexx2": "flexx2", "realsense": "d455"}


@dataclass
class Iteration:
    """One round: the model compared, every candidate's fit, what was decided."""

    model_effects: list[str]
    gap_mm: float
    fits: list[Fit]
    decision: str  # "added NAME", "none significant", "ambiguous"
    residual_z: list[np.ndarray]  # per-step depth residual maps (nuisance removed, NaN outside the comparison)


@dataclass
class ReconcileResult:
    verdict: str
    named: list[dict[str, Any]]
    candidates: list[dict[str, Any]]
    gap_before: float
    gap_after: float
    intensity_gap_before: float
    intensity_gap_after: float
    model: SimModel
    observations: list[Observation]
    iterations: list[Iteration]
    residual_after: list[np.ndarray]
    notes: list[str] = field(default_factory=list)
    ambiguity: dict[str, Any] | None = None

    def model_toml(self) -> str:
        return tomli_w.dumps(self.model.model_dump(mode="json", exclude_defaults=False))


def base_model(info: dict[str, Any]) -> SimModel:
    """The camera's built-in model at the run's sensor size and reported FOV (without ``--model``)."""
    try:
        backend = tomllib.loads(info["campaign_toml"] or "")["devices"]["camera"]["backend"]
    except (tomllib.TOMLDecodeError, KeyError, TypeError):
        backend = info.get("backend", "")
    profile_name = BACKEND_PROFILES.get(backend, backend)
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


def with_effect(model: SimModel, name: str, params: dict[str, Any]) -> SimModel:
    """A copy of ``model`` with effect ``name`` on (validated like a model file)."""
    data = model.model_dump(mode="json")
    data["effects"] = {**data["effects"], name: params}
    return parse_model(tomli_w.dumps(data), f"model with {name}")


class Simulation:
    """Re-simulates the measured steps; renders are shared across models with the same geometry."""

    def __init__(self, observations: list[Observation], info: dict[str, Any]) -> None:
        self.observations = observations
        self.info = info
        self.cache: dict[tuple[str, str], Any] = {}
        self.t0_s = min((float(o.times_s[0]) for o in observations if len(o.times_s)), default=0.0)

    def predictor(self, model: SimModel) -> Predictor:
        return Predictor(model, self.info["width"], self.info["height"], self.info["bin_px"], self.cache)

    def predict(self, model: SimModel) -> list[Prediction]:
        predictor = self.predictor(model)
        return [predictor.predict(o.scene, o.times_s - self.t0_s) for o in self.observations]


def gaps(lay: Layout, obs: list[Observation], dz: list[np.ndarray], di: list[np.ndarray]) -> tuple[float, float]:
    """(depth gap in mm, intensity gap in %) of the residual maps ``dz``, ``di`` (``raw_residuals``)."""
    with np.errstate(invalid="ignore", divide="ignore"):
        log_var = [o.intensity_var / o.intensity**2 for o in obs]
    return depth_gap_mm(lay, dz, [o.z_var for o in obs]), intensity_gap_pct(lay, di, log_var)


def competing(a: Fit, b: Fit) -> bool:
    """Whether two candidates explain the same part of the residual (their fitted changes correlate)."""
    norm = float(np.linalg.norm(a.signature) * np.linalg.norm(b.signature))
    return norm > 0 and abs(float(a.signature @ b.signature)) / norm >= COMPETING_CORRELATION


def _residual_maps(lay: Layout, dz: list[np.ndarray]) -> list[np.ndarray]:
    """Per-step depth residual maps with the nuisance removed (NaN outside the compared bins)."""
    flat = lay.profile_z(np.nan_to_num(lay.stack_z(dz)))
    maps, start = [], 0
    for d, mask in zip(dz, lay.z_masks, strict=True):
        m = np.full(d.shape, np.nan)
        n = int(mask.sum())
        m[mask] = flat[start:start + n]
        maps.append(m)
        start += n
    return maps


def _fit_effects(found: list[tuple[Candidate, dict[str, Any]]], model: SimModel, sim: Simulation, lay: Layout,
                 max_nfev: int) -> tuple[optimize.OptimizeResult, Callable[[np.ndarray], SimModel]]:
    """Nonlinear least squares of the parameters of ``found`` (added to ``model``) on full re-simulations;
    returns the solver's result and the map from its parameter vector to the model."""
    vectors = [c.vector(p) for c, p in found]
    x0 = np.concatenate([v[0] for v in vectors])
    lo = np.concatenate([v[1][0] for v in vectors])
    hi = np.concatenate([v[1][1] for v in vectors])
    x0 = np.clip(x0, lo + 1e-9 * (hi - lo), hi - 1e-9 * (hi - lo))
    sizes = np.cumsum([0] + [len(v[0]) for v in vectors])

    def build(x: np.ndarray) -> SimModel:
        trial = model
        for i, (candidate, _) in enumerate(found):
            trial = with_effect(trial, candidate.name, candidate.from_vector(x[sizes[i]:sizes[i + 1]]))
        return trial

    def residual(x: np.ndarray) -> np.ndarray:
        dz, di = raw_residuals(sim.observations, sim.predict(build(x)))
        return np.nan_to_num(lay.profiled(dz, di))

    return optimize.least_squares(residual, x0, bounds=(lo, hi), x_scale="jac", max_nfev=max_nfev), build


def refine(candidate: Candidate, fit: Fit, model: SimModel, sim: Simulation, lay: Layout) -> tuple[dict, dict, float]:
    """The candidate's parameters refined on full re-simulations, starting from its linear fit.

    Returns the parameters, their standard errors and the whitened RSS.
    """
    result, _ = _fit_effects([(candidate, fit.params)], model, sim, lay, max_nfev=25)
    params = candidate.from_vector(result.x)
    rss = float(result.fun @ result.fun)
    stderr: dict[str, float] = {}
    try:
        cov = np.linalg.pinv(result.jac.T @ result.jac) * rss / max(len(result.fun) - len(result.x), 1)
        sigma = np.sqrt(np.maximum(np.diag(cov), 0.0))
        for i in range(len(result.x)):
            moved = candidate.from_vector(result.x + sigma[i] * np.eye(len(result.x))[i])
            for key, value in params.items():
                if isinstance(value, float) and moved[key] != value:
                    stderr[key] = max(stderr.get(key, 0.0), abs(moved[key] - value))
    except (np.linalg.LinAlgError, ValueError):
        pass
    return params, stderr, rss


def refine_jointly(found: list[tuple[Candidate, dict[str, Any]]], model: SimModel, sim: Simulation,
                   lay: Layout) -> SimModel:
    """All effects named in this reconcile refitted together (an effect fitted while another was still
    missing carries some of the other's residual)."""
    result, build = _fit_effects(found, model, sim, lay, max_nfev=20)
    return build(result.x)


def _separating_step(a: Fit, b: Fit, lay: Layout, obs: list[Observation]) -> str:
    """The measured step where the two fitted candidates' predictions differ most."""
    diff = (a.signature - b.signature) ** 2
    per_step = np.bincount(lay.row_steps(), diff, lay.n_steps)
    s = obs[int(np.argmax(per_step))].scene
    where = f"{s.wall_distance_mm:.0f} mm" if s.wall_distance_mm is not None else f"{s.robot_angle_deg:g} deg"
    return f"{s.step_id} ({s.procedure}, {s.target} at {where})"


def reconcile(path: str | Path, model: SimModel | None = None,
              progress: Callable[[str], None] | None = None) -> ReconcileResult:
    """Name, fit and add the effects the model is missing to explain the measured run at ``path``."""
    say = progress or (lambda _: None)
    say("reading the measured run")
    observations, info, notes = observe_run(path)
    if not observations:
        raise InputError(f"{path} has no step the simulator can re-create (walls, charts, boards, stars, "
                         "masks, material plates)")
    model = model or base_model(info)
    sim = Simulation(observations, info)
    say(f"re-simulating {len(observations)} steps")
    preds = sim.predict(model)
    lay = layout(observations, preds, model.profile().technology)
    dz, di = raw_residuals(observations, preds)
    gap_before, igap_before = gaps(lay, observations, dz, di)
    iterations: list[Iteration] = []
    named: list[dict[str, Any]] = []
    verdict, ambiguity = "none", None
    first_candidates: list[dict[str, Any]] = []
    start_model = model
    found: list[tuple[Candidate, dict[str, Any]]] = []
    for _ in range(MAX_EFFECTS):
        r = np.nan_to_num(lay.profiled(dz, di))
        ctx = Context(observations, preds, model, sim.predictor, sim.t0_s, lay)
        fits = []
        for candidate in candidates_for(ctx):
            say(f"scoring {candidate.name}")
            fit = score(candidate, ctx, lay, r)
            if fit is not None:
                fits.append((fit, candidate))
        fits.sort(key=lambda fc: -fc[0].score)
        gap, igap = gaps(lay, observations, dz, di)
        iteration = Iteration(sorted(model.effects), gap, [f for f, _ in fits], "none significant",
                              _residual_maps(lay, dz))
        iterations.append(iteration)
        if not first_candidates:
            first_candidates = [{"name": f.name, "score": round(f.score, 2)} for f, _ in fits]
        if not fits or fits[0][0].score < DBIC_THRESHOLD or fits[0][0].loso_gain <= 0:
            break
        best, candidate = fits[0]
        runner = fits[1][0] if len(fits) > 1 else None
        if runner is not None and runner.score > best.score - MARGIN and competing(best, runner):
            iteration.decision = "ambiguous"
            ambiguity = {"between": [best.name, runner.name], "scores": [best.score, runner.score],
                         "separating_capture": _separating_step(best, runner, lay, observations)}
            verdict = "effect_found" if named else "ambiguous"
            break
        say(f"fitting {best.name}")
        params, stderr, rss = refine(candidate, best, model, sim, lay)
        model = with_effect(model, best.name, params)
        found.append((candidate, params))
        preds = sim.predict(model)
        dz, di = raw_residuals(observations, preds)
        new_gap, new_igap = gaps(lay, observations, dz, di)
        named.append({"name": best.name, "parameters": params, "evidence": {
            "delta_bic": round(best.score, 2), "loso_gain": round(best.loso_gain, 4),
            "runner_up": runner.name if runner else None,
            "runner_up_delta_bic": round(runner.score, 2) if runner else None,
            "stderr": stderr, "rss_before": best.rss0, "rss_after": rss,
            "gap_before_mm": gap, "gap_after_mm": new_gap, "intensity_gap_before_pct": igap,
            "intensity_gap_after_pct": new_igap, "steps": lay.n_steps}})
        iteration.decision = f"added {best.name}"
        verdict = "effect_found"
    if len(found) > 1:
        say("refitting the named effects together")
        model = refine_jointly(found, start_model, sim, lay)
        preds = sim.predict(model)
        dz, di = raw_residuals(observations, preds)
        for entry in named:
            entry["parameters"] = dict(model.effects[entry["name"]])
    residual_after = _residual_maps(lay, dz)
    gap_after, igap_after = gaps(lay, observations, dz, di)
    notes += [f"{name} is not tested: {why}" for name, why in NOT_IDENTIFIABLE.items()]
    return ReconcileResult(verdict, named, first_candidates, gap_before, gap_after, igap_before, igap_after,
                           model, observations, iterations, residual_after, notes, ambiguity)


def _rounded(value: float) -> float | None:
    return round(value, 4) if math.isfinite(value) else None


def json_document(result: ReconcileResult, model_path: Path) -> dict[str, Any]:
    """CONTRACTS §6."""
    doc: dict[str, Any] = {
        "verdict": result.verdict,
        "named_effects": result.named,
        "candidates": result.candidates,
        "gap_before": _rounded(result.gap_before),
        "gap_after": _rounded(result.gap_after),
        "gap_unit": "mm",
        "model_toml": str(model_path),
        "intensity_gap_before": _rounded(result.intensity_gap_before),
        "intensity_gap_after": _rounded(result.intensity_gap_after),
        "intensity_gap_unit": "%",
        "notes": result.notes,
    }
    if result.ambiguity:
        doc["ambiguity"] = result.ambiguity
    return doc
