"""OUTDIR/batch.html: every run of a batch side by side, the key figures across them, the sweep's figures
over its grid and, for null sweeps that were reconciled, the thresholds' error rates."""

from __future__ import annotations

import html
import math
import statistics
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from matplotlib.figure import Figure

from labctl.batch.index import ErrorRates, NullCalibration, counts, figure_names
from labctl.batch.tasks import Summary
from labctl.evaluation.keyfigures import FIGURE_BY_NAME
from labctl.provenance import labctl_version, now_iso
from labctl.report.html import CSS
from labctl.report.plots.png import save_png

MAX_PLOTTED = 12  # figures plotted across runs (all are tabled)


def _fmt(value: Any) -> str:
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return '<span class="null">n/a</span>'
    if isinstance(value, float):
        return f"{value:.4g}"
    if isinstance(value, list):
        return html.escape(", ".join(str(v) for v in value)) or "-"
    return html.escape(str(value))


def _table(header: Sequence[str], rows: Sequence[Sequence[Any]]) -> str:
    head = "".join(f"<th>{html.escape(h)}</th>" for h in header)
    body = "".join("<tr>" + "".join(f"<td>{_fmt(v)}</td>" for v in row) + "</tr>" for row in rows)
    return f"<table><tr>{head}</tr>{body}</table>"


def _value(s: Summary, figure: str) -> float | None:
    if figure.startswith("reconcile."):
        v = s.get("reconcile", {}).get(figure.removeprefix("reconcile."))
    else:
        v = s.get("evaluate", {}).get("figures", {}).get(figure)
    return float(v) if isinstance(v, int | float) and math.isfinite(v) else None


def _runs_section(summaries: Sequence[Summary], axes: Sequence[str]) -> str:
    header = ["run"] + list(axes) + ["status", "camera", "verdict", "named", "gap before", "gap after", "gap floor",
                                     "s", "error"]
    rows = []
    for s in summaries:
        r, camera = s.get("reconcile", {}), s.get("evaluate", {}).get("camera", {})
        link = s["name"]
        rows.append([link] + [s.get("parameters", {}).get(a) for a in axes] + [
            s.get("status"), f"{camera.get('model', '')} {camera.get('serial', '')}".strip() or None,
            r.get("verdict"), r.get("named"), r.get("gap_before"), r.get("gap_after"), r.get("gap_floor"),
            s.get("seconds"), s.get("error")])
    return "<h2>Runs</h2>" + _table(header, rows)


def _figures_section(summaries: Sequence[Summary], outdir: Path) -> str:
    """Every key figure across the runs: range, median, where the extremes are; a strip plot per figure."""
    names = figure_names(summaries)
    if not names:
        return ""
    rows, plotted = [], []
    for name in names:
        values = [(s["name"], v) for s in summaries if (v := _value(s, name)) is not None]
        low, high = min(values, key=lambda p: p[1]), max(values, key=lambda p: p[1])
        rows.append([name, FIGURE_BY_NAME[name].unit if name in FIGURE_BY_NAME else "", len(values), low[1],
                     statistics.median(v for _, v in values), high[1], low[0], high[0]])
        if len(plotted) < MAX_PLOTTED:
            plotted.append((name, values))
    cols = 3
    plot_rows = math.ceil(len(plotted) / cols)
    fig = Figure(figsize=(12, 2.6 * plot_rows))
    axes = fig.subplots(plot_rows, cols, squeeze=False)
    for ax, (name, values) in zip(axes.flat, plotted):
        ax.plot(range(len(values)), [v for _, v in values], "o", ms=4)
        ax.set_title(name, fontsize=9)
        ax.set_xlabel("run (order of the index)", fontsize=8)
    for ax in list(axes.flat)[len(plotted):]:
        ax.axis("off")
    fig.tight_layout()
    image = save_png(fig, outdir / "plots" / "figures_across_runs.png", dpi=90)
    return ("<h2>Key figures across the runs</h2>" + f'<img src="{image.relative_to(outdir).as_posix()}" '
            'alt="key figures across the runs">'
            + _table(["figure", "unit", "runs", "min", "median", "max", "min at", "max at"], rows))


def grid_rows(summaries: Sequence[Summary], axes: Sequence[str], figures: Sequence[str]) -> list[list[Any]]:
    """One row per combination of the non-seed axes: its values, runs, runs ok, verdict counts, and each
    figure's mean and standard deviation over the seeds."""
    groups: dict[tuple, list[Summary]] = {}
    for s in summaries:
        groups.setdefault(tuple(str(s.get("parameters", {}).get(a)) for a in axes), []).append(s)
    rows = []
    for key, members in groups.items():
        verdicts: dict[str, int] = {}
        for s in members:
            if "verdict" in s.get("reconcile", {}):
                verdicts[s["reconcile"]["verdict"]] = verdicts.get(s["reconcile"]["verdict"], 0) + 1
        row: list[Any] = list(key) + [len(members), sum(s.get("status") == "ok" for s in members),
                                      ", ".join(f"{k} {v}" for k, v in sorted(verdicts.items())) or None]
        for figure in figures:
            values = [v for s in members if (v := _value(s, figure)) is not None]
            row += [statistics.fmean(values) if values else None,
                    statistics.stdev(values) if len(values) > 1 else None]
        rows.append(row)
    return rows


