"""keyfigures.json and the self-describing HTML report."""

from __future__ import annotations

import html
import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, TypeVar, cast

from labctl.evaluation.capture import capture_table
from labctl.evaluation.conditions import RunConditions
from labctl.evaluation.depth_quality import vendor_table
from labctl.evaluation.evaluate import Evaluation, depth_table, judged_suitability
from labctl.evaluation.keyfigures import (
    FIGURE_BY_NAME,
    VENDOR_FIGURES,
    CameraDescription,
    FigureEntry,
    KeyFiguresDocument,
    better_direction,
    clean,
    keyfigures_document,
)
from labctl.evaluation.remission import misalignment_summary, remission_table
from labctl.evaluation.scenes import AlignmentRecord
from labctl.evaluation.sections import (
    AlignmentSection,
    BoehlerStarRow,
    CaptureRow,
    CheckerboardRow,
    SlantedEdgeRow,
    XYNoiseRow,
)
from labctl.evaluation.sharpness import resolution_table
from labctl.evaluation.suitability import Suitability
from labctl.evaluation.vdi2634 import acceptance_table, rim_rule_deviation, verdicts
from labctl.jsondoc import write_json
from labctl.provenance import labctl_version, now_iso
from labctl.report.curves import write_curves
from labctl.report.plots.acceptance import plot_acceptance
from labctl.report.plots.boehler import plot_boehler
from labctl.report.plots.capture import plot_capture
from labctl.report.plots.depth_quality import plot_vendor_figures
from labctl.report.plots.distortion import plot_distortion
from labctl.report.plots.figures import (
    plot_depth_curves,
    plot_face_mask,
    plot_resolution,
    plot_sharpness,
    plot_surface_maps,
    plot_xy_noise,
)
from labctl.report.plots.remission import plot_misalignment_fit, plot_remission
from labctl.report.pointcloud_io import write_pcd

#: page style shared by the report and the comparison: tables sit in a container that scrolls sideways
#: on screen, headers wrap at underscores, and in print everything wraps to the page width
CSS = """
body{font-family:system-ui,-apple-system,Segoe UI,Roboto,sans-serif;margin:2em auto;max-width:1150px;padding:0 1em;color:#222}
h1{font-size:1.6em}h2{border-bottom:1px solid #ccc;padding-bottom:.2em;margin-top:2em}
.tablewrap{max-width:100%;overflow-x:auto;margin:.4em 0}
table{border-collapse:collapse;font-size:.85em}td,th{border:1px solid #ddd;padding:.25em .5em;text-align:right}
th{background:#f4f4f4;font-weight:600;vertical-align:bottom}td.l,th.l{text-align:left}
.null{color:#999}.note{color:#a15c00}
img{max-width:100%;height:auto;border:1px solid #eee}td.src{font-size:.85em;color:#555}
.verdict-pass{color:#1a7f37;background:#dafbe1}.verdict-fail{color:#cf222e;background:#ffebe9}
.verdict-not_evaluated{color:#9a6700;background:#fff8c5}.verdict-marginal{color:#953800;background:#fff1e5}.verdict-no_numeric_requirement{color:#57606a}
.summary{border:1px solid #ccc;border-radius:6px;padding:.2em 1em 1em;background:#fafafa}
.summary h2{margin-top:.6em}
@page{size:A4;margin:14mm 12mm}
@media print{body{max-width:none;margin:0;padding:0;font-size:9pt}.tablewrap{overflow:visible}
table{font-size:7.5pt;width:100%}td,th{padding:.15em .3em;overflow-wrap:break-word}
img{break-inside:avoid}h2,h3{break-after:avoid}tr{break-inside:avoid}}
"""


#: how the report and the comparison say which way a figure improves (keyfigures.json's ``better``)
BETTER_TEXT = {"lower": "lower", "higher": "higher", "zero": "closer to 0", "none": "none"}


def better_text(name: str) -> str:
    """Which way figure ``name`` improves, in words (``zero``: a signed figure, closer to 0 is better)."""
    return BETTER_TEXT[better_direction(name)]


def wrap_table(table_html: str) -> str:
    """A table inside the sideways-scrolling container, so it never widens the page."""
    return f'<div class="tablewrap">{table_html}</div>'


def wrappable(name: str) -> str:
    """A name (column, figure, step) that may wrap after its underscores (``<wbr>``), escaped."""
    return html.escape(name).replace("_", "_<wbr>")


def _fmt(value: Any, digits: int = 3) -> str:
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return '<span class="null">n/a</span>'
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, float):
        return f"{value:.0f}" if abs(value) >= 10 ** (digits - 1) else f"{value:.{digits}g}"
    return html.escape(str(value))


