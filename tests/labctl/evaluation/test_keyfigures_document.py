"""keyfigures.json's shape as documented (docs/keyfigures.md): ``camera``, ``figures`` and ``suitability`` first;
every figure the documentation names present with ``value`` (null where not measured), ``unit`` and ``source``;
and the file read back as written."""

from __future__ import annotations

import math

from labctl.evaluation.keyfigures import CameraDescription, FigureValue, keyfigures_document, read_keyfigures
from labctl.evaluation.suitability import CheckResult, StoryVerdict, Suitability
from labctl.jsondoc import to_json, write_json

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
                                  {"z_precision_q90_mm": FigureValue(0.5, ["s"])},
                                  Suitability(standard="std", stories={"a": StoryVerdict(verdict="pass", checks=[
                                      CheckResult(requirement="r", status="pass", limit=1.0, values={"z": 0.5},
                                                  source="s", judgement=True)])}),
                                  {"z_precision_q90_mm": [{"check": "quantization_limited", "message": "m"}]})
    written.notes = ["a note"]
    read = read_keyfigures(write_json(tmp_path / "keyfigures.json", written, final_newline=True))
    assert read == written
