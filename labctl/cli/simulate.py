"""``labctl sim``: look at what the simulator produces."""

from __future__ import annotations

import json
import math
from pathlib import Path

import click
from click.core import ParameterSource

from labctl.cli.outputs import OutputFile, png_file
from labctl.errors import InputError
from labctl.jsondoc import dumps
from sim.profiles import PROFILES, SOURCES
from sim.scenes.targets import PLATE_MATERIALS, TARGETS, scene_parameters


@click.group("sim")
def sim_group() -> None:
    """Simulator tools: preview frames, list camera profiles."""


def _model(camera: str | None, model_path: Path | None):
    from sim.model import default_model_text, load_model, parse_model

    if model_path is not None:
        model = load_model(model_path)[0]
        if camera is not None and camera != model.camera:
            raise InputError(f"--camera {camera} and --model {model_path} (camera = \"{model.camera}\") disagree: the "
                             "model file names the camera; drop --camera, or give a model of that camera")
        return model
    if camera is None:
        raise InputError("give --camera PROFILE or --model MODEL.toml")
    return parse_model(default_model_text(camera), f"built-in profile {camera}")


def _same_kind(default: object, value: object) -> bool:
    """Whether ``value`` has the kind of ``default``: a whole number, a number, true/false or a list of numbers."""
    def number(v: object) -> bool:
        return isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v)
    if isinstance(default, bool):
        return isinstance(value, bool)
    if isinstance(default, int):
        return isinstance(value, int) and not isinstance(value, bool)
    if isinstance(default, tuple):
        return isinstance(value, list) and len(value) == len(default) and all(number(v) for v in value)
    return number(value)


KIND_OF = {bool: "true or false", int: "a whole number", float: "a number", tuple: "a list [a, b] of numbers"}
#: scene parameters that are sizes (> 0), and the fewest wedges a Boehler star can have
SIZES = {"tile_mm", "board_mm", "diameter_mm", "disc_mm", "spacing_mm", "plate_mm"}
MIN_SEGMENTS = 2


def _param(values: tuple[str, ...], target: str) -> dict[str, object]:
    """``--param KEY=VALUE`` items checked against the parameters of ``target``'s scene (name and kind)."""
    known = scene_parameters(target)
    params: dict[str, object] = {}
    for item in values:
        key, sep, raw = item.partition("=")
        if not sep:
            raise InputError(f"--param {item!r}: expected KEY=VALUE")
        if key not in known:
            takes = f"its parameters are {', '.join(known)}" if known else "it takes none"
            raise InputError(f"--param {item!r}: target {target} has no parameter {key!r}; {takes}")
        try:
            value = json.loads(raw)
        except json.JSONDecodeError:
            value = raw
        if not _same_kind(known[key], value):
            kind = KIND_OF.get(type(known[key]), "a number")
            raise InputError(f"--param {item!r}: {key} of {target} is {kind} (default {json.dumps(known[key])}), "
                             f"got {raw!r}")
        sizes = value if isinstance(value, list) else [value]
        if (key in SIZES and min(sizes) <= 0) or (key == "segments" and value < MIN_SEGMENTS):
            least = f"at least {MIN_SEGMENTS}" if key == "segments" else "> 0"
            raise InputError(f"--param {item!r}: {key} of {target} must be {least}")
        params[key] = value
    return params


def _given(ctx: click.Context, name: str) -> bool:
    """Whether the option ``name`` was given on the command line (not its default)."""
    return ctx.get_parameter_source(name) is not ParameterSource.DEFAULT


@sim_group.command("preview")
@click.option("--camera", type=click.Choice(sorted(PROFILES)), help="built-in profile (default model)")
@click.option("--model", "model_path", type=click.Path(dir_okay=False, path_type=Path), help="model file")
@click.option("--target", type=click.Choice(TARGETS), help="scene to show (default: a gallery of all)")
@click.option("--distance-mm", type=click.FloatRange(min=0.0, min_open=True), default=1000.0, show_default=True,
              help="camera-wall distance (stage targets)")
@click.option("--angle-deg", type=click.FloatRange(-90.0, 90.0, min_open=True, max_open=True), default=0.0,
              show_default=True, help="robot angle (material plates)")
@click.option("--param", multiple=True, help="target parameter KEY=VALUE (e.g. segments=24)")
@click.option("--projector/--no-projector", default=True, help="stereo dot projector")
@click.option("-o", "--output", required=True, type=OutputFile("preview.png"), help="PNG to write")
@click.pass_context
def preview(ctx, camera, model_path, target, distance_mm, angle_deg, param, projector, output) -> None:
    """Render a simulated frame (intensity and depth) of a scene to a PNG."""
    from sim.preview import GALLERY, preview_figure

    png_file(output, "-o")
    model = _model(camera, model_path)
    if target is None:
        given = [f"--{name.replace('_', '-')}" for name in ("param", "distance_mm", "angle_deg") if _given(ctx, name)]
        if given:
            raise InputError(f"{', '.join(given)} appl{'ies' if len(given) == 1 else 'y'} to one scene: add --target "
                             f"(one of {', '.join(TARGETS)})")
        targets = [(name, dict(where)) for name, where in GALLERY.items()]
    else:
        where: dict[str, object] = {"params": _param(param, target), "projector": projector}
        plate = target in PLATE_MATERIALS
        wrong = "--distance-mm" if plate and _given(ctx, "distance_mm") else \
            "--angle-deg" if not plate and _given(ctx, "angle_deg") else None
        if wrong is not None:
            right = "--angle-deg (the robot's angle)" if plate else "--distance-mm"
            raise InputError(f"{wrong} does not apply to target {target}: it is placed with {right}")
        where["angle_deg" if plate else "distance_mm"] = angle_deg if plate else distance_mm
        gap = where["params"].get("gap_mm", 0.0)  # type: ignore[union-attr]
        if not plate and not 0 <= gap < distance_mm:
            raise InputError(f"--param gap_mm={gap}: the target stands gap_mm in front of the wall, so 0 <= gap_mm < "
                             f"--distance-mm ({distance_mm:g}); give a smaller gap or a larger distance")
        targets = [(target, where)]
    try:
        path = preview_figure(model, targets, output)
    except (TypeError, KeyError, ValueError, ArithmeticError) as exc:
        shown = " ".join(f"--param {p}" for p in param)
        raise InputError(f"cannot render {target or 'the gallery'}{' with ' + shown if shown else ''}: {exc}") from None
    click.echo(f"preview: {path}")


@sim_group.command("profiles")
@click.option("--json", "as_json", is_flag=True, help="one JSON document")
def profiles(as_json: bool) -> None:
    """List the built-in camera profiles with the source of each number."""
    from dataclasses import asdict

    doc = {name: {"parameters": asdict(p), "sources": SOURCES[name]} for name, p in PROFILES.items()}
    if as_json:
        click.echo(dumps(doc))
        return
    for name, entry in doc.items():
        p = entry["parameters"]
        click.echo(f"{name}: {p['vendor']} {p['model']}, {p['technology']}, {p['width']} x {p['height']} px, "
                   f"FOV {p['fov_h_deg']:g} x {p['fov_v_deg']:g} deg, {p['frame_rate_hz']:g} fps")
        for field, source in entry["sources"].items():
            click.echo(f"    {field}: {source}")
