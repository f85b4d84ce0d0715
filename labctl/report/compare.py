"""Side-by-side comparison of cameras from their evaluations (Thesis 2024, 6.6, Fig. 6-12; README.md, Command line).

Input: the output directories of ``labctl evaluate`` (their ``keyfigures.json``).
Output: ``compare.json`` (every figure per camera, the suitability verdicts),
``compare.html`` with the Fig. 6-12 style chart (all figures, lower is better;
the signed figures, where closer to 0 is better, as their magnitude |value|;
angular resolutions x 10 as in Thesis 2024 so they share the axis; fill rates,
where higher is better, are left out), the datasheet-comparable figures with
where they are defined, the
inter-eye-distance coverage per camera against the 90 px requirement, and the
suitability matrix.
"""

from __future__ import annotations

import html
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from labctl.errors import InputError
from labctl.evaluation.keyfigures import (
    FIGURES,
    VENDOR_FIGURES,
    FigureEntry,
    KeyFiguresDocument,
    better_direction,
    read_keyfigures,
)
from labctl.evaluation.suitability import IED_MIN_PX
from labctl.jsondoc import write_json
from labctl.provenance import labctl_version, now_iso
from labctl.report.html import CSS, better_text, references_html, verdict_cell, wrap_table, wrappable
from labctl.report.plots.png import save_png
from metrics.uncertainty import distinguishable

#: figures left out of the chart (different scale or "higher is better")
NOT_CHARTED = {"hyperfocal_distance_mm", "best_focus_distance_mm", "ied_pixels_at_hyperfocal",
               "ied_pixels_at_hyperfocal_angular",
               "fill_rate_1000mm_pct", "fill_rate_2000mm_pct",
               # ~0 at the principal point whatever the noise (the off-axis figures are charted instead)
               "x_repeatability_center_mm", "y_repeatability_center_mm"}
TIMES_TEN = {"intensity_resolution_h_deg", "intensity_resolution_v_deg", "cloud_resolution_h_deg",
             "cloud_resolution_v_deg"}


@dataclass(kw_only=True)
class CompareDocument:
    """``compare.json``: the cameras' labels (their models, ``*`` for simulated, numbered where repeated), the
    evaluation directories they come from, and by label: every defined figure's value (None where not
    measured), each user story's verdict and its one-line reason; the user stories' names; and per figure the
    plausibility checks it fails, for the cameras where it fails any (figures failing none left out); per figure
    the expanded uncertainties (k = 2) the evaluations state, and the pairs of cameras whose values (their
    magnitudes, for figures better closer to 0) differ by no more than the expanded uncertainty of the
    difference: not distinguishable, so not ranked (figures with none left out); and per figure which way it
    improves (``better``: lower, higher, zero or none, as in keyfigures.json)."""

    cameras: list[str]
    sources: list[str]
    figures: dict[str, dict[str, float | None]]  # figure -> label -> value
    suitability: dict[str, dict[str, str]]  # label -> story -> verdict
    reasons: dict[str, dict[str, str]]  # label -> story -> reason
    stories: dict[str, str]  # story -> its description
    flags: dict[str, dict[str, list[str]]]  # figure -> label -> failed checks
    expanded_uncertainty: dict[str, dict[str, float]] = field(default_factory=dict)  # figure -> label -> U
    not_distinguishable: dict[str, list[list[str]]] = field(default_factory=dict)  # figure -> [label, label] pairs
    better: dict[str, str] = field(default_factory=dict)  # figure -> lower / higher / zero / none


def load_evaluation(directory: Path) -> KeyFiguresDocument:
    """The ``keyfigures.json`` of an output directory of ``labctl evaluate`` (InputError when it has none)."""
    return read_keyfigures(Path(directory) / "keyfigures.json")


def camera_label(doc: KeyFiguresDocument) -> str:
    """The camera's model as the comparison labels it (``*`` for simulated)."""
    return str(doc.camera.model).replace(" (simulated)", "*")


