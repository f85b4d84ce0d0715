"""Report and comparison layout without a browser: tables never widen the page, labels and legends read right.

The screenshots in docs/images (docs/screenshots.sh, headless Chromium at 1400 px) show the same pages; these
tests pin what makes them readable: every table sits in the sideways-scrolling container (and wraps in print),
column names may wrap at their underscores, the summary comes first, story names are words and verdicts carry
a class that colours them, the face-mask title names the depth the picture shows.
"""

from __future__ import annotations

import html
import json
import math
import textwrap
from html.parser import HTMLParser
from pathlib import Path

import numpy as np
import pytest
from matplotlib.backends.backend_agg import FigureCanvasAgg
from pypdf import PdfReader

from labctl.cli import main
from labctl.evaluation.keyfigures import FIGURE_BY_NAME, better_direction
from labctl.evaluation.scenes import face_mask
from labctl.report.compare import IED_TITLE, _chart_floor, ied_figure, story_name
from labctl.report.html import SUMMARY_FIGURES, depth_quantization_html, resolution_rows
from labctl.report.pdf import find_browser
from labctl.report.plots.figures import face_mask_title, percent_axis_limits, sharpness_figure
from labctl.report.plots.remission import misalignment_label
from labctl.run.store import RunReader
from tests.conftest import campaign_text

RUN = """
[[procedure]]
kind = "alignment"
distance_mm = 1500
frames = 2
field_px = 4

[[procedure]]
kind = "offset_calibration"
frames = 3

[[procedure]]
kind = "depth_sweep"
start_mm = 1500
stop_mm = 2000
step_mm = 500
frames = 3

[[procedure]]
kind = "face_mask"
distance_mm = 1000
frames = 3
"""


def invoke(*args: object) -> int:
    with pytest.raises(SystemExit) as info:
        main([str(a) for a in args])
    return int(info.value.code or 0)


class Tables(HTMLParser):
    """Each <table>'s enclosing elements, the visible text, and the classes of the cells."""

    def __init__(self) -> None:
        super().__init__()
        self.stack: list[tuple[str, str]] = []
        self.table_parents: list[list[tuple[str, str]]] = []
        self.text: list[str] = []
        self.cell_classes: list[tuple[str, str]] = []  # (class, text of the cell)
        self._cell: str | None = None

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        cls = dict(attrs).get("class") or ""
        if tag == "table":
            self.table_parents.append(list(self.stack))
        if tag in ("td", "th"):
            self._cell = cls
            self.cell_classes.append((cls, ""))
        if tag not in ("wbr", "img", "br", "meta"):
            self.stack.append((tag, cls))

    def handle_endtag(self, tag: str) -> None:
        while self.stack:
            if self.stack.pop()[0] == tag:
                break
        if tag in ("td", "th"):
            self._cell = None

    def handle_data(self, data: str) -> None:
        if not any(t in ("style", "title") for t, _ in self.stack):
            self.text.append(data)
        if self._cell is not None and self.cell_classes:
            cls, text = self.cell_classes[-1]
            self.cell_classes[-1] = (cls, text + data)


def parse(page: str) -> Tables:
    parser = Tables()
    parser.feed(page)
    return parser


@pytest.fixture(scope="module")
def report(tmp_path_factory: pytest.TempPathFactory) -> tuple[str, dict, Path]:
    """report.html and keyfigures.json of a small simulated run: wall sweep and face mask."""
    d = tmp_path_factory.mktemp("layout")
    (d / "campaign.toml").write_text(campaign_text(procedures=textwrap.dedent(RUN)))
    (d / "model.toml").write_text('camera = "blaze101"\n[camera_overrides]\nwidth = 96\nheight = 72\n')
    assert invoke("run", d / "campaign.toml", "--sim", "--model", d / "model.toml", "-o", d / "r.h5", "--quiet") == 0
    assert invoke("evaluate", d / "r.h5", "-o", d / "out", "--quiet") == 0
    return (d / "out" / "report.html").read_text(), json.loads((d / "out" / "keyfigures.json").read_text()), d / "r.h5"


def test_every_report_table_scrolls_inside_the_page_and_wraps_in_print(report):
    page, *_ = report
    parsed = parse(page)
    assert len(parsed.table_parents) >= 5
    for parents in parsed.table_parents:
        assert ("div", "tablewrap") in parents
    style = page[page.index("<style>"):page.index("</style>")]
    assert ".tablewrap{max-width:100%;overflow-x:auto" in style
    assert "@media print" in style and ".tablewrap{overflow:visible}" in style


