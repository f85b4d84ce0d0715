"""Plausibility flags on known inputs: Nyquist, quantization step, coordinate on the principal axis."""

import math

import numpy as np

from labctl.evaluation.keyfigures import CameraDescription, FigureValue, keyfigures_document
from labctl.evaluation.plausibility import PlausibilityInputs, plausibility_flags
from labctl.evaluation.sharpness import EdgeMeasurement, SharpnessPosition, SharpnessResult
from labctl.evaluation.suitability import Suitability
from labctl.jsondoc import to_json
from metrics.plausibility import quantization_step
from metrics.xy_error import XYPrecision


def edge(sfr10: float) -> EdgeMeasurement:
    return EdgeMeasurement(sfr10, sfr10 / 2, 0.3, 5.0, (0, 0, 10, 10), True, (), np.zeros(1), np.zeros(1))


def sharpness(sfr10_h: float, sfr10_v: float, best_mm: float = 400.0) -> SharpnessResult:
    positions = [SharpnessPosition(d, f"{i:05d}_slanted_edge", "w", 100.0, edge(0.3), edge(0.3))
                 for i, d in enumerate((200.0, 300.0))]
    positions.append(SharpnessPosition(best_mm, "00009_slanted_edge", "w", 100.0, edge(sfr10_h), edge(sfr10_v)))
    return SharpnessResult(positions, (0.1, 0.1), best_focus_mm=best_mm)


def noise(centre_xy, off_axis_xy) -> XYPrecision:
    return XYPrecision(0.01, 0.01, 0.4, 0.4, centre_xy, off_axis_xy, 0.3, 0.3, 0.5, 0.5, 0.0)


def checks(flags, name):
    return [f["check"] for f in flags.get(name, [])]


def test_quantization_step_of_integer_millimetres_and_of_continuous_data():
    rng = np.random.default_rng(1)
    continuous = (2000 + rng.standard_normal((4, 60, 80))).astype(np.float32)
    assert math.isnan(quantization_step(continuous))  # float32 rounding is not an output resolution
    assert quantization_step(np.round(continuous)) == 1.0
    assert quantization_step(np.round(continuous * 4) / 4) == 0.25
    with_invalid = np.round(continuous)
    with_invalid[0, :5] = np.nan
    assert quantization_step(with_invalid) == 1.0
    assert math.isnan(quantization_step(np.full(10, 7.0)))  # one value: no step to tell


def test_sfr10_above_nyquist_flags_only_that_orientation():
    flags = plausibility_flags({}, PlausibilityInputs(sharpness(sfr10_h=0.42, sfr10_v=0.71)))
    assert checks(flags, "intensity_resolution_v_deg") == ["above_nyquist"]
    assert "0.71" in flags["intensity_resolution_v_deg"][0]["message"]
    assert "intensity_resolution_h_deg" not in flags
    assert plausibility_flags({}, PlausibilityInputs(sharpness(0.5, 0.5))) == {}  # at Nyquist is still possible


def test_figures_below_the_quantization_step_are_flagged_per_channel():
    values = {"z_precision_q90_mm": 0.0, "z_trueness_q90_mm": 0.6, "z_accuracy_q90_mm": 1.4,
              "x_precision_q90_mm": 0.3, "surface_roughness_sq_mm": 0.2, "best_focus_distance_mm": 0.5,
              "z_accuracy_2000mm_pct": 0.01, "repeatability_skin_40deg_mm": None}
    inputs = PlausibilityInputs(quantization_mm={"z": 1.0, "x": math.nan, "y": math.nan})
    flags = plausibility_flags(values, inputs)
    assert {n for n in flags} == {"z_precision_q90_mm", "z_trueness_q90_mm", "surface_roughness_sq_mm"}
    assert all(checks(flags, n) == ["quantization_limited"] for n in flags)
    # x is quantized too on a camera with integer-mm coordinates
    inputs.quantization_mm["x"] = 1.0
    assert checks(plausibility_flags(values, inputs), "x_precision_q90_mm") == ["quantization_limited"]


def test_repeatability_on_the_principal_axis_is_flagged():
    xy = [("00003_depth_sweep", 1000.0, noise((0.002, -0.004), (250.0, 190.0))),
          ("00004_depth_sweep", 2000.0, noise((0.001, 30.0), (500.0, 5.0)))]
    flags = plausibility_flags({}, PlausibilityInputs(xy_noise=xy))
    assert checks(flags, "x_repeatability_center_mm") == ["near_axis"]
    assert checks(flags, "y_repeatability_center_mm") == ["near_axis"]  # -0.004 mm at 1000 mm
    assert "2 step(s)" in flags["x_repeatability_center_mm"][0]["message"]
    assert checks(flags, "y_repeatability_off_axis_mm") == ["near_axis"]  # 5 mm at 2000 mm: 0.25 %
    assert "x_repeatability_off_axis_mm" not in flags


def test_keyfigures_json_carries_the_flags():
    doc = to_json(keyfigures_document(CameraDescription(), {"z_precision_q90_mm": FigureValue(0.0, ["s"])}, Suitability(),
                                      {"z_precision_q90_mm": [{"check": "quantization_limited", "message": "m"}]}))
    assert doc["figures"]["z_precision_q90_mm"]["flags"] == [{"check": "quantization_limited", "message": "m"}]
    assert doc["figures"]["z_trueness_q90_mm"]["flags"] == []


