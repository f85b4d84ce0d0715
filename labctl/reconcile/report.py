"""OUTDIR/reconcile.json, OUTDIR/model.toml and the report OUTDIR/reconcile.html with its plots."""

from __future__ import annotations

import html
import math
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from labctl.jsondoc import write_json
from labctl.provenance import labctl_version, now_iso
from labctl.reconcile.goodness import UNITS
from labctl.reconcile.results import Determination, NotComparable, Parameters, ReconcileDocument
from labctl.reconcile.workflow import ReconcileResult, json_document
from labctl.report.html import CSS as REPORT_CSS
from labctl.report.plots.png import save_png

CSS = REPORT_CSS + ".verdict{font-size:1.3em;font-weight:600}\n"


def _step_means(maps: list[np.ndarray]) -> np.ndarray:
    return np.array([float(np.nanmean(m)) if np.isfinite(m).any() else math.nan for m in maps])


def _step_rms(maps: list[np.ndarray]) -> np.ndarray:
    return np.array([float(np.sqrt(np.nanmean(m**2))) if np.isfinite(m).any() else math.nan for m in maps])


def _radius(shape: tuple[int, int]) -> np.ndarray:
    h, w = shape
    y, x = np.mgrid[0:h, 0:w]
    return np.hypot(x - (w - 1) / 2, y - (h - 1) / 2) / math.hypot(w / 2, h / 2)


def plot_residuals(result: ReconcileResult, path: Path) -> Path:
    """Per-step mean depth residual before/after vs distance, robot angle and time; bin residual vs radius."""
    before, after = result.iterations[0].residual_z, result.residual_after
    scenes = [o.scene for o in result.observations]
    times = np.array([float(np.mean(o.times_s)) if len(o.times_s) else math.nan for o in result.observations])
    times = times - np.nanmin(times) if np.isfinite(times).any() else times
    mb, ma = _step_means(before), _step_means(after)
    stage = np.array([s.wall_distance_mm is not None for s in scenes])
    fig = Figure(figsize=(11, 7.5))
    axes = fig.subplots(2, 2)
    for ax, x, mask, label in ((axes[0, 0], [s.wall_distance_mm or math.nan for s in scenes], stage,
                                "camera-target distance (mm)"),
                               (axes[0, 1], [s.robot_angle_deg if s.robot_angle_deg is not None else math.nan
                                             for s in scenes], ~stage, "robot angle (deg)"),
                               (axes[1, 1], times, np.ones(len(scenes), bool), "time since the first frame (s)")):
        x = np.asarray(x, float)
        ax.plot(x[mask], mb[mask], "o", color="tab:red", label="before", ms=4)
        ax.plot(x[mask], ma[mask], "s", color="tab:blue", label="after", ms=4, mfc="none")
        ax.axhline(0, color="0.6", lw=0.8)
        ax.set_xlabel(label)
        ax.set_ylabel("mean depth residual (mm)")
        ax.legend(fontsize=8)
        if not mask.any():
            ax.text(0.5, 0.5, "no such steps in the run", transform=ax.transAxes, ha="center", color="0.5")
    ax = axes[1, 0]
    edges = np.linspace(0, 1, 21)
    for maps, style, label in ((before, "o-", "before"), (after, "s--", "after")):
        r = np.concatenate([_radius(m.shape)[np.isfinite(m)] for m in maps])
        v = np.concatenate([m[np.isfinite(m)] for m in maps])
        idx = np.clip(np.digitize(r, edges) - 1, 0, len(edges) - 2)
        count = np.bincount(idx, minlength=len(edges) - 1)
        with np.errstate(invalid="ignore", divide="ignore"):
            rms = np.sqrt(np.bincount(idx, v * v, len(edges) - 1) / count)
        ax.plot((edges[:-1] + edges[1:]) / 2, rms, style, label=label, ms=4)
    ax.set_xlabel("pixel radius (fraction of the half diagonal)")
    ax.set_ylabel("RMS depth residual (mm)")
    ax.legend(fontsize=8)
    fig.suptitle("measurement - simulation (lab nuisance removed): before and after reconcile")
    fig.tight_layout()
    return save_png(fig, path, dpi=100)