def _sources(source: str) -> str:
    """Source steps, runs of one procedure shortened to 'first ... last procedure (n steps)'."""
    ids = [s for s in (source or "").split(",") if s]
    groups: list[list[str]] = []
    for step in ids:
        kind = step.split("_", 1)[-1]
        if groups and groups[-1][-1].split("_", 1)[-1] == kind:
            groups[-1].append(step)
        else:
            groups.append([step])
    parts = [", ".join(g) if len(g) < 3 else f"{g[0].split('_', 1)[0]} ... {g[-1]} ({len(g)} steps)" for g in groups]
    return html.escape(", ".join(parts))


def write_outputs(evaluation: Evaluation, outdir: Path) -> tuple[Path, Path]:
    """Write keyfigures.json, the curves as NeXus (curves.h5, where the runs have wall steps), the plots and
    report.html into ``outdir``."""
    outdir.mkdir(parents=True, exist_ok=True)
    plots = outdir / "plots"
    plots.mkdir(exist_ok=True)
    doc = keyfigures_document(evaluation.camera, evaluation.figures, judged_suitability(evaluation), evaluation.flags)
    doc.runs = evaluation.runs
    doc.conditions = evaluation.conditions
    doc.notes = evaluation.notes
    doc.depth_sweep = _clean_rows(depth_table(evaluation))
    if evaluation.sharpness is not None:
        doc.slanted_edge = _clean_rows(resolution_table(evaluation.sharpness))

    sections: list[str] = _alignment_section(evaluation)
    sections.extend(_capture_sections(evaluation, outdir, plots, doc))
    if evaluation.alignment is not None:
        doc.alignment = alignment_document(evaluation.alignment)
    if evaluation.depth:
        img = plot_depth_curves(evaluation.depth, plots / "depth_error.png")
        sections.append(_section("Depth error over distance (Thesis 2024, 4.2.1)", img, outdir,
                                 depth_quantization_html(evaluation.quantization_mm) + _depth_rows(evaluation)))
    if evaluation.vendor:
        doc.depth_quality = _clean_rows(vendor_table(evaluation.vendor))
        img = plot_vendor_figures(evaluation.vendor, plots / "depth_quality.png")
        sections.append(_section("Datasheet-comparable figures", img, outdir, _vendor_html(evaluation, doc)))
    if evaluation.acceptance is not None and evaluation.acceptance.measurements:
        sections.append(_acceptance_section(evaluation, outdir, plots, doc))
    if evaluation.surface is not None:
        img = plot_surface_maps(evaluation.surface, plots / "surface_texture.png")
        sections.append(_section("Surface texture (Thesis 2024, 4.2.2, ISO 25178-2)", img, outdir, ""))
    if evaluation.sharpness is not None:
        img = plot_sharpness(evaluation.sharpness, plots / "sharpness.png")
        sections.append(_section("Sharpness over distance (Thesis 2024, 5.1.2, ISO 12233)", img, outdir, ""))
        img = plot_resolution(evaluation.sharpness, plots / "intensity_resolution.png")
        table = _rows_table(resolution_rows(resolution_table(evaluation.sharpness)), "step")
        sections.append(_section("Resolution of the intensity image (Thesis 2024, 6.3.1)", img, outdir, table))
    sections.extend(_geometry_sections(evaluation, outdir, plots, doc))
    sections.extend(_remission_sections(evaluation, outdir, plots, doc))
    if evaluation.face is not None:
        face = evaluation.face
        pcd = outdir / f"face_mask_{face.step_id}.pcd"
        write_pcd(pcd, face.cloud, face.intensity)
        img = plot_face_mask(face.cloud, face.intensity, face.distance_mm, face.step_id, plots / "face_mask.png")
        link = f'<p>Organized point cloud for CloudCompare / Open3D: <a href="{pcd.name}">{pcd.name}</a> ' \
               f"({face.invalid_fraction:.1%} invalid points).</p>"
        sections.append(_section("Face mask (Thesis 2024, 6.7)", img, outdir, link))
        doc.face_mask = {"step": face.step_id, "pcd": pcd.name, "invalid_fraction": face.invalid_fraction}
    json_path = write_json(outdir / "keyfigures.json", doc, final_newline=True)
    write_curves(evaluation, outdir / "curves.h5")
    report = outdir / "report.html"
    report.write_text(_page(evaluation, doc, sections))
    return json_path, report


def alignment_document(a: AlignmentRecord) -> AlignmentSection:
    """The ``alignment`` section of keyfigures.json: the accepted corner fields (x, y, z in mm) and residual tilt."""
    return {"step": a.step_id, "fields_mm": {name: [clean(float(v)) for v in xyz] for name, xyz in a.fields_mm.items()},
            "tilt_x_deg": clean(a.tilt_x_deg), "tilt_y_deg": clean(a.tilt_y_deg)}