def compare(directories: list[Path], outdir: Path) -> Path:
    """Write compare.json, compare.html and their plots; returns the HTML path."""
    if len(directories) < 1:
        raise InputError("give at least one evaluation directory")
    docs = [load_evaluation(d) for d in directories]
    labels = _unique([camera_label(d) for d in docs])
    outdir.mkdir(parents=True, exist_ok=True)
    plots = outdir / "plots"
    plots.mkdir(exist_ok=True)
    table = {fig.name: {label: _figure(doc, fig.name).value for label, doc in zip(labels, docs)} for fig in FIGURES}
    verdicts = {label: {k: v.verdict for k, v in doc.suitability.stories.items()} for label, doc in zip(labels, docs)}
    reasons = {label: {k: v.summary for k, v in doc.suitability.stories.items()} for label, doc in zip(labels, docs)}
    flags = {fig.name: {label: [f["check"] for f in _figure(doc, fig.name).flags]
                        for label, doc in zip(labels, docs) if _figure(doc, fig.name).flags}
             for fig in FIGURES}
    uncertainty = {fig.name: {label: u for label, doc in zip(labels, docs)
                              if (u := _figure(doc, fig.name).expanded_uncertainty) is not None and math.isfinite(u)}
                   for fig in FIGURES}
    uncertainty = {k: v for k, v in uncertainty.items() if v}
    result = CompareDocument(cameras=labels, sources=[str(d) for d in directories], figures=table,
                             suitability=verdicts, reasons=reasons, stories=_story_names(docs),
                             flags={k: v for k, v in flags.items() if v}, expanded_uncertainty=uncertainty,
                             not_distinguishable=_not_distinguishable(table, uncertainty, labels),
                             better={fig.name: better_direction(fig.name) for fig in FIGURES})
    write_json(outdir / "compare.json", result, final_newline=True)
    chart = _chart(table, labels, plots / "comparison.png")
    ied = _ied_chart(table["ied_pixels_at_hyperfocal"], labels, plots / "ied_coverage.png")
    page = outdir / "compare.html"
    page.write_text(_page(result, chart.relative_to(outdir), ied.relative_to(outdir)))
    return page


def _not_distinguishable(table: dict[str, dict[str, float | None]], uncertainty: dict[str, dict[str, float]],
                         labels: list[str]) -> dict[str, list[list[str]]]:
    """Per figure, the pairs of cameras whose values differ by no more than the expanded uncertainty of their
    difference (``metrics.uncertainty.distinguishable``), compared as the ranking compares them: by magnitude
    for figures better closer to 0. Pairs where either has no stated uncertainty are not judged."""
    pairs: dict[str, list[list[str]]] = {}
    for name, stated in uncertainty.items():
        ranked = {label: abs(v) if better_direction(name) == "zero" else v for label in labels
                  if (v := table[name].get(label)) is not None and math.isfinite(v) and label in stated}
        close = [[a, b] for i, a in enumerate(labels) for b in labels[i + 1:] if a in ranked and b in ranked
                 and not distinguishable(ranked[a], stated[a], ranked[b], stated[b])]
        if close:
            pairs[name] = close
    return pairs


def story_name(key: str) -> str:
    """A readable name for a user-story id an evaluation did not describe: ``3d_face_recognition_1_to_n`` ->
    ``3D face recognition 1:N``."""
    words = {"3d": "3D", "pad": "PAD", "nir": "NIR", "rgb": "RGB"}
    text = " ".join(words.get(w, w) for w in key.split("_"))
    return text.replace(" 1 to n", " 1:N").replace(" 1 to 1", " 1:1")


def _figure(doc: KeyFiguresDocument, name: str) -> FigureEntry:
    """A figure of an evaluation; one its version of labctl did not define reads as not measured."""
    return doc.figures.get(name) or FigureEntry(value=None, unit="", source="", meaning="", flags=[],
                                                better=better_direction(name))


def _story_names(docs: list[KeyFiguresDocument]) -> dict[str, str]:
    """User-story id -> its description as the evaluations give it (a readable form of the id otherwise)."""
    names: dict[str, str] = {}
    for doc in docs:
        for key, story in doc.suitability.stories.items():
            names.setdefault(key, story.description or story_name(key))
    return names


def _unique(labels: list[str]) -> list[str]:
    seen: dict[str, int] = {}
    out = []
    for label in labels:
        seen[label] = seen.get(label, 0) + 1
        out.append(label if seen[label] == 1 else f"{label} ({seen[label]})")
    return out