def test_long_column_names_may_wrap_and_invalid_pixels_are_percent_as_in_the_plot(report):
    page, doc, _ = report
    depth = page[page.index("Depth error over distance"):]
    assert "precision_<wbr>q90_<wbr>mm" in depth and "invalid_<wbr>pct" in depth
    assert "invalid_fraction" not in depth.split("</table>")[0]
    # keyfigures.json keeps the fraction, the report shows 100 x it
    fraction = doc["depth_sweep"][0]["invalid_fraction"]
    assert 0 <= fraction <= 1


def test_summary_comes_first_with_camera_verdict_and_six_figures(report):
    page, doc, _ = report
    start = page.index('<div class="summary">')
    summary = page[start:page.index("</table>", start)].replace("<wbr>", "")  # names may wrap at underscores
    assert page.index('<div class="summary">') < page.index("<h2>Key figures</h2>")
    assert doc["camera"]["model"] in summary
    assert len(SUMMARY_FIGURES) == 6
    for name in SUMMARY_FIGURES:
        assert name in summary
    judged = [s for s in doc["suitability"]["stories"].values() if s["verdict"] != "no_numeric_requirement"]
    assert f"suitable for {sum(s['verdict'] == 'pass' for s in judged)} of {len(judged)} user stories" in summary
    for story in judged:
        assert f'class="verdict-{story["verdict"]}"' in summary and html.escape(story["description"]) in summary


def test_report_cites_what_a_reader_can_follow(report):
    page, *_ = report
    text = "".join(parse(page).text)
    assert "References" in text and "Thesis 2024" in text and "docs/references.md" in text
    assert "Depth error over distance (Thesis 2024, 4.2.1)" in text


def test_face_mask_title_names_the_depth_shown_not_the_wall():
    """The demo's blaze-101: mask 572-607 mm from the camera, wall at 900 mm; the title once said "at 900 mm"."""
    z = np.full((60, 80), 900.0)
    z[20:40, 30:50] = np.linspace(572.0, 607.0, 400).reshape(20, 20)
    title = face_mask_title(z, 900.0, "00090_face_mask")
    assert title.startswith("Face mask 572-607 mm from the camera")
    assert "wall at 900 mm" in title and "00090_face_mask" in title


def test_face_mask_title_of_a_simulated_mask(report):
    """Simulated mask (sim/face_mask.py): base plane 1000 mm from the camera (``distance_mm``), the wall 300 mm
    (the default gap) behind it, relief up to 33.6 mm: its points lie between about 966 and 1000 mm, and the
    title states that range, not the wall's 1300 mm."""
    _, doc, run = report
    with RunReader(run) as reader:
        face = face_mask(reader.step(doc["face_mask"]["step"]))
    title = face_mask_title(face.cloud[..., 2], face.distance_mm, face.step_id)
    near, far = (float(v) for v in title.split()[2].split("-"))
    assert near == pytest.approx(1000 - 33.6, abs=12) and far == pytest.approx(1000, abs=12)
    assert "wall at 1300 mm" in title


def test_misalignment_legend_reads_as_an_equation():
    assert misalignment_label(10.2, 19.8, 14.9).splitlines()[0] == "fit: 10.20 + 19.80/cos θ - 14.90 tan θ mm"
    assert misalignment_label(-3.0, -20.0, -15.0).splitlines()[0] == "fit: -3.00 - 20.00/cos θ + 15.00 tan θ mm"
    assert misalignment_label(0.028, -0.02, 0.017).splitlines()[0] == "fit: 0.03 - 0.02/cos θ - 0.02 tan θ mm"
    label = misalignment_label(0.0, -0.0, 0.004)  # once printed as "b +0.0 + -0.0/cos - (0.0) tan"
    assert "+ -" not in label and "-0.0" not in label and "(0.0" not in label


def test_invalid_pixel_axis_starts_at_zero_percent():
    assert percent_axis_limits(np.zeros(5)) == (0.0, 1.0)  # not -0.04 ... +0.04 %
    assert percent_axis_limits(np.array([0.0, 5.0, np.nan])) == pytest.approx((0.0, 5.5))
    assert percent_axis_limits(np.array([95.0])) == (0.0, 100.0)


def keyfigures_dir(tmp_path: Path, name: str, model: str, verdicts: dict[str, str], described: bool,
                   zero: float | None) -> Path:
    d = tmp_path / name
    d.mkdir()
    stories = {k: {"verdict": v, **({"description": f"{k} in words"} if described else {})} for k, v in verdicts.items()}
    doc = {"camera": {"model": model},
           "figures": {"ied_pixels_at_hyperfocal": {"value": 85.0, "unit": "px"},
                       "x_repeatability_center_mm": {"value": zero, "unit": "mm"},
                       "z_precision_q90_mm": {"value": 1.3, "unit": "mm"}},
           "suitability": {"standard": "s", "stories": stories}}
    (d / "keyfigures.json").write_text(json.dumps(doc))
    return d