def _alignment_section(evaluation: Evaluation) -> list[str]:
    a = evaluation.alignment
    if a is None:
        return []
    fields = ", ".join(f"{name.replace('_', ' ')} {xyz[2]:.1f} mm" for name, xyz in a.fields_mm.items())
    return [f"<h2>Alignment (Thesis 2024, 4.1.2)</h2><p>Accepted in {html.escape(a.step_id)}: corner fields {fields}; "
            f"residual tilt {a.tilt_x_deg:+.3f} deg about x (up), {a.tilt_y_deg:+.3f} deg about y (right).</p>"]


def _geometry_sections(evaluation: Evaluation, outdir: Path, plots: Path, doc: KeyFiguresDocument) -> list[str]:
    """Checkerboard distortion, Boehler star and x/y noise sections (Thesis 2024, 5.1.3-5.3)."""
    geo = evaluation.geometry
    sections: list[str] = []
    if geo is None:
        return sections
    board = geo.checkerboard
    if board is not None:
        r = board.intensity
        img = plot_distortion(board.image, r, plots / "distortion.png", cloud=board.cloud_distortion,
                              title=f"Checkerboard placed at {board.placed_mm:.0f} mm, laser reference "
                                    f"{board.distance_mm:.0f} mm ({board.step_id})")
        rows: list[CheckerboardRow] = [
            {"image": "intensity", "raw_w_pct": r.raw_distortion_w_pct, "raw_h_pct": r.raw_distortion_h_pct,
             "radial_w_pct": r.radial_distortion_w_pct, "radial_h_pct": r.radial_distortion_h_pct,
             "median_w_pct": r.radial_median_w_pct, "median_h_pct": r.radial_median_h_pct,
             "fov_estimate_h_deg": r.fov_estimate_deg[0], "fov_estimate_v_deg": r.fov_estimate_deg[1], "k1": r.k1,
             "corners": r.n_corners},
        ]
        if board.cloud_distortion is not None:
            c = board.cloud_distortion
            rows.append({"image": "point cloud", "raw_w_pct": c.distortion_w_pct, "raw_h_pct": c.distortion_h_pct,
                         "radial_w_pct": c.distortion_w_pct, "radial_h_pct": c.distortion_h_pct,
                         "median_w_pct": c.median_w_pct, "median_h_pct": c.median_h_pct,
                         "fov_estimate_h_deg": math.nan, "fov_estimate_v_deg": math.nan, "k1": math.nan,
                         "corners": c.n_corners})
        doc.checkerboard = _clean_rows(rows)
        sections.append(_section("Distortion (Thesis 2024, 5.2, EBU Tech 3249 / ISO 17850)", img, outdir,
                                 _rows_table(rows, "image")))
    if geo.chosen_star is not None:
        star = geo.chosen_star
        img = plot_boehler(star.result, star.cloud, plots / "boehler.png")
        stars: list[BoehlerStarRow] = [
            {"star": f"{s.segments} segments ({s.step_id})", "placed_mm": s.placed_mm,
             "resolution_h_mm": s.result.resolution_h_mm, "resolution_v_mm": s.result.resolution_v_mm,
             "angular_h_deg": s.result.angular_h_deg, "angular_v_deg": s.result.angular_v_deg,
             "distance_mm": s.result.distance_mm} for s in geo.stars]
        doc.boehler_star = _clean_rows(stars)
        sections.append(_section("Resolution of the point cloud: Boehler star (Thesis 2024, 5.1.3)", img, outdir,
                                 _rows_table(stars, "star")))
    if geo.precision:
        noise: list[XYNoiseRow] = [
            {"step": sid, "distance_mm": d, "repeatability_center_x_mm": p.repeatability_center_x_mm,
             "repeatability_center_y_mm": p.repeatability_center_y_mm,
             "repeatability_off_axis_x_mm": p.repeatability_off_axis_x_mm,
             "repeatability_off_axis_y_mm": p.repeatability_off_axis_y_mm, "precision_q90_x_mm": p.precision_q90_x_mm,
             "precision_q90_y_mm": p.precision_q90_y_mm} for sid, d, p in geo.precision]
        doc.xy_noise = _clean_rows(noise)
        img = plot_xy_noise(geo.precision, plots / "xy_noise.png")
        sections.append(_section("x/y noise on the wall (Thesis 2024, 5.3)", img, outdir, _rows_table(noise, "step")))
    return sections