def _chart(table: dict[str, dict[str, float | None]], labels: list[str], path: Path) -> Path:
    names = [f.name for f in FIGURES if f.name not in NOT_CHARTED]
    fig = Figure(figsize=(14, 6))
    ax = fig.subplots()
    width = 0.8 / max(len(labels), 1)
    x = np.arange(len(names))
    floor = _chart_floor(table, names, labels)
    for k, label in enumerate(labels):
        values = np.array([_charted(name, table[name][label]) for name in names])
        positions = x + (k - (len(labels) - 1) / 2) * width
        bars = ax.bar(positions, values, width, label=label)
        colour = bars.patches[0].get_facecolor() if bars.patches else None
        for pos, v in zip(positions, values):
            if v == 0 or not math.isfinite(v):  # a log axis cannot draw 0: say it instead of leaving a gap
                ax.text(pos, floor, "0" if v == 0 else "n/a", rotation=90, ha="center", va="bottom", fontsize=8,
                        fontweight="bold", color=colour)
    ax.set_xticks(x)
    ax.set_xticklabels([chart_label(n) for n in names], rotation=70, ha="right", fontsize=8)
    ax.set_yscale("log")
    ax.set_ylim(bottom=floor)
    ax.set_ylabel("value (mm, %, deg x10); lower is better,\n|value| of signed figures: closer to 0 is better")
    ax.set_title("Key figures of the cameras (Thesis 2024, Fig. 6-12); labels at the foot: 0 = value zero, "
                 "n/a = not measured", pad=28)
    ax.grid(axis="y", alpha=0.3, which="both")
    ax.legend(ncol=max(len(labels), 1), loc="lower center", bbox_to_anchor=(0.5, 1.0), fontsize=9, frameon=False)
    fig.tight_layout()
    return save_png(fig, path, dpi=100)


def chart_label(name: str) -> str:
    """A figure's label under its bars: ``|name|`` for a signed figure (its magnitude is charted), `` x10`` for the
    angular resolutions."""
    label = f"|{name}|" if better_direction(name) == "zero" else name
    return label + (" x10" if name in TIMES_TEN else "")


def _charted(name: str, value: float | None) -> float:
    """The bar height of a figure: |value| (x 10 for angular resolutions), NaN when not measured."""
    if value is None or not math.isfinite(value):
        return math.nan
    return abs(value) * (10 if name in TIMES_TEN else 1)


def _chart_floor(table: dict[str, dict[str, float | None]], names: list[str], labels: list[str]) -> float:
    """Foot of the log axis: a decade below the smallest non-zero bar (0.001 when there is none)."""
    heights = [_charted(n, table[n][label]) for n in names for label in labels]
    positive = [h for h in heights if math.isfinite(h) and h > 0]
    return 10.0 ** (math.floor(math.log10(min(positive))) - 1) if positive else 1e-3


#: the IED chart shows ``ied_pixels_at_hyperfocal``: the pinhole count at the image centre (docs/suitability.md)
IED_TITLE = "Inter-eye distance at the hyperfocal distance\n(pinhole, face at the image centre)"


def _ied_chart(ied: dict[str, float | None], labels: list[str], path: Path) -> Path:
    fig = ied_figure(ied, labels)
    return save_png(fig, path, dpi=100)


def ied_figure(ied: dict[str, float | None], labels: list[str]) -> Figure:
    """The IED coverage bars of each camera against the 90 px requirement (ISO/IEC 39794-5:2019, Annex D)."""
    fig = Figure(figsize=(7, 3.8))
    ax = fig.subplots()
    values = [ied[label] if ied[label] is not None else np.nan for label in labels]
    bars = ax.bar(labels, values, color=["tab:green" if v >= IED_MIN_PX else "tab:red" for v in np.nan_to_num(values)])
    ax.bar_label(bars, labels=[f"{v:.0f} px" if math.isfinite(v) else "" for v in values], label_type="center",
                 color="white", fontsize=9, fontweight="bold")  # inside the bars: clear of the required line
    for k, v in enumerate(values):
        if not math.isfinite(v):  # no bar to label: say so at its foot
            ax.text(k, 2.0, "n/a", ha="center", va="bottom", fontsize=9, fontweight="bold", color="tab:gray")
    ax.set_xlim(-0.5, len(labels) - 0.5)  # every camera keeps its place, with or without a bar
    ax.axhline(IED_MIN_PX, color="black", linestyle="--", label=f"required {IED_MIN_PX:g} px (ISO/IEC 39794-5)")
    ax.set_ylim(bottom=0)  # the "n/a" labels at the foot stay inside the axes when no camera has a bar
    ax.set_ylabel("px across 62.5 mm\nat the hyperfocal distance")
    ax.set_title(IED_TITLE, pad=24)
    ax.legend(loc="lower center", bbox_to_anchor=(0.5, 1.0), frameon=False, fontsize=8)  # above the bars, never on them
    fig.tight_layout()
    return fig


