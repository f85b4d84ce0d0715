"""``labctl sim``: look at what the simulator produces."""

from __future__ import annotations

import json
from pathlib import Path

import click

from labctl.cli.outputs import OutputFile, png_file
from labctl.errors import InputError
from sim.model import default_model_text, load_model, parse_model
from sim.profiles import PROFILES, SOURCES
from sim.scenes.targets import PLATE_MATERIALS, TARGETS


@click.group("sim")
def sim_group() -> None:
    """Simulator tools: preview frames, list camera profiles."""


def _model(camera: str | None, model_path: Path | None):
    if model_path is not None:
        return load_model(model_path)[0]
    if camera is None:
        raise InputError("give --camera PROFILE or --model MODEL.toml")
    return parse_model(default_model_text(camera), f"built-in profile {camera}")


def _param(values: tuple[str, ...]) -> dict[str, object]:
    params: dict[str, object] = {}
    for item in values:
        key, sep, raw = item.partition("=")
        if not sep:
            raise InputError(f"--param {item!r}: expected KEY=VALUE")
        try:
            params[key] = json.loads(raw)
        except json.JSONDecodeError:
            params[key] = raw
    return params


@sim_group.command("preview")
@click.option("--camera", type=click.Choice(sorted(PROFILES)), help="built-in profile (default model)")
@click.option("--model", "model_path", type=click.Path(dir_okay=False, path_type=Path), help="model file")
@click.option("--target", type=click.Choice(TARGETS), help="scene to show (default: a gallery of all)")
@click.option("--distance-mm", type=float, default=1000.0, show_default=True, help="camera-wall distance")
@click.option("--angle-deg", type=float, default=0.0, show_default=True, help="robot angle (material plates)")
@click.option("--param", multiple=True, help="target parameter KEY=VALUE (e.g. segments=24)")
@click.option("--projector/--no-projector", default=True, help="stereo dot projector")
@click.option("-o", "--output", required=True, type=OutputFile("preview.png"), help="PNG to write")
def preview(camera, model_path, target, distance_mm, angle_deg, param, projector, output) -> None:
    """Render a simulated frame (intensity and depth) of a scene to a PNG."""
    from sim.preview import GALLERY, preview_figure

    png_file(output, "-o")
    model = _model(camera, model_path)
    if target is None:
        targets = [(name, dict(where)) for name, where in GALLERY.items()]
    else:
        where: dict[str, object] = {"params": _param(param), "projector": projector}
        if target in PLATE_MATERIALS:
            where["angle_deg"] = angle_deg
        else:
            where["distance_mm"] = distance_mm
        targets = [(target, where)]
    try:
        path = preview_figure(model, targets, output)
    except (TypeError, KeyError, ValueError) as exc:
        raise InputError(f"cannot render {target or 'the gallery'}: {exc}") from None
    click.echo(f"preview: {path}")


@sim_group.command("profiles")
@click.option("--json", "as_json", is_flag=True, help="one JSON document")
def profiles(as_json: bool) -> None:
    """List the built-in camera profiles with the source of each number."""
    from dataclasses import asdict

    doc = {name: {"parameters": asdict(p), "sources": SOURCES[name]} for name, p in PROFILES.items()}
    if as_json:
        click.echo(json.dumps(doc, indent=2))
        return
    for name, entry in doc.items():
        p = entry["parameters"]
        click.echo(f"{name}: {p['vendor']} {p['model']}, {p['technology']}, {p['width']} x {p['height']} px, "
                   f"FOV {p['fov_h_deg']:g} x {p['fov_v_deg']:g} deg, {p['frame_rate_hz']:g} fps")
        for field, source in entry["sources"].items():
            click.echo(f"    {field}: {source}")