def _remission_sections(evaluation: Evaluation, outdir: Path, plots: Path, doc: KeyFiguresDocument) -> list[str]:
    """Repeatability and trueness over angle per material, and the misalignment fit (Thesis 2024, 5.4)."""
    result = evaluation.remission
    if result is None:
        return []
    rows = remission_table(result)
    doc.remission_angle = _clean_rows(rows)
    angles = sorted({r["angle_deg"] for r in rows})
    pivots = []
    for key, title in (("repeatability_mm", "repeatability (mm)"), ("trueness_geometric_mm", "trueness vs geometry (mm)")):
        table = [{"material": m, **{f"{a:g} deg": next((r[key] for r in rows if r["material"] == m and r["angle_deg"] == a
                                                         and r["on_target"]), math.nan) for a in angles}}
                 for m in sorted({r["material"] for r in rows})]
        pivots.append(f"<h3>{html.escape(title)}</h3>{_rows_table(table, 'material')}")
    img = plot_remission(result, plots / "remission_angle.png")
    sections = [_section("Remission and angle of incidence (Thesis 2024, 5.4, Fig. 6-11)", img, outdir, "".join(pivots))]
    summary = misalignment_summary(result)
    if summary is not None:
        doc.misalignment = _clean(summary)
        img = plot_misalignment_fit(result, plots / "misalignment_fit.png")
        text = (f"<p>Fitted to {html.escape(str(summary['material']))} over {summary['angles']} angles: target "
                f"offset delta = {_fmt(summary['target_offset_mm'])} &plusmn; {_fmt(summary['target_offset_se_mm'], 2)} mm, "
                f"camera axis offset e = {_fmt(summary['camera_axis_offset_mm'])} &plusmn; "
                f"{_fmt(summary['camera_axis_offset_se_mm'], 2)} mm, level b = {_fmt(summary['bias_mm'])} mm, residual "
                f"RMS {_fmt(summary['residual_rms_mm'], 2)} mm. The geometric reference R + delta / cos(theta) - "
                "e tan(theta) removes the set-up from the trueness above.</p>")
        sections.append(_section("Target and camera misalignment (Thesis 2024, 5.4.2)", img, outdir, text))
    return sections


def _capture_sections(evaluation: Evaluation, outdir: Path, plots: Path, doc: KeyFiguresDocument) -> list[str]:
    """Maps, temporal noise and plane fit of each single capture (``labctl device camera``)."""
    if not evaluation.captures:
        return []
    rows = capture_table(evaluation.captures)
    doc.capture = _clean_rows(rows)
    sections = []
    for result, row in zip(evaluation.captures, rows):
        img = plot_capture(result, plots / f"capture_{result.step_id}.png")
        plane = ("<p>The scene is not planar: " if not row["planar"] else "<p>Planar scene: ") + (
            f'{_fmt(row["plane_inlier_fraction"] * 100)} % of the points within '
            f"{_fmt(result.summary.plane.tolerance_mm)} mm of the least-squares plane.</p>"
            if result.summary.plane is not None else "no plane (fewer than 3 valid points).</p>")
        sections.append(_section(f"Single capture {result.step_id}", img, outdir,
                                 plane + _rows_table([row], "step")))
    return sections


def resolution_rows(rows: Sequence[SlantedEdgeRow]) -> list[dict[str, object]]:
    """The intensity-resolution table as the report shows it: the notes of both orientations in one column
    ("h, v: ..." when they agree, else "h: ...; v: ..."), so that its columns fit the page; keyfigures.json keeps
    ``note_h`` and ``note_v``."""
    shown = []
    for row in rows:
        h, v = row["note_h"], row["note_v"]
        note = f"h, v: {h}" if h and h == v else "; ".join(f"{o}: {n}" for o, n in (("h", h), ("v", v)) if n)
        shown.append({**{k: val for k, val in row.items() if k not in ("note_h", "note_v")}, "notes": note})
    return shown


#: a section or row of keyfigures.json (labctl/evaluation/sections.py)
Record = TypeVar("Record", bound=Mapping[str, object])


def _clean(record: Record) -> Record:
    """``record`` with every float JSON-safe (:func:`clean`: None where missing or not finite), the rest as is."""
    return cast(Record, {k: clean(v) if isinstance(v, float) else v for k, v in record.items()})


def _clean_rows(rows: Sequence[Record]) -> list[Record]:
    return [_clean(row) for row in rows]


def _rows_table(rows: Sequence[Mapping[str, object]], key: str) -> str:
    if not rows:
        return ""
    cols = [c for c in rows[0] if c != key]
    head = "".join(f"<th>{wrappable(c)}</th>" for c in cols)
    body = "".join(
        f'<tr><td class="l">{wrappable(str(r[key]))}</td>'
        + "".join(f'<td class="l">{_fmt(r[c])}</td>' if isinstance(r[c], str) else f"<td>{_fmt(r[c])}</td>" for c in cols)
        + "</tr>"
        for r in rows
    )
    return wrap_table(f'<table><tr><th class="l">{wrappable(key)}</th>{head}</tr>{body}</table>')