def test_comparison_names_stories_in_words_and_colours_verdicts(tmp_path):
    a = keyfigures_dir(tmp_path, "a", "cam A", {"3d_face_recognition_1_to_1": "fail", "pad_light": "pass"}, False, 0.0)
    b = keyfigures_dir(tmp_path, "b", "cam B", {"3d_face_recognition_1_to_1": "pass"}, False, None)
    assert invoke("compare", a, b, "-o", tmp_path / "cmp") == 0
    page = (tmp_path / "cmp" / "compare.html").read_text()
    parsed = parse(page)
    text = "".join(parsed.text)
    assert "3d_face_recognition_1_to_1" not in text and "3D face recognition 1:1" in text
    assert ("l verdict-fail", "fail") in parsed.cell_classes and ("l verdict-pass", "pass") in parsed.cell_classes
    # cam B has no pad_light story: not evaluated, said so
    assert ("l verdict-not_evaluated", "not evaluated") in parsed.cell_classes
    for parents in parsed.table_parents:
        assert ("div", "tablewrap") in parents
    result = json.loads((tmp_path / "cmp" / "compare.json").read_text())
    assert result["stories"]["3d_face_recognition_1_to_1"] == "3D face recognition 1:1"


def test_comparison_uses_the_evaluations_story_descriptions(tmp_path):
    a = keyfigures_dir(tmp_path, "a", "cam A", {"pad_makeup_nir": "fail"}, True, 0.5)
    assert invoke("compare", a, "-o", tmp_path / "cmp") == 0
    assert "pad_makeup_nir in words" in (tmp_path / "cmp" / "compare.html").read_text()


def test_story_names():
    assert story_name("3d_face_recognition_1_to_n") == "3D face recognition 1:N"
    assert story_name("pad_makeup_nir") == "PAD makeup NIR"


def test_chart_foot_lies_below_every_bar_so_zero_and_missing_are_labelled_there():
    table = {"a_mm": {"A": 0.0, "B": 0.03}, "b_deg": {"A": None, "B": 2.0}}
    assert _chart_floor(table, ["a_mm", "b_deg"], ["A", "B"]) == pytest.approx(0.001)
    assert _chart_floor({"a_mm": {"A": 0.0}}, ["a_mm"], ["A"]) == pytest.approx(0.001)


def documented_keys() -> tuple[set[str], str]:
    """Top-level keys of the keyfigures.json example in docs/keyfigures.md, and the example's text."""
    text = (Path(__file__).parents[3] / "docs" / "keyfigures.md").read_text()
    example = text[text.index("```json"):text.index("```", text.index("```json") + 7)]
    return {line.split('"')[1] for line in example.splitlines() if line.startswith('  "')}, example


def test_keyfigures_json_has_the_shape_docs_keyfigures_md_shows(report):
    _, doc, _ = report
    keys, example = documented_keys()
    assert set(doc) <= keys  # nothing undocumented
    assert {"camera", "figures", "suitability", "runs", "notes", "depth_sweep", "alignment", "face_mask"} <= set(doc)
    assert set(doc["suitability"]) == {"standard", "stories"}
    assert '"suitability": {"standard": ' in example and '"evaluated"' not in example
    story = next(iter(doc["suitability"]["stories"].values()))
    assert {"description", "verdict", "checks", "figures"} <= set(story)
    for name, figure in doc["figures"].items():
        assert set(figure) >= {"value", "unit", "source", "meaning"}, name


def test_alignment_result_is_in_keyfigures_json(report):
    """The simulated camera is mounted square to the wall at 1500 mm: every corner field reads about 1500 mm
    (plus the camera-laser offset, a few mm at most) and the residual tilt is about 0."""
    _, doc, _ = report
    a = doc["alignment"]
    assert a["step"] == "00000_alignment"
    assert set(a["fields_mm"]) == {"top_left", "top_right", "bottom_left", "bottom_right"}
    for x, y, z in a["fields_mm"].values():
        assert z == pytest.approx(1500, abs=15) and abs(x) > 100 and abs(y) > 100
    assert abs(a["tilt_x_deg"]) < 0.2 and abs(a["tilt_y_deg"]) < 0.2


