"""keyfigures.json's shape as documented (docs/keyfigures.md): ``camera``, ``figures`` and ``suitability`` first;
every figure the documentation names present with ``value`` (null where not measured), ``unit`` and ``source``;
and the file read back as written, its procedure sections into their records."""

from __future__ import annotations

import dataclasses
import json
import math

import pytest

from labctl.evaluation.keyfigures import (
    CameraDescription,
    FigureValue,
    KeyFiguresDocument,
    keyfigures_document,
    read_keyfigures,
)
from labctl.evaluation.suitability import CheckResult, StoryVerdict, Suitability
from labctl.jsondoc import to_json, write_json
from metrics.uncertainty import Component

#: name -> unit, as the documentation's table lists them
DOCUMENTED = {
    "z_trueness_q90_mm": "mm", "z_accuracy_q90_mm": "mm", "z_precision_q90_mm": "mm",
    "z_repeatability_center_mm": "mm", "surface_primary_sq_mm": "mm", "surface_waviness_sq_mm": "mm",
    "surface_roughness_sq_mm": "mm", "hyperfocal_distance_mm": "mm", "best_focus_distance_mm": "mm",
    "intensity_resolution_h_deg": "deg", "intensity_resolution_v_deg": "deg", "cloud_resolution_h_deg": "deg",
    "cloud_resolution_v_deg": "deg", "pixel_aspect_distortion_pct": "%", "radial_distortion_intensity_w_pct": "%",
    "radial_distortion_intensity_h_pct": "%", "radial_distortion_cloud_w_pct": "%",
    "radial_distortion_cloud_h_pct": "%", "x_trueness_q90_mm": "mm", "y_trueness_q90_mm": "mm",
    "x_accuracy_q90_mm": "mm", "y_accuracy_q90_mm": "mm", "x_precision_q90_mm": "mm", "y_precision_q90_mm": "mm",
    "x_repeatability_center_mm": "mm", "y_repeatability_center_mm": "mm", "repeatability_skin_40deg_mm": "mm",
    "repeatability_skin_70deg_mm": "mm", "ied_pixels_at_hyperfocal": "px",
}


def test_every_documented_figure_is_in_the_file_with_value_unit_and_source(tmp_path):
    values = {"z_precision_q90_mm": FigureValue(1.25, ["00002_depth_sweep", "00003_depth_sweep"]),
              "z_trueness_q90_mm": FigureValue(math.nan, ["00002_depth_sweep"])}
    doc = to_json(keyfigures_document(CameraDescription(model="cam"), values, Suitability()))
    assert list(doc)[:3] == ["camera", "figures", "suitability"]
    for name, unit in DOCUMENTED.items():
        figure = doc["figures"][name]
        assert list(figure)[:3] == ["value", "unit", "source"] and figure["unit"] == unit, name
    assert doc["figures"]["z_precision_q90_mm"]["value"] == 1.25
    assert doc["figures"]["z_precision_q90_mm"]["source"] == "00002_depth_sweep,00003_depth_sweep"
    assert doc["figures"]["z_trueness_q90_mm"]["value"] is None  # not finite: null
    assert doc["figures"]["hyperfocal_distance_mm"]["value"] is None  # not measured: null


def test_the_file_reads_back_as_written(tmp_path):
    written = keyfigures_document(CameraDescription(model="cam", serial="1", width=8, fov_deg=[60.0, 45.0]),
                                  {"z_precision_q90_mm": FigureValue(0.5, ["s"], (Component("frames", 0.01),))},
                                  Suitability(standard="std", stories={"a": StoryVerdict(verdict="pass", checks=[
                                      CheckResult(requirement="r", status="pass", limit=1.0, values={"z": 0.5},
                                                  source="s", judgement=True)])}),
                                  {"z_precision_q90_mm": [{"check": "quantization_limited", "message": "m"}]})
    written.notes = ["a note"]
    read = read_keyfigures(write_json(tmp_path / "keyfigures.json", written, final_newline=True))
    assert read == written