def _section(title: str, image: Path, outdir: Path, table: str) -> str:
    rel = image.relative_to(outdir).as_posix()
    return f'<h2>{html.escape(title)}</h2>\n<img src="{rel}" alt="{html.escape(title)}">\n{table}'


def _vendor_html(evaluation: Evaluation, doc: KeyFiguresDocument) -> str:
    """The vendor key figures next to where they are defined, then the figures at every distance."""
    rows = "".join(
        f'<tr><td class="l">{wrappable(f.name)}</td><td>{_value_html(doc.figures[f.name])}</td>'
        f'<td class="l">{f.unit}</td><td class="l">{html.escape(f.meaning)}{_null_reason(doc.figures[f.name])}</td>'
        f'<td class="l src">{html.escape(f.section)}</td></tr>'
        for f in VENDOR_FIGURES
    )
    return ("<p>The figures camera vendors quote in their datasheets, computed as their own tools define them "
            "(see docs/metrics.md for the choices where a definition is vague); subpixel RMS only for stereo "
            "cameras. Z accuracy is measured from the camera's depth origin (<code>absolute_reference_mm</code>: "
            "the laser reading minus the campaign's <code>devices.camera.depth_origin_offset_mm</code>), not "
            "against the offset-calibrated reference of the depth-error section, and is n/a without it.</p>"
            + wrap_table('<table><tr><th class="l">name</th><th>value</th><th class="l">unit</th>'
                         f'<th class="l">definition</th><th class="l">defined by</th></tr>{rows}</table>')
            + f"<h3>At every wall distance</h3>{_rows_table(vendor_table(evaluation.vendor), 'step')}")


def _value_html(entry: FigureEntry) -> str:
    """A figure's value, with ``± U`` (the expanded uncertainty, k = 2) where it has one."""
    if entry.value is None or entry.expanded_uncertainty is None:
        return _fmt(entry.value)
    return f"{_fmt(entry.value)} &plusmn; {_fmt(entry.expanded_uncertainty, 2)}"


def _null_reason(entry: FigureEntry) -> str:
    """Why a figure is n/a, where its flags say (its other flags are shown in the Key figures table)."""
    return _flags_html(entry.flags) if entry.value is None else ""


def _acceptance_section(evaluation: Evaluation, outdir: Path, plots: Path, doc: KeyFiguresDocument) -> str:
    """VDI/VDE 2634-2 quantities with their maximum permissible errors and verdicts, per position, and the share of
    each sphere's points its fit used (the rim rule's departure from the guideline)."""
    result = evaluation.acceptance
    assert result is not None
    judged = verdicts(result)
    doc.acceptance_test = {name: _clean(row) for name, row in judged.items()}
    rows = [{"quantity": name, "value_mm": row["value"],
             "expanded_uncertainty_mm": _or_nan(row["expanded_uncertainty_mm"]), "mpe_mm": _or_nan(row["mpe_mm"]),
             "verdict": row["verdict"].replace("_", " ")} for name, row in judged.items()]
    bases = "".join(f"<li><code>{name}</code>: {html.escape(row['uncertainty_basis'])}</li>"
                    for name, row in judged.items())
    table = (_rows_table(rows, "quantity") + "<p>The verdict is decided with guard bands of the expanded "
             "uncertainty U (k = 2) around the MPE: pass inside it by more than U, fail outside it by more than U, "
             f"marginal within U of it; without U on the value alone. U rests on:</p><ul>{bases}</ul>")
    doc.acceptance_positions = per_step = _clean_rows(acceptance_table(result))
    img = plot_acceptance(result, plots / "acceptance.png")
    averaged = sorted({len(m.frames) for m in result.measurements})
    deviation = rim_rule_deviation(result)
    used = [{"measurement": f"{m.step_id} frames {m.frames.start}-{m.frames.stop - 1}",
             **{f"sphere_{i + 1}_points_used_pct": 100 * share for i, share in enumerate(m.points_used)}}
            for m in result.measurements if m.points_used]
    text = (f"<p>A measurement is the per-pixel mean of {' or '.join(str(n) for n in averaged)} frames "
            "(<code>frames_per_measurement</code>); a quantity's figure is the measurement of largest magnitude, "
            "compared with the campaign's maximum permissible error (MPE). Each sphere is fitted to its points whose "
            "line of sight meets it at an incidence of at most <code>max_incidence_deg</code> and passes at least "
            "<code>rim_margin_px</code> inside its silhouette (the rim rule; 60 deg and 1 px unless the campaign "
            "says otherwise), besides the guideline's 0.3 % outlier rule.</p>"
            + (f'<p class="note">{html.escape(deviation[0].upper() + deviation[1:])}. The rim rule removes the '
               "size bias of the rim pixels, which mix the sphere with the background (docs/metrics.md).</p>"
               if deviation else "") + table
            + "<h3>Per position (largest magnitude over the measurements)</h3>"
            + _rows_table([{k: (f"{v[0]:g}, {v[1]:g}" if k == "offset_mm" else v) for k, v in row.items()
                           if k not in ("points_used", "pose_deg")} for row in per_step], "step")
            + (f"<h3>Points each sphere fit used</h3>{_rows_table(used, 'measurement')}" if used else ""))
    return _section("Acceptance test (VDI/VDE 2634 Part 2)", img, outdir, text)