def test_better_direction_is_the_one_docs_keyfigures_md_gives():
    """Each figure's "better" column in docs/keyfigures.md is what the report and comparison show; more pixels
    across the eyes is better whichever pixel size counts them (the angular count once read "lower")."""
    text = (Path(__file__).parents[3] / "docs" / "keyfigures.md").read_text()
    documented = {}
    for line in text.splitlines():
        cells = [c.strip() for c in line.split("|")[1:-1]]
        if len(cells) >= 4 and cells[0].startswith("`") and cells[0].strip("`") in FIGURE_BY_NAME:
            direction = next((c for c in cells if c in ("lower", "higher", "zero", "none")), None)
            if direction is not None:  # the tables of definitions only have no "better" column
                documented[cells[0].strip("`")] = direction
    assert {"ied_pixels_at_hyperfocal", "ied_pixels_at_hyperfocal_angular", "best_focus_distance_mm",
            "fill_rate_1000mm_pct"} <= set(documented)
    for name, direction in documented.items():
        assert better_direction(name) == direction, name


def test_resolution_table_shows_both_orientations_notes_in_one_column():
    """16 columns with two note columns overflowed the page (the simulated flexx2: 1189 px in 1150); the notes of
    both orientations share one column."""
    base = {"distance_mm": 300.0, "step": "00012_slanted_edge", "sfr10_h": 0.62, "sfr10_v": math.nan}
    rows = resolution_rows([
        {**base, "note_h": "SFR10 above Nyquist", "note_v": "no SFR10"},
        {**base, "note_h": "SFR10 above Nyquist", "note_v": "SFR10 above Nyquist"},
        {**base, "note_h": "", "note_v": "edge not found"},
        {**base, "note_h": "", "note_v": ""},
    ])
    assert [r["notes"] for r in rows] == ["h: SFR10 above Nyquist; v: no SFR10", "h, v: SFR10 above Nyquist",
                                          "v: edge not found", ""]
    assert all("note_h" not in r and "note_v" not in r and r["sfr10_h"] == 0.62 for r in rows)


def test_comparison_gives_each_verdicts_reason_each_figures_flags_and_names_the_ied_model(tmp_path):
    d = tmp_path / "a"
    d.mkdir()
    story = {"verdict": "fail", "description": "3D face recognition, 1:1 verification",
             "summary": "fails inter-eye distance >= 90 px: 75.5"}
    flag = {"check": "near_axis", "message": "taken where x = 0.5 mm"}
    doc = {"camera": {"model": "cam A"},
           "figures": {"ied_pixels_at_hyperfocal": {"value": 75.5, "unit": "px", "flags": []},
                       "x_repeatability_center_mm": {"value": 0.003, "unit": "mm", "flags": [flag]}},
           "suitability": {"standard": "s", "stories": {"3d_face_recognition_1_to_1": story}}}
    (d / "keyfigures.json").write_text(json.dumps(doc))
    assert invoke("compare", d, "-o", tmp_path / "cmp") == 0
    page = (tmp_path / "cmp" / "compare.html").read_text()
    assert "<b>fail</b><br>fails inter-eye distance &gt;= 90 px: 75.5" in page
    row = page[page.index("x_<wbr>repeatability_<wbr>center_<wbr>mm"):]
    assert row[:row.index("</tr>")].count("near axis") == 1
    assert "pinhole" in IED_TITLE and "6-2" not in IED_TITLE
    ied_text = page[page.index("Inter-eye distance coverage"):page.index("<h2>Suitability")]
    assert "pinhole" in ied_text and "ied_pixels_at_hyperfocal_angular" in ied_text
    result = json.loads((tmp_path / "cmp" / "compare.json").read_text())
    assert result["flags"] == {"x_repeatability_center_mm": {"cam A": ["near_axis"]}}
    assert result["reasons"]["cam A"]["3d_face_recognition_1_to_1"] == story["summary"]


def test_ied_chart_title_legend_and_labels_lie_inside_the_figure():
    """The title once ran past the figure's right edge (cut at "centre" in the 700 px PNG), and a camera without
    a value (n/a) pushed the last camera's name off the axis."""
    labels = ["Basler blaze-101*", "Schmersal AM-T100*", "pmd flexx2 VGA*", "Intel RealSense D455*"]
    fig = ied_figure(dict(zip(labels, [75.5, 50.4, 65.8, None])), labels)
    canvas = FigureCanvasAgg(fig)  # the figures are plain Figures; Agg is what writes their PNG
    canvas.draw()
    renderer = canvas.get_renderer()
    ax = fig.axes[0]
    texts = [ax.title, ax.yaxis.label, *ax.get_xticklabels(), ax.get_legend()]
    for artist in texts:
        box = artist.get_window_extent(renderer)
        assert box.x0 >= 0 and box.y0 >= 0 and box.x1 <= fig.bbox.width and box.y1 <= fig.bbox.height, artist
    assert "n/a" in [t.get_text() for t in ax.texts]