def _fmt(value: float | None) -> str:
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return '<span class="null">n/a</span>'  # styled by the shared CSS
    if isinstance(value, float):
        return f"{value:.0f}" if abs(value) >= 100 else f"{value:.3g}"
    return html.escape(str(value))


def _with_uncertainty(result: CompareDocument, name: str, label: str) -> str:
    """A key-figure cell: the value, its expanded uncertainty where stated, the cameras it is not distinguishable
    from, and its plausibility flags."""
    cell = _fmt(result.figures[name][label])
    u = result.expanded_uncertainty.get(name, {}).get(label)
    if u is not None:
        cell += f" &plusmn; {_fmt(u)}"
    twins = [b if a == label else a for a, b in result.not_distinguishable.get(name, []) if label in (a, b)]
    if twins:
        cell += ('<br><span class="note">not distinguishable from '
                 + ", ".join(html.escape(t) for t in twins) + "</span>")
    return cell + "".join(f'<br><span class="note">&#9888; {html.escape(c.replace("_", " "))}</span>'
                          for c in result.flags.get(name, {}).get(label, []))


def _page(result: CompareDocument, chart: Path, ied: Path) -> str:
    labels = result.cameras
    head = "".join(f"<th>{html.escape(label)}</th>" for label in labels)
    story_head = "".join(f'<th class="l">{html.escape(label)}</th>' for label in labels)  # over left-aligned verdicts
    units = {f.name: f.unit for f in FIGURES}
    rows = "".join(
        f'<tr><td class="l">{wrappable(name)}</td><td class="l">{units[name]}</td><td class="l">{better_text(name)}</td>'
        + "".join(f"<td>{_with_uncertainty(result, name, label)}</td>" for label in labels)
        + "</tr>"
        for name in result.figures
    )
    vendor_rows = "".join(
        f'<tr><td class="l">{wrappable(f.name)}</td><td class="l">{f.unit}</td>'
        + "".join(f"<td>{_fmt(result.figures[f.name][label])}</td>" for label in labels)
        + f'<td class="l">{html.escape(f.section)}</td></tr>'
        for f in VENDOR_FIGURES
    )
    suit_rows = "".join(
        f'<tr><td class="l">{html.escape(name)}</td>'
        + "".join(verdict_cell(result.suitability[label].get(story, "not_evaluated"),
                               result.reasons.get(label, {}).get(story, "")) for label in labels) + "</tr>"
        for story, name in result.stories.items()
    )
    return f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>labctl camera comparison</title>
<style>{CSS}</style></head><body>
<h1>Camera comparison</h1>
<p>labctl {labctl_version()}, {now_iso()}. Cameras marked * were simulated.</p>
<img src="{chart.as_posix()}" alt="key figures per camera">
<h2>Inter-eye distance coverage</h2><img src="{ied.as_posix()}" alt="IED coverage">
<p>Pixels across the 62.5 mm inter-eye distance of a face at the image centre at the hyperfocal distance, pinhole
model (<code>ied_pixels_at_hyperfocal</code>); the mean angular pixel size of Thesis 2024, eq. 6-2 counts more
(<code>ied_pixels_at_hyperfocal_angular</code>, in the key figures below).</p>
<h2>Suitability (Thesis 2024, Ch. 3, 6.6)</h2>
{wrap_table(f'<table><tr><th class="l">user story</th>{story_head}</tr>{suit_rows}</table>')}
<h2>Datasheet-comparable figures</h2>
<p>As the camera vendors' tools define them; set them next to the datasheets.</p>
{wrap_table(f'<table><tr><th class="l">figure</th><th class="l">unit</th>{head}<th class="l">defined by</th></tr>'
             f'{vendor_rows}</table>')}
<h2>Key figures</h2>
<p>value &plusmn; U: the expanded uncertainty (k = 2) where the evaluation states it. Two cameras whose values
(magnitudes, for figures better closer to 0) differ by no more than sqrt(U<sub>1</sub><sup>2</sup> +
U<sub>2</sub><sup>2</sup>) are marked not distinguishable: neither ranks above the other in that figure.</p>
{wrap_table(f'<table><tr><th class="l">figure</th><th class="l">unit</th><th class="l">better</th>{head}</tr>{rows}</table>')}
{references_html()}
</body></html>
"""