def _bin_mean(maps: list[np.ndarray]) -> np.ndarray:
    """Mean over steps per bin (NaN where no step compared that bin)."""
    stack = np.stack(maps)
    count = np.isfinite(stack).sum(axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(count > 0, np.nansum(stack, axis=0) / count, np.nan)


def plot_residual_map(result: ReconcileResult, path: Path) -> Path:
    """Where on the sensor the disagreement sits: mean depth residual per bin over all steps, before/after."""
    fig = Figure(figsize=(11, 3.8))
    axes = fig.subplots(1, 2)
    before, after = _bin_mean(result.iterations[0].residual_z), _bin_mean(result.residual_after)
    lim = float(np.nanpercentile(np.abs(before), 98)) if np.isfinite(before).any() else 1.0
    for ax, data, title in ((axes[0], before, "before"), (axes[1], after, "after")):
        im = ax.imshow(data, cmap="RdBu_r", vmin=-lim, vmax=lim)
        ax.set_title(f"mean depth residual per bin, {title}")
        ax.set_xticks([])
        ax.set_yticks([])
        fig.colorbar(im, ax=ax, label="mm")
    fig.tight_layout()
    return save_png(fig, path, dpi=100)


def plot_candidates(result: ReconcileResult, path: Path) -> Path:
    """Every round's candidate scores (dBIC over steps) against the threshold (with null runs: the value the best
    must exceed for p <= alpha against the null replicas' best)."""
    rounds = [it for it in result.iterations if it.fits]
    fig = Figure(figsize=(4.2 * max(len(rounds), 1), 3.6))
    axes = fig.subplots(1, max(len(rounds), 1), squeeze=False)
    for ax, (i, it) in zip(axes[0], enumerate(rounds), strict=False):
        names = [f.name for f in it.fits][::-1]
        scores = [max(f.score, -20.0) for f in it.fits][::-1]
        threshold = result.rule.threshold({f.name for f in it.fits})
        ax.barh(names, scores, color=["tab:green" if s >= threshold else "0.6" for s in scores])
        if math.isfinite(threshold):
            ax.axvline(threshold, color="tab:red", ls="--", lw=1)
        ax.set_title(f"round {i + 1}: {it.decision}", fontsize=9)
        ax.set_xlabel("dBIC over steps")
        ax.tick_params(labelsize=8)
    fig.tight_layout()
    return save_png(fig, path, dpi=100)


def _rms_text(values: np.ndarray) -> str:
    """RMS of the finite ``values`` to 3 decimals, or "n/a" when a procedure has no usable step."""
    finite = values[np.isfinite(values)]
    return f"{np.sqrt(np.mean(finite ** 2)):.3f}" if finite.size else "n/a"


def plot_unexplained(result: ReconcileResult, path: Path) -> Path:
    """The unexplained residual: its curve over the carrying axis and its mean map over the sensor."""
    u = result.unexplained
    fig = Figure(figsize=(11, 3.8))
    axes = fig.subplots(1, 2)
    ax = axes[0]
    curve = u.curve if u is not None and u.curve else []
    if u is not None and curve:
        xs = [c.x for c in curve]
        numeric = all(isinstance(x, (int, float)) for x in xs)
        ax.plot(xs if numeric else range(len(xs)), [c.mean_mm for c in curve], "o-", color="tab:purple", ms=4)
        if not numeric:
            ax.set_xticks(range(len(xs)), xs, rotation=30, fontsize=8)
        ax.axhline(0, color="0.6", lw=0.8)
        axis = next(a for a in u.axes if a.axis == u.carrying_axis)
        ax.set_xlabel(f"{u.carrying_axis} ({axis.unit})" if axis.unit else u.carrying_axis)
    else:
        ax.text(0.5, 0.5, "no single axis carries the residual", transform=ax.transAxes, ha="center", color="0.5")
    ax.set_ylabel("mean depth residual (mm)")
    ax.set_title("curve over the carrying axis", fontsize=9)
    data = np.array([[math.nan if v is None else v for v in row] for row in (u.spatial_map_mm if u else [])], float)
    if data.size and np.isfinite(data).any():
        lim = float(np.nanpercentile(np.abs(data), 98)) or 1.0
        im = axes[1].imshow(data, cmap="RdBu_r", vmin=-lim, vmax=lim)
        fig.colorbar(im, ax=axes[1], label="mm")
    axes[1].set_title("mean residual per bin over all steps (physical effects only)", fontsize=9)
    axes[1].set_xticks([])
    axes[1].set_yticks([])
    fig.tight_layout()
    return save_png(fig, path, dpi=100)


def _unexplained(result: ReconcileResult, plot: Path | None) -> str:
    u = result.unexplained
    if u is None:
        return ""
    rows = "".join(f"<tr><td class=l>{html.escape(a.axis)}</td><td>{a.eta2:.3f}</td><td>{a.effect_mm:.3f}</td>"
                   f"<td>{'' if a.same_at_every_distance is None else a.same_at_every_distance}</td></tr>"
                   for a in u.axes)
    empirical = "".join(f"<li><b>{html.escape(e.name)}</b> (empirical): gap {e.gap_before_mm:.3f} &rarr; "
                        f"{e.gap_after_mm:.3f} mm</li>" for e in result.empirical)
    return (f"<h2>Unexplained residual</h2><p class=note>{html.escape(u.message or '')}</p>"
            "<table><tr><th class=l>axis</th><th>share of the residual (eta&sup2;)</th><th>peak to peak (mm)</th>"
            f"<th>same at every distance</th></tr>{rows}</table>"
            + (f"<p>Empirical corrections in the model:</p><ul>{empirical}</ul>" if empirical else "")
            + (f'<img src="{plot.name}" alt="unexplained residual">' if plot else ""))


def _goodness(result: ReconcileResult) -> str:
    g, p = result.goodness_after, result.goodness_physical
    if g is None or p is None:
        return ""
    worst = p.worst_step
    judged = result.rule.judge(p)
    against = (f" (against {judged.null_runs} null runs of the campaign: p = {judged.p_value:.3f})"
               if judged else " (the fixed floors)")
    return (f"<p>Noise floor of the gap: <b>{g.gap_floor_mm:.3f} mm</b> (intensity {g.intensity_gap_floor_pct:.2f} %). "
            f"With the named physical effects the residual is <b>"
            f"{'consistent' if result.rule.consistent(p) else 'NOT consistent'}</b> with the noise{against}"
            + (f" (worst step {html.escape(worst.step_id)}: {worst.gap:.3f} against its floor {worst.floor:.3f} in "
               f"{worst.family})" if worst else "") + ".</p>" + _families(result))


def _families(result: ReconcileResult) -> str:
    """Every residual family's gap before and after against its floor, and the steps each left out."""
    before, after = result.goodness_before, result.goodness_after
    if before is None or after is None:
        return ""

    def cell(value: float) -> str:
        return f"{value:.3f}" if math.isfinite(value) else "&ndash;"

    rows = "".join(
        f"<tr><td class=l>{family}</td><td>{cell(before.family_gap(family)[0])}</td>"
        f"<td>{cell(after.family_gap(family)[0])}</td><td>{cell(after.family_gap(family)[1])}</td>"
        f"<td class=l>{html.escape(UNITS[family])}</td>"
        f"<td class=l>{'yes' if after.family_consistent(family) else 'NO'}</td></tr>" for family in after.families)
    left_out = "".join(f"<li>{html.escape(e.step)} ({html.escape(e.family)}): {html.escape(e.reason)}</li>"
                       for e in result.excluded)
    return ("<table><tr><th class=l>family</th><th>gap before</th><th>gap after</th><th>floor</th>"
            f"<th class=l>unit</th><th class=l>consistent</th></tr>{rows}</table>"
            + (f"<p>Steps left out of a family's comparison:</p><ul>{left_out}</ul>" if left_out else ""))


def _corners(result: ReconcileResult) -> str:
    """The checkerboard corner families: gap against floor before and after, and the effects they named."""
    c = result.corners
    if c is None:
        return ""
    before, after = c.before.summary().families(), c.after.summary().families()
    rows = "".join(
        f"<tr><td class=l>{family}</td><td>{before[family].gap}</td><td>{a.gap}</td>"
        f"<td>{a.gap_floor}</td><td class=l>{'yes' if a.consistent_with_noise else 'NO'}</td></tr>"
        for family, a in after.items())
    named = "".join(
        f"<li><b>{html.escape(e.name)}</b>: {_params(e.parameters, e.evidence.stderr)}"
        f"{_determination(e.evidence.determination)} (dBIC {e.evidence.delta_bic:.1f}; corner gap "
        f"{e.evidence.gap_before_mm:.3f} &rarr; {e.evidence.gap_after_mm:.3f} mm, "
        f"{e.evidence.gap_before_px:.3f} &rarr; {e.evidence.gap_after_px:.3f} px)</li>" for e in c.named)
    decisions = "; ".join(html.escape(r.decision) for r in c.rounds)
    return (f"<h2>Checkerboard corners</h2><p>Steps {html.escape(', '.join(c.steps))}: measured corner positions "
            "against the simulated ones, in mm in the board plane (image: px converted by the board distance over "
            f"the focal length; cloud: the lateral position the point cloud gives the corner). Image gap "
            f"{c.before.gap_px:.3f} &rarr; {c.after.gap_px:.3f} px (floor {c.after.gap_floor_px:.3f} px).</p>"
            "<table><tr><th class=l>family</th><th>gap before (mm)</th><th>gap after (mm)</th><th>floor (mm)</th>"
            f"<th class=l>consistent with noise</th></tr>{rows}</table>"
            + (f"<ul>{named}</ul>" if named else "<p>No effect named from the corners.</p>")
            + f"<p>Rounds: {decisions}.</p>")


def _not_comparable_page(nc: NotComparable) -> str:
    needed = "".join(f"<li><b>{html.escape(k)}</b>: {html.escape(v)}</li>" for k, v in nc.procedures_needed.items())
    return (f"<p class=note>Nothing to compare: {html.escape(nc.reason)}.</p>"
            f"<p>Procedures that would give the comparison something to work with:</p><ul>{needed}</ul>"
            f"<p>{html.escape(nc.not_compared)}</p>")


def _where(result: ReconcileResult) -> str:
    """Per procedure and the worst steps, before the reconcile."""
    before, after = result.iterations[0].residual_z, result.residual_after
    rb, ra = _step_rms(before), _step_rms(after)
    scenes = [o.scene for o in result.observations]
    rows = []
    for proc in sorted({s.procedure for s in scenes}):
        idx = [i for i, s in enumerate(scenes) if s.procedure == proc]
        rows.append(f"<tr><td class=l>{html.escape(proc)}</td><td>{len(idx)}</td>"
                    f"<td>{_rms_text(rb[idx])}</td><td>{_rms_text(ra[idx])}</td></tr>")
    worst = [i for i in np.argsort(-np.nan_to_num(rb))[:6] if np.isfinite(rb[i])]
    steps = []
    for i in worst:
        s = scenes[i]
        where = f"{s.wall_distance_mm:.0f} mm" if s.wall_distance_mm is not None else f"{s.robot_angle_deg:g} deg"
        steps.append(f"<tr><td class=l>{html.escape(s.step_id)}</td><td class=l>{html.escape(s.target)} at {where}</td>"
                     f"<td>{rb[i]:.3f}</td><td>{ra[i]:.3f}</td></tr>")
    return ("<table><tr><th class=l>procedure</th><th>steps</th><th>RMS before (mm)</th><th>RMS after (mm)</th></tr>"
            + "".join(rows) + "</table><p>Steps that disagreed most:</p><table><tr><th class=l>step</th>"
            "<th class=l>target</th><th>RMS before (mm)</th><th>RMS after (mm)</th></tr>" + "".join(steps) + "</table>")


def _params(params: Parameters, stderr: dict[str, float]) -> str:
    parts = []
    for k, v in params.items():
        if isinstance(v, float):
            err = f" &plusmn; {stderr[k]:.3g}" if k in stderr else ""
            parts.append(f"{html.escape(k)} = {v:.4g}{err}")
        else:
            parts.append(f"{html.escape(k)} = {html.escape(str(v))}")
    return ", ".join(parts)


def write_reconcile(result: ReconcileResult, measured: Path, output: Path) -> tuple[Path, Path, ReconcileDocument]:
    """Write model.toml, reconcile.json and reconcile.html (with PNGs) into ``output``; returns the report's and
    the model's paths and the document reconcile.json holds."""
    output.mkdir(parents=True, exist_ok=True)
    model_path = output / "model.toml"
    model_path.write_text(result.model_toml(), encoding="utf-8")
    doc = json_document(result, model_path)
    write_json(output / "reconcile.json", doc)
    if result.not_comparable is not None or not result.iterations:
        page = _not_comparable_page(result.not_comparable) if result.not_comparable is not None else _corners(result)
        return _write_page(output, measured, result, model_path, page), model_path, doc
    plots = [plot_residuals(result, output / "reconcile_residuals.png"),
             plot_residual_map(result, output / "reconcile_map.png"),
             plot_candidates(result, output / "reconcile_candidates.png")]
    unexplained_plot = plot_unexplained(result, output / "reconcile_unexplained.png") if result.unexplained else None
    named = "".join(
        f"<tr><td class=l>{html.escape(e.name)}</td><td class=l>{_params(e.parameters, e.evidence.stderr)}"
        f"{_determination(e.evidence.determination)}</td>"
        f"<td>{e.evidence.delta_bic:.1f}</td><td>{_loso(e.evidence.loso_gain)}</td>"
        f"<td class=l>{html.escape(str(e.evidence.runner_up))}</td>"
        f"<td>{e.evidence.gap_before_mm:.3f} &rarr; {e.evidence.gap_after_mm:.3f}</td></tr>"
        for e in result.named)
    rounds = "".join(
        f"<h3>Round {i + 1}: {html.escape(it.decision)} (model effects: {html.escape(', '.join(it.model_effects) or 'none')};"
        f" gap {it.gap_mm:.3f} mm)</h3>"
        + ("<table><tr><th class=l>candidate</th><th>dBIC</th><th>LOSO gain</th><th class=l>linear fit</th></tr>"
           + "".join(f"<tr><td class=l>{html.escape(f.name)}</td><td>{f.score:.1f}</td><td>{f.loso_gain:.3f}</td>"
                     f"<td class=l>{_params(f.params, {})}</td></tr>" for f in it.fits) + "</table>"
           if it.fits else "<p>No candidate scored: the model is consistent with the noise and names nothing more.</p>")
        for i, it in enumerate(result.iterations))
    ambiguity = ""
    if result.ambiguity:
        a = result.ambiguity
        ambiguity = (f"<p class=note>Ambiguous between {html.escape(a.between[0])} and {html.escape(a.between[1])}"
                     f" (dBIC {a.scores[0]:.1f} vs {a.scores[1]:.1f}). A capture this run does not hold would separate "
                     f"them: {html.escape(a.separating_capture)}.</p>")
    body = f"""{ambiguity}{_goodness(result)}
<p>Gap (RMS of the systematic mean-depth residual over every compared bin, lab nuisance removed, stack noise
subtracted): <b>{result.gap_before:.3f} mm &rarr; {result.gap_after:.3f} mm</b>; intensity gap
{result.intensity_gap_before:.2f} % &rarr; {result.intensity_gap_after:.2f} %.</p>
<h2>Named effects</h2>
<table><tr><th class=l>effect</th><th class=l>parameters (&plusmn; statistical standard error)</th><th>dBIC</th>
<th>LOSO gain</th><th class=l>runner-up</th><th>gap (mm)</th></tr>{named or '<tr><td colspan=6>none</td></tr>'}</table>
{_unexplained(result, unexplained_plot)}{_corners(result)}
<h2>Where the disagreement sits</h2>{_where(result)}
<img src="{plots[1].name}" alt="residual map">
<h2>Residuals before and after</h2><img src="{plots[0].name}" alt="residual plots">
<h2>Candidates</h2><img src="{plots[2].name}" alt="candidate scores">{rounds}"""
    return _write_page(output, measured, result, model_path, body), model_path, doc


def _loso(gain: float | None) -> str:
    """The leave-one-step-out gain, or what stands in for it: effects named from the checkerboard corners are
    scored over the corners, not cross-validated by step."""
    return f"{gain:.3f}" if gain is not None else "(corners)"


def _determination(det: Determination) -> str:
    if det.well_determined:
        return ""
    return (f"<br><span class=note>poorly determined: {html.escape('; '.join(det.problems))}. "
            f"Capture that would fix it: {html.escape(str(det.capture))}</span>")


def _write_page(output: Path, measured: Path, result: ReconcileResult, model_path: Path, body: str) -> Path:
    notes = "".join(f"<li>{html.escape(n)}</li>" for n in result.notes)
    page = f"""<!doctype html><html><head><meta charset="utf-8"><title>labctl reconcile: {html.escape(measured.name)}</title>
<style>{CSS}</style></head><body>
<h1>Reconcile: {html.escape(measured.name)}</h1>
<p>labctl {html.escape(labctl_version())}, {html.escape(now_iso())}. Model compared: camera
<b>{html.escape(result.model.camera)}</b>; corrected model: <code>{html.escape(str(model_path))}</code>.</p>
<p class=verdict>Verdict: {html.escape(result.verdict)}</p>{body}
<h2>Notes</h2><ul>{notes}</ul>
</body></html>"""
    report = output / "reconcile.html"
    report.write_text(page, encoding="utf-8")
    return report
