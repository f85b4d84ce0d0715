"""Evaluation of simulated runs: key figures, notes, report."""

import json
from pathlib import Path

import pytest

from labctl.cli import main
from labctl.errors import InputError
from labctl.evaluation.evaluate import evaluate_runs
from labctl.evaluation.keyfigures import FIGURES, STEREO_ONLY, VENDOR_FIGURES

CONTRACT_NAMES = {
    "z_trueness_q90_mm", "z_accuracy_q90_mm", "z_precision_q90_mm", "z_repeatability_center_mm",
    "surface_primary_sq_mm", "surface_waviness_sq_mm", "surface_roughness_sq_mm", "hyperfocal_distance_mm",
    "best_focus_distance_mm", "intensity_resolution_h_deg", "intensity_resolution_v_deg",
    "cloud_resolution_h_deg", "cloud_resolution_v_deg", "pixel_aspect_distortion_pct",
    "radial_distortion_intensity_w_pct", "radial_distortion_intensity_h_pct", "radial_distortion_cloud_w_pct",
    "radial_distortion_cloud_h_pct", "x_trueness_q90_mm", "y_trueness_q90_mm", "x_accuracy_q90_mm",
    "y_accuracy_q90_mm", "x_precision_q90_mm", "y_precision_q90_mm", "x_repeatability_center_mm",
    "y_repeatability_center_mm", "repeatability_skin_40deg_mm", "repeatability_skin_70deg_mm",
    "ied_pixels_at_hyperfocal",
}
DEPTH = {"z_trueness_q90_mm", "z_accuracy_q90_mm", "z_precision_q90_mm", "z_repeatability_center_mm",
         "surface_primary_sq_mm", "surface_waviness_sq_mm", "surface_roughness_sq_mm",
         # the wall stacks of a depth sweep also give the x/y noise when the run has no xy_sweep
         "x_precision_q90_mm", "y_precision_q90_mm", "x_repeatability_center_mm", "y_repeatability_center_mm",
         "x_repeatability_off_axis_mm", "y_repeatability_off_axis_mm"}
#: the datasheet-comparable figures of the wall at 1 m and 2 m; a ToF camera has no subpixel RMS, and Z accuracy
#: needs the campaign's devices.camera.depth_origin_offset_mm (tests/labctl/evaluation/test_absolute_reference.py)
NEEDS_DEPTH_ORIGIN = {"z_accuracy_1000mm_pct", "z_accuracy_2000mm_pct"}
VENDOR = {f.name for f in VENDOR_FIGURES} - STEREO_ONLY - NEEDS_DEPTH_ORIGIN


def invoke(*args) -> int:
    with pytest.raises(SystemExit) as info:
        main([str(a) for a in args])
    return info.value.code


@pytest.fixture
def sim_run(tmp_path, write_campaign, small_model):
    def make(name="r.h5", camera="blaze101", backend="blaze", **kw) -> Path:
        out = tmp_path / name
        campaign = write_campaign(f"{name}.toml", backend=backend, **kw)
        assert invoke("run", campaign, "--sim", "--model", small_model(camera, 120, 90), "-o", out, "--quiet") == 0
        return out

    return make


def test_every_contract_figure_is_defined():
    assert CONTRACT_NAMES <= {f.name for f in FIGURES}


def test_depth_run_gives_depth_figures_and_nulls_elsewhere(sim_run, tmp_path):
    run = sim_run()
    assert invoke("evaluate", run, "-o", tmp_path / "out", "--quiet", "--no-pdf") == 0
    doc = json.loads((tmp_path / "out" / "keyfigures.json").read_text())
    figures = doc["figures"]
    assert CONTRACT_NAMES <= set(figures)
    for name, f in figures.items():
        if name in DEPTH:
            assert f["value"] is not None and f["value"] > 0, name
            assert f["unit"] == "mm"
        elif name in VENDOR:
            assert f["value"] is not None, name
        elif name == "pixel_aspect_distortion_pct":  # needs only the camera's FOV and pixels
            assert f["value"] == pytest.approx(100 * ((51 / 90) / (67 / 120) - 1))
        else:
            assert f["value"] is None, name
    stories = doc["suitability"]["stories"]
    assert stories["3d_face_recognition_1_to_n"]["verdict"] == "not_evaluated"
    assert figures["z_precision_q90_mm"]["source"] == "00003_depth_sweep"  # the 2000 mm position
    assert len(figures["z_repeatability_center_mm"]["source"].split(",")) == 5
    assert doc["camera"]["model"].startswith("Basler blaze-101") and doc["camera"]["width"] == 120
    # trueness of an unbiased simulated camera: only the stack's own noise and the laser's
    assert figures["z_trueness_q90_mm"]["value"] < figures["z_precision_q90_mm"]["value"]
    assert [row["reference_mm"] for row in doc["depth_sweep"]] == pytest.approx(
        [1006, 1506, 2006, 2506, 3006], abs=1.5)
    report = (tmp_path / "out" / "report.html").read_text()
    assert "plots/depth_error.png" in report and "plots/surface_texture.png" in report
    assert (tmp_path / "out" / "plots" / "depth_error.png").stat().st_size > 10_000


def test_runs_of_one_camera_evaluate_together(sim_run):
    near = sim_run("near.h5", procedures="""
    [[procedure]]
    kind = "offset_calibration"
    frames = 6
    [[procedure]]
    kind = "depth_sweep"
    start_mm = 1000
    stop_mm = 1500
    step_mm = 500
    frames = 6
    """)
    far = sim_run("far.h5", procedures="""
    [[procedure]]
    kind = "offset_calibration"
    frames = 6
    [[procedure]]
    kind = "depth_sweep"
    start_mm = 2000
    stop_mm = 3000
    step_mm = 1000
    frames = 6
    """)
    evaluation = evaluate_runs([near, far])
    assert [round(p.errors.reference_mm, -2) for p in evaluation.depth] == [1000, 1500, 2000, 3000]
    assert evaluation.figures["z_precision_q90_mm"].value is not None


def test_runs_of_different_cameras_are_refused(sim_run):
    a = sim_run("a.h5")
    b = sim_run("b.h5", camera="flexx2", backend="flexx2")
    with pytest.raises(InputError, match="evaluate one camera at a time"):
        evaluate_runs([a, b])


def test_sweep_without_2m_position_says_so(sim_run):
    run = sim_run(procedures="""
    [[procedure]]
    kind = "offset_calibration"
    frames = 4
    [[procedure]]
    kind = "depth_sweep"
    start_mm = 500
    stop_mm = 1000
    step_mm = 500
    frames = 4
    """)
    evaluation = evaluate_runs([run])
    assert "z_precision_q90_mm" not in evaluation.figures
    assert "z_repeatability_center_mm" in evaluation.figures
    assert any("2000 mm" in note for note in evaluation.notes)
