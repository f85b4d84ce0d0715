"""keyfigures.json and the self-describing HTML report."""

from __future__ import annotations

import html
import json
import math
from pathlib import Path
from typing import Any

from labctl.eval_sharpness import resolution_table
from labctl.evaluate import Evaluation, depth_table
from labctl.keyfigures import FIGURE_BY_NAME, clean, keyfigures_document
from labctl.plots import plot_depth_curves, plot_resolution, plot_sharpness, plot_surface_maps
from labctl.store import labctl_version, now_iso

SUITABILITY_PENDING = {
    "evaluated": False,
    "reason": "the suitability checks (SPEC 9) need radial distortion, imagery resolution and the hyperfocal "
    "distance, which these runs do not provide",
}

CSS = """
body{font-family:system-ui,-apple-system,Segoe UI,Roboto,sans-serif;margin:2em auto;max-width:1150px;color:#222}
h1{font-size:1.6em}h2{border-bottom:1px solid #ccc;padding-bottom:.2em;margin-top:2em}
table{border-collapse:collapse;font-size:.9em}td,th{border:1px solid #ddd;padding:.3em .6em;text-align:right}
th{background:#f4f4f4}td.l,th.l{text-align:left}.null{color:#999}.note{color:#a15c00}
img{max-width:100%;border:1px solid #eee}
"""


def _fmt(value: Any, digits: int = 3) -> str:
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return '<span class="null">n/a</span>'
    if isinstance(value, float):
        return f"{value:.{digits}g}" if abs(value) < 1e4 else f"{value:.0f}"
    return html.escape(str(value))


def write_outputs(evaluation: Evaluation, outdir: Path) -> tuple[Path, Path]:
    """Write keyfigures.json, the plots and report.html into ``outdir``."""
    outdir.mkdir(parents=True, exist_ok=True)
    plots = outdir / "plots"
    plots.mkdir(exist_ok=True)
    doc = keyfigures_document(evaluation.camera, evaluation.figures, SUITABILITY_PENDING)
    doc["runs"] = evaluation.runs
    doc["notes"] = evaluation.notes
    doc["depth_sweep"] = _clean_rows(depth_table(evaluation))
    if evaluation.sharpness is not None:
        doc["slanted_edge"] = _clean_rows(resolution_table(evaluation.sharpness))
    json_path = outdir / "keyfigures.json"
    json_path.write_text(json.dumps(doc, indent=2, allow_nan=False) + "\n")

    sections: list[str] = []
    if evaluation.depth:
        img = plot_depth_curves(evaluation.depth, plots / "depth_error.png")
        sections.append(_section("Depth error over distance (SPEC 1)", img, outdir, _depth_rows(evaluation)))
    if evaluation.surface is not None:
        img = plot_surface_maps(evaluation.surface, plots / "surface_texture.png")
        sections.append(_section("Surface texture (SPEC 2, ISO 25178-2)", img, outdir, ""))
    if evaluation.sharpness is not None:
        img = plot_sharpness(evaluation.sharpness, plots / "sharpness.png")
        sections.append(_section("Sharpness over distance (SPEC 3, ISO 12233)", img, outdir, ""))
        img = plot_resolution(evaluation.sharpness, plots / "intensity_resolution.png")
        table = _rows_table(resolution_table(evaluation.sharpness), "step")
        sections.append(_section("Resolution of the intensity image (thesis 6.3.1)", img, outdir, table))
    report = outdir / "report.html"
    report.write_text(_page(evaluation, doc, sections))
    return json_path, report


def _clean_rows(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    return [{k: clean(v) if isinstance(v, float) else v for k, v in row.items()} for row in rows]


def _rows_table(rows: list[dict[str, Any]], key: str) -> str:
    if not rows:
        return ""
    cols = [c for c in rows[0] if c != key]
    head = "".join(f"<th>{html.escape(c)}</th>" for c in cols)
    body = "".join(
        f'<tr><td class="l">{html.escape(str(r[key]))}</td>' + "".join(f"<td>{_fmt(r[c])}</td>" for c in cols) + "</tr>"
        for r in rows
    )
    return f'<table><tr><th class="l">{html.escape(key)}</th>{head}</tr>{body}</table>'


def _section(title: str, image: Path, outdir: Path, table: str) -> str:
    rel = image.relative_to(outdir).as_posix()
    return f'<h2>{html.escape(title)}</h2>\n<img src="{rel}" alt="{html.escape(title)}">\n{table}'


def _depth_rows(evaluation: Evaluation) -> str:
    return _rows_table(depth_table(evaluation), "step")


def _page(evaluation: Evaluation, doc: dict[str, Any], sections: list[str]) -> str:
    cam = evaluation.camera
    fig_rows = "".join(
        f'<tr><td class="l">{html.escape(name)}</td><td>{_fmt(f["value"])}</td><td class="l">{f["unit"]}</td>'
        f'<td class="l">{html.escape(FIGURE_BY_NAME[name].meaning)}</td>'
        f'<td class="l">{html.escape(f["source"] or "")}</td></tr>'
        for name, f in doc["figures"].items()
    )
    notes = "".join(f'<li class="note">{html.escape(n)}</li>' for n in evaluation.notes)
    runs = "".join(f"<li>{html.escape(r)}</li>" for r in evaluation.runs)
    simulated = " (simulated)" if cam.get("simulated") else ""
    suit = doc["suitability"]
    suit_html = (
        f'<p class="note">Not evaluated: {html.escape(suit["reason"])}</p>' if not suit.get("evaluated") else ""
    )
    return f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>labctl report: {html.escape(cam['model'])}</title>
<style>{CSS}</style></head><body>
<h1>Characterization of {html.escape(cam['model'])}{simulated}</h1>
<p>Serial {html.escape(str(cam['serial']))}, {cam['width']}&times;{cam['height']} px,
FOV {cam['fov_deg'][0]:g}&times;{cam['fov_deg'][1]:g}&deg;. Report by labctl {labctl_version()} on {now_iso()}.</p>
<ul>{runs}</ul>
{f'<ul>{notes}</ul>' if notes else ''}
<h2>Key figures</h2>
<table><tr><th class="l">name</th><th>value</th><th class="l">unit</th><th class="l">meaning</th>
<th class="l">source steps</th></tr>{fig_rows}</table>
<h2>Suitability (SPEC 9)</h2>{suit_html}
{''.join(sections)}
</body></html>
"""