def _with_every_section() -> KeyFiguresDocument:
    """A document holding every procedure section, one row per table, with nulls where a value was not measured."""
    doc = keyfigures_document(CameraDescription(model="cam"), {}, Suitability())
    doc.runs, doc.notes = ["run.h5"], []
    doc.conditions = [{"path": "run.h5", "sha256": "ab" * 32, "recorded_by": "0.1.0", "created": "2026-11-26T19:00:00Z",
                       "status": "complete", "simulated": True, "exposures_us": [100.0, 300.0],
                       "camera_temperatures_c": {"asic": [29.0, 31.5]},
                       "devices": [{"role": "camera", "backend": "sim", "model": "cam", "serial": "1", "firmware": "2"}]}]
    doc.depth_sweep = [{"step": "00002_depth_sweep", "reference_mm": 2005.0, "trueness_median_mm": 0.1,
                        "trueness_q90_mm": 0.3, "accuracy_median_mm": 0.5, "accuracy_q90_mm": 1.5,
                        "precision_median_mm": 0.6, "precision_q90_mm": 1.4, "repeatability_center_mm": 2.0,
                        "invalid_fraction": 0.0}]
    doc.slanted_edge = [{"distance_mm": 300.0, "step": "00012_slanted_edge", "sfr10_h": 0.37, "sfr50_h": 0.2,
                         "sfr_area_h": 0.1, "valid_h": True, "resolution_h_deg": 0.3, "resolution_h_mm": 1.6,
                         "note_h": "", "sfr10_v": None, "sfr50_v": None, "sfr_area_v": None, "valid_v": False,
                         "resolution_v_deg": None, "resolution_v_mm": None, "note_v": "edge not found"}]
    doc.capture = [{"step": "00000_capture", "frames": 2, "valid_fraction": 0.9, "depth_median_mm": 1478.0,
                    "depth_q05_mm": 900.0, "depth_q95_mm": 2500.0, "temporal_noise_median_mm": 3.0,
                    "temporal_noise_q90_mm": 27.6, "planar": False, "plane_inlier_fraction": None,
                    "plane_distance_on_axis_mm": None, "plane_tilt_about_x_deg": None, "plane_tilt_about_y_deg": None,
                    "plane_rms_mm": None}]
    doc.alignment = {"step": "00000_alignment", "fields_mm": {"top_left": [-1041.4, -745.5, 2005.9]},
                     "tilt_x_deg": -0.004, "tilt_y_deg": None}
    doc.depth_quality = [{"step": "00002_depth_sweep", "reference_mm": 2005.0, "absolute_reference_mm": 2005.4,
                          "fill_rate_pct": 100.0,
                          "z_accuracy_pct": 0.03, "plane_fit_rms_mm": 0.24, "plane_fit_rms_pct": 0.05,
                          "subpixel_rms_px": None, "spatial_precision_mm": 0.24, "temporal_precision_mm": 0.25}]
    doc.acceptance_test = {"probing_error_form_mm": {"value": 2.6, "mpe_mm": 5, "verdict": "pass"},
                           "flatness_error_mm": {"value": 3.1, "mpe_mm": None, "verdict": "no_mpe"}}
    doc.acceptance_positions = [{"step": "00119_sphere_bar", "distance_mm": 1000.0, "pose_deg": 0.0, "frames": 4.0,
                                 "probing_error_form_mm": 2.6, "probing_error_size_mm": -0.4,
                                 "sphere_spacing_error_mm": 0.1, "flatness_error_mm": None}]
    doc.checkerboard = [{"image": "point cloud", "raw_w_pct": 0.01, "raw_h_pct": 0.02, "radial_w_pct": 0.01,
                         "radial_h_pct": 0.02, "median_w_pct": 0.0, "median_h_pct": 0.0, "fov_estimate_h_deg": None,
                         "fov_estimate_v_deg": None, "k1": None, "corners": 88}]
    doc.boehler_star = [{"star": "72 segments (00041_boehler_star)", "placed_mm": 1000.0, "resolution_h_mm": 2.36,
                         "resolution_v_mm": 2.4, "angular_h_deg": 0.223, "angular_v_deg": 0.23, "distance_mm": 1003.0}]
    doc.xy_noise = [{"step": "00005_depth_sweep", "distance_mm": 2005.7, "repeatability_center_x_mm": 0.01,
                     "repeatability_center_y_mm": 0.01, "repeatability_off_axis_x_mm": 0.5,
                     "repeatability_off_axis_y_mm": 0.4, "precision_q90_x_mm": 0.685, "precision_q90_y_mm": 0.6}]
    doc.remission_angle = [{"step": "00084_remission_angle", "material": "silicone", "angle_deg": 40.0,
                            "radius_mm": 850.0, "on_target": True, "distance_mm": 850.0, "distance_se_mm": 0.01,
                            "repeatability_mm": 0.64, "plane_rms_mm": 0.3, "invalid_fraction": 0.0,
                            "off_target_fraction": 0.0, "trueness_zero_mm": 0.17, "reference_mm": 850.1,
                            "trueness_geometric_mm": 0.07}]
    doc.misalignment = {"material": "ptfe", "target_offset_mm": -0.02, "target_offset_se_mm": 0.01,
                        "camera_axis_offset_mm": 0.02, "camera_axis_offset_se_mm": 0.01, "bias_mm": 0.03,
                        "bias_se_mm": 0.01, "residual_rms_mm": 0.06, "angles": 15}
    doc.face_mask = {"step": "00118_face_mask", "pcd": "face_mask_00118_face_mask.pcd", "invalid_fraction": 0.0}
    return doc