def _or_nan(value: float | None) -> float:
    """A number for a report table: NaN (shown n/a) where None."""
    return math.nan if value is None else value


def depth_quantization_html(quantization_mm: dict[str, float]) -> str:
    """Under the depth table: what a quantized depth output does to its figures (empty for continuous depth)."""
    step = quantization_mm.get("z", math.nan)
    if not math.isfinite(step):
        return ""
    return (f'<p class="note">The depth is stored in steps of {_fmt(step)} mm: figures near or below a step are '
            "largely rounding. A pixel with little noise against the step and a true depth away from a rounding "
            "boundary reads the same value in every frame (precision and repeatability 0), and a single frame's "
            "error jumps by up to a step from one distance to the next as the reference moves between steps.</p>")


def _depth_rows(evaluation: Evaluation) -> str:
    """The depth table as in the plot: invalid pixels in % (keyfigures.json keeps the fraction)."""
    rows = [{("invalid_pct" if k == "invalid_fraction" else k): (100.0 * v if k == "invalid_fraction" else v)
             for k, v in row.items()} for row in depth_table(evaluation)]
    return _rows_table(rows, "step")


def verdict_cell(verdict: str, note: str = "") -> str:
    """A table cell with the verdict in words (and a one-line ``note``), coloured by its class ``verdict-<verdict>``."""
    line = f"<br>{html.escape(note)}" if note else ""
    return f'<td class="l verdict-{html.escape(verdict)}"><b>{html.escape(verdict.replace("_", " "))}</b>{line}</td>'


def _conditions_html(conditions: list[RunConditions]) -> str:
    """What the figures rest on: per run file its SHA-256, the labctl that recorded it, when, its status and
    exposure times; the devices (camera and reference instruments) with model, serial and firmware."""
    if not conditions:
        return ""
    runs = "".join(
        f'<tr><td class="l">{html.escape(c["path"])}</td><td class="l"><code>{html.escape(c["sha256"])}</code></td>'
        f'<td class="l">labctl {html.escape(c["recorded_by"])}, {html.escape(c["created"])}</td>'
        f'<td class="l">{html.escape(c["status"])}{" (simulated)" if c["simulated"] else ""}</td>'
        f'<td class="l">{", ".join(f"{e:g}" for e in c["exposures_us"]) or "not stated"}</td></tr>'
        for c in conditions)
    seen: dict[tuple[str, ...], None] = {}
    for c in conditions:
        for d in c["devices"]:
            seen[(d["role"], d["model"], d["serial"], d["firmware"], d["backend"])] = None
    devices = "".join("<tr>" + "".join(f'<td class="l">{html.escape(v)}</td>' for v in key) + "</tr>" for key in seen)
    return ("<h2>Conditions</h2>"
            + wrap_table('<table><tr><th class="l">run file</th><th class="l">SHA-256</th><th class="l">recorded by</th>'
                         f'<th class="l">status</th><th class="l">exposure (&micro;s)</th></tr>{runs}</table>')
            + wrap_table('<table><tr><th class="l">device</th><th class="l">model</th><th class="l">serial</th>'
                         f'<th class="l">firmware</th><th class="l">backend</th></tr>{devices}</table>')
            + _temperatures_html(conditions))


def _temperatures_html(conditions: list[RunConditions]) -> str:
    """The camera's temperature range per sensor and run file, or a note that the camera reports none."""
    rows = "".join(
        f'<tr><td class="l">{html.escape(c["path"])}</td><td class="l">{html.escape(sensor)}</td>'
        f"<td>{low:.1f}</td><td>{high:.1f}</td></tr>"
        for c in conditions for sensor, (low, high) in c.get("camera_temperatures_c", {}).items())
    if not rows:
        return '<p class="note">Camera temperature: not reported (this camera reports none to labctl).</p>'
    return wrap_table('<table><tr><th class="l">run file</th><th class="l">camera temperature sensor</th>'
                      f"<th>lowest (&deg;C)</th><th>highest (&deg;C)</th></tr>{rows}</table>")


