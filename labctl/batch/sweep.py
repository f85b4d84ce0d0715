"""Simulated campaign sweeps: a sweep file names a campaign, a model and parameter grids; every point of the
grid is one simulated run (``labctl run --sim``), evaluated and optionally reconciled (docs/scale.md).

The sweep file (TOML; paths relative to it)::

    [sweep]
    campaign = "campaign.toml"   # required
    model = "model.toml"         # optional: default the camera's built-in model
    camera = "blaze101"          # without a model file or a camera axis: default the campaign's camera
    evaluate = true              # labctl evaluate of every run (default true)
    reconcile = false            # labctl reconcile of every run against the model (default false)
    keep_runs = true             # false: a run file is deleted once it is evaluated / reconciled
    figures = ["z_accuracy_q90_mm"]   # key figures tabled and plotted over the grid (default: a few)

    [grid]                       # the points are every combination of the axes' values
    seed = {start = 100, count = 50}          # or a list; default: the campaign's [sim] seed
    camera = ["blaze101", "d455"]             # the model's camera and the campaign's backend together
    "model.effects.wiggling.amplitude_mm" = [0.0, 2.0, 4.0]   # any model field (effects, camera_overrides, lab)
    "campaign.procedure.1.step_mm" = [200, 400]               # any campaign field (list items by index)
    "camera,model.camera_overrides.width" = [["blaze101", 160], ["flexx2", 224]]  # axes that move together

Each point is reconciled against the sweep's model (the built-in model without
one) with the camera of the point: the grid's ``model.`` changes are what the
reconcile should find. A point whose effects equal that model's is a null run.
"""

from __future__ import annotations

import copy
import itertools
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import tomli_w

from labctl.batch.tasks import Summary, guarded, process_run
from labctl.errors import InputError
from labctl.evaluation.keyfigures import FIGURE_BY_NAME
from labctl.reconcile.workflow import BACKEND_PROFILES
from labctl.run.campaign import run_campaign
from labctl.run.config import load_campaign, model_camera_mismatch, parse_campaign
from labctl.run.filekind import describe, is_hdf5
from labctl.run.lab import simulated_lab
from labctl.run.progress import Reporter
from sim.effects import default_effects
from sim.errors import ModelError
from sim.model import load_model, parse_model
from sim.profiles import get_profile

#: figures tabled and plotted when the sweep file names none
DEFAULT_FIGURES = ["z_trueness_q90_mm", "z_precision_q90_mm", "z_accuracy_q90_mm", "z_repeatability_center_mm"]
#: the reconcile's numbers a sweep can table over its grid besides the key figures
RECONCILE_FIGURES = ("reconcile.gap_before", "reconcile.gap_after", "reconcile.gap_floor")
SWEEP_KEYS = {"campaign", "model", "camera", "evaluate", "reconcile", "keep_runs", "figures", "name"}
PROFILE_BACKENDS = {profile: backend for backend, profile in BACKEND_PROFILES.items()}


@dataclass(frozen=True)
class Point:
    """One simulated run of the sweep."""

    name: str
    parameters: dict[str, Any]  # axis -> value
    campaign_toml: str
    model_toml: str
    reconcile_model_toml: str | None  # None: the camera's built-in model (as labctl reconcile without --model)
    seed: int | None
    null: bool  # nothing hidden: the run's effects are those it is reconciled against


@dataclass(frozen=True)
class Sweep:
    name: str
    axes: list[str]
    points: list[Point]
    evaluate: bool
    reconcile: bool
    keep_runs: bool
    figures: list[str]


def _set(data: dict[str, Any], path: str, value: Any, where: str) -> None:
    """Set the dotted ``path`` (list items by index) in ``data``, creating tables on the way."""
    keys = path.split(".")
    node: Any = data
    for i, key in enumerate(keys):
        last = i == len(keys) - 1
        if isinstance(node, list):
            if not key.isdigit() or int(key) >= len(node):
                raise InputError(f"{where}: {'.'.join(keys[:i + 1])} is not an item of a list of {len(node)}")
            key = int(key)  # type: ignore[assignment]
        elif not isinstance(node, dict):
            raise InputError(f"{where}: {'.'.join(keys[:i])} is a value, not a table")
        if last:
            node[key] = value
        else:
            if isinstance(node, dict) and key not in node:
                node[key] = {}
            node = node[key]