def test_every_procedure_section_reads_back_as_written(tmp_path):
    written = _with_every_section()
    assert all(getattr(written, f.name) is not None for f in dataclasses.fields(KeyFiguresDocument))
    path = write_json(tmp_path / "keyfigures.json", written, final_newline=True)
    assert read_keyfigures(path) == written
    assert json.loads(path.read_text())["acceptance_test"]["probing_error_form_mm"]["mpe_mm"] == 5  # as given


def test_keys_of_another_labctl_version_are_left_out_of_the_sections(tmp_path):
    """A keyfigures.json whose sections carry keys this version does not know reads as the records it knows."""
    written = _with_every_section()
    data = to_json(written)
    data["depth_sweep"][0]["future_column_mm"] = 1.0
    data["acceptance_test"]["probing_error_form_mm"]["future_key"] = "x"
    data["alignment"]["future_key"] = [1, 2]
    data["face_mask"]["future_key"] = None
    path = tmp_path / "keyfigures.json"
    path.write_text(json.dumps(data))
    assert read_keyfigures(path) == written


def test_a_figure_with_a_budget_has_its_combined_and_expanded_uncertainty(tmp_path):
    """u = root sum of squares of the components (0.3 and 0.4 mm: 0.5 mm, JCGM 100:2008, 5.1.2), U = 2 u (6.2);
    a figure without a budget, or without a value, has none."""
    budget = (Component("a", 0.3), Component("b", 0.4))
    doc = to_json(keyfigures_document(CameraDescription(), {
        "z_precision_q90_mm": FigureValue(1.25, ["s"], budget), "z_trueness_q90_mm": FigureValue(0.5, ["s"]),
        "z_accuracy_q90_mm": FigureValue(math.nan, ["s"], budget)}, Suitability()))
    figure = doc["figures"]["z_precision_q90_mm"]
    assert figure["value"] == 1.25
    assert figure["uncertainty"] == pytest.approx(0.5) and figure["expanded_uncertainty"] == pytest.approx(1.0)
    assert figure["uncertainty_budget"] == [{"component": "a", "value": 0.3}, {"component": "b", "value": 0.4}]
    for name in ("z_trueness_q90_mm", "z_accuracy_q90_mm", "hyperfocal_distance_mm"):
        assert doc["figures"][name]["uncertainty"] is None and doc["figures"][name]["expanded_uncertainty"] is None
        assert doc["figures"][name]["uncertainty_budget"] == []


def test_a_file_without_uncertainties_reads_back_with_none_and_an_empty_budget(tmp_path):
    path = tmp_path / "keyfigures.json"
    path.write_text(json.dumps({"camera": {"model": "cam"}, "figures": {"z_precision_q90_mm": {
        "value": 1.25, "unit": "mm", "source": "s", "meaning": "m", "flags": [], "better": "lower"}}}))
    figure = read_keyfigures(path).figures["z_precision_q90_mm"]
    assert figure.value == 1.25
    assert (figure.uncertainty, figure.expanded_uncertainty, figure.uncertainty_budget) == (None, None, [])