def _suitability_html(suit: Suitability) -> str:
    rows = []
    for story in suit.stories.values():
        checks = "<br>".join(
            f'{html.escape(c.requirement)}: <b>{c.status.replace("_", " ")}</b> ('
            + ", ".join(f"{html.escape(k)} = {_fmt(v)}" + (f" &plusmn; {_fmt(c.uncertainties[k], 2)}"
                        if c.uncertainties.get(k) is not None else "") for k, v in c.values.items())
            + f')<br><small>{html.escape(c.source)}</small>'
            for c in story.checks
        ) or "; ".join(f"{html.escape(k)} = {_fmt(v)}" for k, v in story.figures.items())
        rows.append(f'<tr><td class="l">{html.escape(story.description)}</td>'
                    f'{verdict_cell(story.verdict, story.summary)}'
                    f'<td class="l">{checks}</td></tr>')
    return (f'<p>{html.escape(suit.standard)}</p>'
            + wrap_table('<table><tr><th class="l">user story</th><th class="l">verdict</th>'
                         f'<th class="l">checks (values)</th></tr>{"".join(rows)}</table>'))


#: the figures the summary shows: is the face's shape right and steady (depth trueness, precision), are its
#: features resolved (point-cloud resolution), is it undistorted and large enough for the ISO/IEC 39794-5
#: limits (cloud distortion, inter-eye distance), and does skin seen at an angle stay steady
SUMMARY_FIGURES = ("z_trueness_q90_mm", "z_precision_q90_mm", "cloud_resolution_h_deg",
                   "radial_distortion_cloud_w_pct", "ied_pixels_at_hyperfocal", "repeatability_skin_40deg_mm")

#: the works the report's headings cite, in full (all of them, with the sections used: docs/references.md)
REFERENCES = (
    ("Thesis 2024", "Characterization of 3D cameras for facial biometric applications, master's thesis, 2024 "
                    "(the source of the methods; section numbers as cited)"),
    ("ISO 5725-1/-2", "Accuracy (trueness and precision) of measurement methods and results, ISO 5725-1:2023, "
                      "ISO 5725-2:2019"),
    ("ISO 12233:2023", "Digital cameras - Resolution and spatial frequency responses"),
    ("ISO 25178-2", "GPS - Surface texture: Areal - Part 2: Terms, definitions and surface texture parameters, 2012"),
    ("ISO 17850:2015", "Photography - Digital cameras - Geometric distortion (GD) measurements"),
    ("EBU Tech 3249", "Measurement and analysis of the performance of film and television camera lenses, EBU, 1995"),
    ("ISO/IEC 39794-5:2019", "Extensible biometric data interchange formats - Part 5: Face image data, Annex D"),
    ("VDI/VDE 2634 Part 2", "Optical 3-D measuring systems - Optical systems based on area scanning, 2012"),
)


def references_html() -> str:
    """The References section closing the report and the comparison."""
    items = "".join(f"<li><b>{html.escape(key)}</b>: {html.escape(text)}</li>" for key, text in REFERENCES)
    return ("<h2>References</h2><ul>" + items + "</ul><p>Full citations and the sections used: "
            "docs/references.md in the labctl repository.</p>")


def _summary_html(cam: CameraDescription, doc: KeyFiguresDocument) -> str:
    """Camera, the verdict per user story and the six figures that matter most, ahead of everything else."""
    stories = doc.suitability.stories
    judged = {k: s for k, s in stories.items() if s.verdict != "no_numeric_requirement"}
    passed = sum(s.verdict == "pass" for s in judged.values())
    badges = "".join(f'<li><span class="verdict-{html.escape(s.verdict)}"><b>'
                     f'{html.escape(s.verdict.replace("_", " "))}</b></span> {html.escape(s.description)}</li>'
                     for s in judged.values())
    rows = "".join(
        f'<tr><td class="l">{wrappable(name)}</td><td>{_value_html(doc.figures[name])}</td>'
        f'<td class="l">{doc.figures[name].unit}</td><td class="l">{better_text(name)}</td>'
        f'<td class="l">{html.escape(FIGURE_BY_NAME[name].meaning)}'
        + "".join(f'<br><span class="note">&#9888; {html.escape(f["check"].replace("_", " "))} (see Key figures)</span>'
                  for f in doc.figures[name].flags) + "</td></tr>"
        for name in SUMMARY_FIGURES
    )
    return (f'<div class="summary"><h2>Summary</h2><p><b>{html.escape(cam.model)}</b>: suitable for {passed} of '
            f"{len(judged)} user stories with numeric requirements.</p><ul>{badges}</ul>"
            + wrap_table('<table><tr><th class="l">figure</th><th>value</th><th class="l">unit</th>'
                         f'<th class="l">better</th><th class="l">meaning</th></tr>{rows}</table>') + "</div>")