def test_sfr_notes_give_the_reason_and_the_table_matches_the_validity():
    """A sharp edge (sigma 0.3 px: exp(-2 pi^2 sigma^2 f^2) |sinc f| = 0.1 at f ~ 0.76 cy/px) is valid but above
    Nyquist; a blurred one (sigma 0.8 px) is valid without a note; a noise-free step has flat ESF ends (invalid:
    clipping); a missing edge is invalid with its reason."""
    from labctl.evaluation.sharpness import _measure, edge_note, resolution_table
    from tests.metrics.test_sfr import render_edge

    noise = np.random.default_rng(2).normal(0.0, 1e-4, (80, 60))  # no exactly flat ESF ends
    sharp = _measure(render_edge(80, 60, 5.0, 0.3) + noise, (0, 0, 60, 80))
    blurred = _measure(render_edge(80, 60, 5.0, 0.8) + noise, (0, 0, 60, 80))
    step = _measure(render_edge(80, 60, 5.0, 0.05), (0, 0, 60, 80))
    assert sharp.valid and 0.7 < sharp.sfr10 < 0.82 and "above Nyquist" in edge_note(sharp)
    assert not step.valid and edge_note(step).startswith("clipping")
    assert blurred.valid and blurred.sfr10 < 0.5 and edge_note(blurred) == "" and blurred.reason == ""
    assert edge_note(None) == "edge not found"
    result = SharpnessResult([SharpnessPosition(300.0, "00001_slanted_edge", "w", 1.0, blurred, None),
                              SharpnessPosition(400.0, "00003_slanted_edge", "w", 1.0, sharp, blurred)], (0.1, 0.1))
    rows = resolution_table(result)
    for orientation, key in (("horizontal", "h"), ("vertical", "v")):
        _, _, ok = result.series(orientation, "sfr10")
        assert [r[f"valid_{key}"] for r in rows] == list(ok)
    assert [r["note_v"] for r in rows] == ["edge not found", ""]


def test_stack_means_below_the_step_are_plausible_when_the_noise_dithers_the_quantizer():
    """With 1 mm steps, a trueness of 0.4 mm is an artefact of a noise-free quantizer (noise 0.1 mm) but a
    resolved mean where the noise (0.8 mm) spans the steps; a precision of 0.4 mm is flagged either way."""
    values = {"z_trueness_q90_mm": 0.4, "surface_waviness_sq_mm": 0.1, "z_precision_q90_mm": 0.4}
    quiet = PlausibilityInputs(quantization_mm={"z": 1.0}, noise_mm={"z": 0.1})
    noisy = PlausibilityInputs(quantization_mm={"z": 1.0}, noise_mm={"z": 0.8})
    assert set(plausibility_flags(values, quiet)) == set(values)
    assert set(plausibility_flags(values, noisy)) == {"z_precision_q90_mm"}


def test_quantization_is_detected_on_the_first_wall_step_with_valid_pixels():
    """A stereo camera's first wall step below its minimum range holds no valid pixel: the step comes from
    the next one (z16 depth in whole millimetres, x and y continuous)."""
    from labctl.evaluation.evaluate import _detect_quantization

    class Step:
        def __init__(self, z):
            self.z = z

        def frame(self, channel, k):  # pinhole back-projection: x = z (u - cx) / f, continuous
            v, u = np.mgrid[0:4, 0:5]
            return self.z[k] * ((u - 2.0) if channel == "x" else (v - 1.5)) / 377.7  # a 2.6 um lattice

    blind = Step(np.full((2, 4, 5), np.nan))
    seen = Step(np.round(1000 + np.random.default_rng(0).normal(0, 3, (2, 4, 5))))
    found = {}
    for step in (blind, seen):
        _detect_quantization(found, step.z, (step.frame("x", 0), step.frame("y", 0)))
    assert found["z"] == 1.0 and math.isnan(found["x"]) and math.isnan(found["y"])


def test_the_report_shows_each_flag_under_its_figure(tmp_path):
    from labctl.evaluation.evaluate import Evaluation
    from labctl.report.html import write_outputs

    camera = CameraDescription(model="m", serial="s", width=8, height=6, fov_deg=[60.0, 45.0])
    evaluation = Evaluation(runs=[], camera=camera, figures={"z_precision_q90_mm": FigureValue(0.0, ["00001_x"])},
                            flags={"z_precision_q90_mm": [{"check": "quantization_limited", "message": "rounding"}]})
    json_path, report = write_outputs(evaluation, tmp_path)
    page = report.read_text().replace("<wbr>", "")  # figure names may wrap at their underscores
    table = page[page.index("<h2>Key figures</h2>"):]
    row = next(r for r in table.split("<tr>") if "z_precision_q90_mm" in r)
    summary = page[page.index('<div class="summary">'):page.index("<h2>Key figures</h2>")]
    assert "quantization limited" in next(r for r in summary.split("<tr>") if "z_precision_q90_mm" in r)
    assert "quantization limited: rounding" in row
    assert '"flags": []' in json_path.read_text()  # the figures without a flag