def test_sharpness_legend_lies_under_the_plots_and_names_the_focus_lines():
    """The simulated flexx2's legend once covered its vertical SFR10 at 1000 mm; the hyperfocal and best-focus
    lines had no legend entry, the SFR10 plot no Nyquist line to judge its values against."""
    from tests.labctl.evaluation.test_plausibility import sharpness

    result = sharpness(0.62, 0.79)
    result.hyperfocal_mm = 300.0
    fig = sharpness_figure(result)
    canvas = FigureCanvasAgg(fig)  # the figures are plain Figures; Agg is what writes their PNG
    canvas.draw()
    renderer = canvas.get_renderer()
    [legend] = fig.legends
    box = legend.get_window_extent(renderer)
    assert box.x0 >= 0 and box.y0 >= 0 and box.x1 <= fig.bbox.width
    for ax in fig.axes:
        assert box.y1 < ax.xaxis.label.get_window_extent(renderer).y0  # under every axis and its label
    labels = [t.get_text() for t in legend.get_texts()]
    assert labels == ["horizontal", "vertical", "Nyquist 0.5 cy/px", "hyperfocal 300 mm", "best focus 400 mm"]


def test_depth_section_says_when_the_depth_is_quantized():
    """The AM-T100's integer millimetres: precision 0 at 506 mm and single-frame errors of 0.056 then 0.994 mm
    at 1506 and 2006 mm; the depth section says why."""
    text = depth_quantization_html({"x": 1.0, "y": 1.0, "z": 1.0})
    assert "steps of 1 mm" in text and "precision and repeatability 0" in text
    assert depth_quantization_html({"x": math.nan, "y": math.nan, "z": math.nan}) == ""
    assert depth_quantization_html({}) == ""


def test_key_figures_with_an_uncertainty_show_value_plus_minus_U(report):
    """value +- U (k = 2) where keyfigures.json has an expanded uncertainty, the value alone where it has none."""
    page, doc, _ = report
    assert doc["figures"]["z_precision_q90_mm"]["expanded_uncertainty"] == pytest.approx(
        2 * doc["figures"]["z_precision_q90_mm"]["uncertainty"])
    table = page[page.index("<h2>Key figures</h2>"):].split("</table>")[0]
    rows = {row.split("</td>")[0]: row for row in table.split('<tr><td class="l">')[1:]}
    for name, figure in doc["figures"].items():
        cell = rows[name.replace("_", "_<wbr>")].split("</td>")[1]
        assert ("&plusmn;" in cell) == (figure["expanded_uncertainty"] is not None), name
    assert sum(f["expanded_uncertainty"] is not None for f in doc["figures"].values()) >= 4


def test_the_report_prints_to_an_a4_pdf_with_its_text(report):
    """report.pdf beside report.html (headless Chromium): A4 pages (210 x 297 mm = 595 x 842 pt), more than one,
    whose text extracts (pypdf) and holds the camera, the key figures' names and the conditions."""
    if find_browser() is None:
        pytest.skip("no Chromium on PATH: make's set-up installs it as root (apt-get install chromium)")
    _, doc, run = report
    pdf = PdfReader(run.parent / "out" / "report.pdf")
    assert len(pdf.pages) > 1
    box = pdf.pages[0].mediabox
    assert float(box.width) == pytest.approx(595.3, abs=1.0) and float(box.height) == pytest.approx(841.9, abs=1.0)
    text = " ".join(page.extract_text() for page in pdf.pages)
    flat = text.replace("\n", "").replace(" ", "")
    assert doc["camera"]["model"].replace(" ", "") in flat and "Conditions" in text
    for name in ("z_trueness_q90_mm", "z_precision_q90_mm", "ied_pixels_at_hyperfocal"):
        assert name in flat, name


def test_without_chromium_the_evaluation_says_why_there_is_no_pdf(report, tmp_path, monkeypatch, capsys):
    *_, run = report
    monkeypatch.setenv("PATH", str(tmp_path))  # no browser on it
    assert invoke("evaluate", run, "-o", tmp_path / "out", "--quiet") == 0
    err = capsys.readouterr().err
    assert "report.pdf not written: no Chromium on PATH (Debian: apt-get install chromium)" in err
    assert (tmp_path / "out" / "report.html").is_file() and not (tmp_path / "out" / "report.pdf").exists()