def _capture_summary_html(cam: CameraDescription, rows: Sequence[CaptureRow]) -> str:
    """The summary of a run of single captures (``labctl device camera``): what each stack shows, since without a
    reference distance no key figure and no suitability verdict can be computed."""
    def line(r: CaptureRow) -> str:
        plane = (f"planar, plane {_fmt(r['plane_distance_on_axis_mm'])} mm away on the axis, residual RMS "
                 f"{_fmt(r['plane_rms_mm'])} mm" if r["planar"] else "not planar")
        return (f"<li><b>{html.escape(r['step'])}</b>: {r['frames']} frame(s), {_fmt(100 * r['valid_fraction'])} % valid "
                f"pixels, depth median {_fmt(r['depth_median_mm'])} mm (5-95 %: {_fmt(r['depth_q05_mm'])}-"
                f"{_fmt(r['depth_q95_mm'])} mm), temporal noise median {_fmt(r['temporal_noise_median_mm'])} mm, "
                f"Q90 {_fmt(r['temporal_noise_q90_mm'])} mm; {plane}</li>")
    return (f'<div class="summary"><h2>Summary</h2><p><b>{html.escape(cam.model)}</b>: single capture '
            "(<code>labctl device camera</code>) without a reference distance, so no key figure and no suitability "
            "verdict: those need a campaign's procedures. What was captured (maps below):</p>"
            f"<ul>{''.join(line(r) for r in rows)}</ul></div>")


def _capture_only(doc: KeyFiguresDocument) -> bool:
    """The runs hold only capture steps: no figure came from a step (the pixel aspect comes from the datasheet)."""
    return doc.capture is not None and not any(f.source for f in doc.figures.values())


def _flags_html(flags: list[dict[str, str]]) -> str:
    """A figure's plausibility flags, one warning line each."""
    return "".join(f'<br><span class="note">&#9888; {html.escape(f["check"].replace("_", " "))}: '
                   f'{html.escape(f["message"])}</span>' for f in flags)


def _page(evaluation: Evaluation, doc: KeyFiguresDocument, sections: list[str]) -> str:
    cam = evaluation.camera
    fig_rows = "".join(
        f'<tr><td class="l">{wrappable(name)}</td><td>{_value_html(f)}</td><td class="l">{f.unit}</td>'
        f'<td class="l">{html.escape(FIGURE_BY_NAME[name].meaning)}{_flags_html(f.flags)}</td>'
        f'<td class="l">{better_text(name)}</td>'
        f'<td class="l src">{_sources(f.source)}</td></tr>'
        for name, f in doc.figures.items()
    )
    notes = "".join(f'<li class="note">{html.escape(n)}</li>' for n in evaluation.notes)
    runs = "".join(f"<li>{html.escape(r)}</li>" for r in evaluation.runs)
    simulated = " (simulated)" if cam.simulated and "simulated" not in cam.model else ""
    suit_html = _suitability_html(doc.suitability)
    capture_only = _capture_only(doc)  # its maps come first: the key figures and verdicts are all n/a
    return f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>labctl report: {html.escape(cam.model)}</title>
<style>{CSS}</style></head><body>
<h1>Characterization of {html.escape(cam.model)}{simulated}</h1>
<p>Serial {html.escape(str(cam.serial))}, {cam.width}&times;{cam.height} px,
FOV {cam.fov_deg[0]:g}&times;{cam.fov_deg[1]:g}&deg;. Report by labctl {labctl_version()} on {now_iso()}.</p>
{_capture_summary_html(cam, doc.capture or []) if capture_only else _summary_html(cam, doc)}
{_conditions_html(evaluation.conditions) or f'<ul>{runs}</ul>'}
{f'<ul>{notes}</ul>' if notes else ''}
{''.join(sections) if capture_only else ''}
<h2>Key figures</h2>
<p class="note">value &plusmn; U: the expanded uncertainty (k = 2, about 95 %) where it is estimated; its budget
is in keyfigures.json (docs/keyfigures.md, Uncertainty).</p>
{wrap_table(f'''<table><tr><th class="l">name</th><th>value</th><th class="l">unit</th><th class="l">meaning</th>
<th class="l">better</th><th class="l">source steps</th></tr>{fig_rows}</table>''')}
<h2>Suitability (Thesis 2024, Ch. 3, 6.6)</h2>{suit_html}
{'' if capture_only else ''.join(sections)}
{references_html()}
</body></html>
"""