def _distinct_axes(summaries: Sequence[Summary], axes: Sequence[str]) -> list[str]:
    """The axes that take more than one value, each once: an axis that moves with an earlier one (zipped
    axes, e.g. a camera and its size) splits the runs the same way and is left out."""
    kept, seen = [], set()
    for axis in axes:
        values = [str(s.get("parameters", {}).get(axis)) for s in summaries]
        pattern = tuple(values.index(v) for v in values)  # the partition of the runs, whatever the labels
        if len(set(values)) > 1 and pattern not in seen:
            kept.append(axis)
            seen.add(pattern)
    return kept


def _grid_section(summaries: Sequence[Summary], axes: Sequence[str], figures: Sequence[str], outdir: Path) -> str:
    """The sweep's figures over its grid: the table per point of the non-seed axes, a plot per figure and axis
    that takes more than one value (the seed only when nothing else varies)."""
    varied = [a for a in axes if a != "seed"]
    header = varied + ["runs", "ok", "verdicts"] + [f"{f} {stat}" for f in figures for stat in ("mean", "sd")]
    section = "<h2>Figures over the grid</h2>" + _table(header, grid_rows(summaries, varied, figures))
    spread = _distinct_axes(summaries, axes)
    plot_axes = [a for a in spread if a != "seed"] or spread
    shown = [f for f in figures if any(_value(s, f) is not None for s in summaries)]
    if not plot_axes or not shown:
        return section
    fig = Figure(figsize=(4.2 * len(plot_axes), 2.8 * len(shown)))
    grid = fig.subplots(len(shown), len(plot_axes), squeeze=False)
    for row, figure in zip(grid, shown):
        for ax, axis in zip(row, plot_axes):
            values = [(s["parameters"].get(axis), v) for s in summaries if (v := _value(s, figure)) is not None]
            labels = sorted({x for x, _ in values}, key=lambda x: (not isinstance(x, int | float), x))
            numeric = all(isinstance(x, int | float) for x in labels)
            position = {x: (x if numeric else i) for i, x in enumerate(labels)}
            ax.plot([position[x] for x, _ in values], [v for _, v in values], "o", ms=3, alpha=0.6)
            means = [statistics.fmean(v for x, v in values if x == label) for label in labels]
            ax.plot([position[x] for x in labels], means, "-" if numeric else "_", color="tab:red", lw=1.2, ms=14,
                    label="mean")
            if not numeric:
                ax.set_xticks(range(len(labels)), [str(x) for x in labels], fontsize=8)
            ax.set_xlabel(axis, fontsize=8)
            ax.set_ylabel(figure, fontsize=8)
    fig.tight_layout()
    image = save_png(fig, outdir / "plots" / "figures_over_grid.png", dpi=90)
    return section + f'<img src="{image.relative_to(outdir).as_posix()}" alt="figures over the grid">'


def _calibration_section(calibration: NullCalibration) -> str:
    def row(label: str, c: ErrorRates) -> list[Any]:
        return [label, c.runs, ", ".join(f"{k} {v}" for k, v in sorted(c.verdicts.items())),
                f"{c.false_positive} ({c.false_positive_rate:.1%}, <= {c.false_positive_upper_95:.1%})",
                f"{c.false_unexplained} ({c.false_unexplained_rate:.1%}, <= {c.false_unexplained_upper_95:.1%})",
                c.largest_candidate_dbic, c.largest_step_ratio]

    rows = [row("all", calibration.overall)] + [row(cam, c) for cam, c in calibration.by_camera.items()]
    return (f"<h2>Reconcile on null runs</h2><p>Runs simulated with nothing the reconciled model lacks: a named "
            f"effect is a false positive, an <code>unexplained</code> verdict a false alarm (95 % upper bounds, "
            f"Clopper-Pearson). Thresholds: dBIC {calibration.dbic_threshold:g}, step gap "
            f"{calibration.step_factor:g} x its floor.</p>"
            + _table(["camera", "runs", "verdicts", "false positives", "false unexplained", "largest dBIC",
                      "largest step gap / floor"], rows))


def write_report(summaries: Sequence[Summary], outdir: Path, title: str, axes: Sequence[str] = (),
                 figures: Sequence[str] = (), calibration: NullCalibration | None = None) -> Path:
    """OUTDIR/batch.html with its plots in OUTDIR/plots."""
    n = counts(summaries)
    sections = [_runs_section(summaries, axes)]
    if axes:
        sections.append(_grid_section(summaries, axes, figures, outdir))
    if calibration is not None:
        sections.append(_calibration_section(calibration))
    sections.append(_figures_section(summaries, outdir))
    page = f"""<!DOCTYPE html>
<html><head><meta charset="utf-8"><title>{html.escape(title)}</title><style>{CSS}</style></head><body>
<h1>{html.escape(title)}</h1>
<p>{n.runs} runs, {n.ok} complete, {n.failed} failed. Every run's outputs are in its directory under
<code>runs/</code> (or <code>points/</code>); <code>index.json</code> and <code>index.csv</code> list them.
labctl {html.escape(labctl_version())}, {html.escape(now_iso())}.</p>
{''.join(sections)}
</body></html>
"""
    path = outdir / "batch.html"
    path.write_text(page)
    return path
