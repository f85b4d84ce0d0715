"""``labctl analyze``: metrics on single files, outside any run (CONTRACTS §2)."""

from __future__ import annotations

import json
from pathlib import Path

import click

from labctl.errors import InputError


@click.group("analyze")
def analyze_group() -> None:
    """Analyze single images or point clouds."""


def _roi(text: str | None) -> tuple[int, int, int, int] | None:
    if text is None:
        return None
    parts = text.split(",")
    try:
        values = tuple(int(p) for p in parts)
    except ValueError:
        values = ()
    if len(values) != 4 or values[2] <= 0 or values[3] <= 0 or min(values[:2]) < 0:
        raise InputError(f"--roi {text!r}: expected X,Y,W,H in whole pixels (W, H > 0)")
    return values  # type: ignore[return-value]


@analyze_group.command("sfr")
@click.argument("image", type=click.Path(dir_okay=False, path_type=Path))
@click.option("--roi", help="region X,Y,W,H in pixels (default: the whole image or the first edge found)")
@click.option("--sfrmat5", is_flag=True, help="no ESF bin correction: reproduce sfrmat5 exactly")
@click.option("--json", "as_json", is_flag=True, help="one JSON document on stdout")
def sfr(image: Path, roi: str | None, sfrmat5: bool, as_json: bool) -> None:
    """ISO 12233 slanted-edge SFR of IMAGE (png, tif, bmp or npy)."""
    from metrics.sfr import analyze_image, load_image

    region = _roi(roi)
    try:
        pixels = load_image(image)
    except (FileNotFoundError, ValueError, OSError) as exc:
        raise InputError(f"cannot read image {image}: {exc}") from None
    try:
        result = analyze_image(pixels, region, bin_correction=not sfrmat5)
    except ValueError as exc:
        raise InputError(f"{image}: {exc}") from None
    doc = {
        "sfr10": result.sfr10,
        "sfr50": result.sfr50,
        "sfr_area": result.sfr_area,
        "angle_deg": result.angle_deg,
        "orientation": result.orientation,
        "clipped": result.clipped,
        "warnings": list(result.warnings),
        "frequency": [round(float(f), 6) for f in result.frequency],
        "sfr": [round(float(v), 6) for v in result.sfr],
    }
    if as_json:
        click.echo(json.dumps({k: (None if isinstance(v, float) and v != v else v) for k, v in doc.items()}))
        return
    click.echo(f"{image}: {result.orientation} edge at {result.angle_deg:.2f} deg")
    click.echo(f"SFR50 {result.sfr50:.4f} cy/px, SFR10 {result.sfr10:.4f} cy/px, SFR area {result.sfr_area:.4f}")
    for warning in result.warnings:
        click.echo(f"warning: {warning}")