def _axis_values(name: str, values: Any, where: str) -> list[Any]:
    if name == "seed" and isinstance(values, dict):
        if set(values) != {"start", "count"} or not all(isinstance(v, int) and v >= 0 for v in values.values()):
            raise InputError(f"{where}: seed = {{start = N, count = M}} with whole numbers >= 0")
        return list(range(values["start"], values["start"] + values["count"]))
    if not isinstance(values, list) or not values:
        raise InputError(f"{where}: grid axis {name!r} needs a non-empty list of values")
    return values


def _grid(grid: dict[str, Any], where: str) -> tuple[list[str], list[dict[str, Any]]]:
    """The axes and every combination of their values (zipped axes ``"a,b"`` move together)."""
    axes: list[str] = []
    choices: list[list[dict[str, Any]]] = []
    for key, raw in grid.items():
        names = [n.strip() for n in key.split(",")]
        for name in names:
            if name not in ("seed", "camera") and not name.startswith(("model.", "campaign.")):
                raise InputError(f"{where}: grid axis {name!r}: use seed, camera, model.<field> or campaign.<field>")
        values = _axis_values(key, raw, where)
        if len(names) > 1:
            bad = [v for v in values if not isinstance(v, list) or len(v) != len(names)]
            if bad:
                raise InputError(f"{where}: grid axes {key!r} move together: every value is a list of "
                                 f"{len(names)} (got {bad[0]!r})")
            choices.append([dict(zip(names, v)) for v in values])
        else:
            choices.append([{names[0]: v} for v in values])
        axes += names
    return axes, [{k: v for part in combo for k, v in part.items()} for combo in itertools.product(*choices)]


def _read_toml(path: Path, what: str) -> tuple[dict[str, Any], str]:
    try:
        text = path.read_text()
        return tomllib.loads(text), text
    except FileNotFoundError:
        raise InputError(f"{what} {path} does not exist") from None
    except UnicodeDecodeError:  # a run file (HDF5) or another binary file
        run = " (a run file is evaluated with 'labctl batch runs')" if is_hdf5(path) else ""
        raise InputError(f"{what} {path} is {describe(path)}, not a TOML text file{run}") from None
    except OSError as exc:
        raise InputError(f"cannot read {what} {path}: {exc.strerror}") from None
    except tomllib.TOMLDecodeError as exc:
        raise InputError(f"{what} {path}: not valid TOML: {exc}") from None


def _built_in(camera: str, where: str) -> dict[str, Any]:
    try:
        return {"camera": camera, "effects": default_effects(get_profile(camera))}
    except KeyError:
        raise InputError(f"{where}: unknown camera profile {camera!r}") from None


def load_sweep(path: Path) -> Sweep:
    """Read, expand and validate a sweep file: every point's campaign and model are checked before any runs."""
    data, _ = _read_toml(path, "sweep file")
    head = data.get("sweep")
    if not isinstance(head, dict) or "campaign" not in head:
        raise InputError(f"{path}: [sweep] campaign = \"CAMPAIGN.toml\" is required")
    unknown = set(head) - SWEEP_KEYS
    if unknown or set(data) - {"sweep", "grid"}:
        raise InputError(f"{path}: unknown key(s) {', '.join(sorted(unknown | (set(data) - {'sweep', 'grid'})))}; "
                         f"[sweep] takes {', '.join(sorted(SWEEP_KEYS))} and [grid] the axes")
    base = path.parent
    campaign, _ = _read_toml(base / head["campaign"], "[sweep] campaign")
    model_file = _read_toml(base / head["model"], "[sweep] model")[0] if "model" in head else None
    axes, combos = _grid(data.get("grid", {}), f"{path} [grid]")
    points = []
    for index, parameters in enumerate(combos or [{}]):
        name = f"p{index:04d}"
        where = f"{path}, point {name} ({', '.join(f'{k} = {v}' for k, v in parameters.items()) or 'no grid'})"
        point_campaign = copy.deepcopy(campaign)
        camera = parameters.get("camera", head.get("camera"))
        if camera is None:
            camera = model_file["camera"] if model_file and "camera" in model_file else BACKEND_PROFILES.get(
                str(campaign.get("devices", {}).get("camera", {}).get("backend")), None)
        if camera is None:
            raise InputError(f"{where}: name the camera ([sweep] camera, a camera axis or a model file)")
        if "camera" in parameters or "camera" in head:
            _set(point_campaign, "devices.camera.backend", PROFILE_BACKENDS.get(camera, camera), where)
        reference = copy.deepcopy(model_file) if model_file is not None else _built_in(camera, where)
        reference["camera"] = camera
        model = copy.deepcopy(reference)
        for axis, value in parameters.items():
            if axis.startswith("model."):
                _set(model, axis.removeprefix("model."), value, where)
            elif axis.startswith("campaign."):
                _set(point_campaign, axis.removeprefix("campaign."), value, where)
        seed = parameters.get("seed")
        if seed is not None and (not isinstance(seed, int) or seed < 0):
            raise InputError(f"{where}: seed must be a whole number >= 0")
        campaign_toml, model_toml = tomli_w.dumps(point_campaign), tomli_w.dumps(model)
        backend = parse_campaign(campaign_toml, f"{where}: campaign").devices.camera.backend
        try:
            parse_model(model_toml, f"{where}: model")
        except ModelError as exc:  # a sweep file's bad point is bad input like any other field of it
            raise InputError(str(exc)) from None
        mismatch = model_camera_mismatch(backend, camera)
        if mismatch is not None:
            raise InputError(f"{where}: {mismatch}; set [sweep] camera = \"{camera}\" (it sets the campaign's "
                             "backend too) or use a model of the campaign's camera")
        reconcile_toml = tomli_w.dumps(reference) if model_file is not None else None
        null = model.get("effects", {}) == reference.get("effects", {})
        points.append(Point(name, parameters, campaign_toml, model_toml, reconcile_toml, seed, null))
    figures = head.get("figures", DEFAULT_FIGURES)
    if not isinstance(figures, list) or not all(isinstance(f, str) for f in figures):
        raise InputError(f"{path}: [sweep] figures is a list of key figure names")
    unknown_figures = [f for f in figures if f not in FIGURE_BY_NAME and f not in RECONCILE_FIGURES]
    if unknown_figures:
        raise InputError(f"{path}: [sweep] figures: unknown key figure(s) {', '.join(map(repr, unknown_figures))}; "
                         f"the names are those of docs/keyfigures.md (e.g. {', '.join(DEFAULT_FIGURES)}) and "
                         f"{', '.join(RECONCILE_FIGURES)}")
    flags = {key: head.get(key, default) for key, default in (("evaluate", True), ("reconcile", False),
                                                              ("keep_runs", True))}
    for key, value in flags.items():
        if not isinstance(value, bool):
            raise InputError(f"{path}: [sweep] {key} is true or false")
    if not flags["evaluate"] and not flags["reconcile"]:
        raise InputError(f"{path}: [sweep] evaluate and reconcile are both false: nothing to do with the runs")
    return Sweep(str(head.get("name", path.stem)), axes, points, figures=figures, **flags)


def simulate_run(campaign_toml: str, model_toml: str, seed: int | None, directory: Path) -> Path:
    """The run ``labctl run CAMPAIGN --sim --model MODEL [--seed N] -o RUN --quiet`` makes, in ``directory``
    (beside the point's campaign and model files); the run file."""
    directory.mkdir(parents=True, exist_ok=True)
    (directory / "campaign.toml").write_text(campaign_toml)
    (directory / "model.toml").write_text(model_toml)
    run = directory / "run.h5"
    run.unlink(missing_ok=True)  # a point run again starts over
    campaign, text = load_campaign(directory / "campaign.toml")
    model_text = load_model(directory / "model.toml")[1]
    lab = simulated_lab(campaign, model_text, seed=seed, source=str(directory / "model.toml"))
    return run_campaign(campaign, text, lab, run, reporter=Reporter(quiet=True)).run_file


def run_point(point: Point, directory: Path, evaluate: bool, reconcile: bool, keep_run: bool) -> Summary:
    """One sweep point on a worker: simulated, then evaluated / reconciled as ``labctl batch runs`` does; the
    run file removed afterwards unless ``keep_run``."""
    run = directory / "run.h5"
    simulated = guarded(lambda: {"run": str(simulate_run(point.campaign_toml, point.model_toml, point.seed,
                                                          directory))}, directory / "simulate-error.txt")
    if "error" in simulated:
        return {"run": str(run), "output": str(directory), "status": "failed", "error": f"simulate: {simulated['error']}",
                "parameters": point.parameters, "null": point.null}
    summary = process_run(run, directory, evaluate, reconcile, point.reconcile_model_toml, "sweep model")
    if not keep_run:
        run.unlink(missing_ok=True)
        summary["run_deleted"] = True
    return {**summary, "parameters": point.parameters, "null": point.null}
