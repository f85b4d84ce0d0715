"""labctl compare: chart, table, IED coverage and suitability across cameras."""

import json

import pytest

from labctl.cli import main


def invoke(*args) -> int:
    with pytest.raises(SystemExit) as info:
        main([str(a) for a in args])
    return info.value.code


def keyfigures(tmp_path, name, model, ied, distortion):
    d = tmp_path / name
    d.mkdir()
    doc = {
        "camera": {"model": model},
        "figures": {"ied_pixels_at_hyperfocal": {"value": ied, "unit": "px"},
                    "radial_distortion_cloud_w_pct": {"value": distortion, "unit": "%"},
                    "intensity_resolution_h_deg": {"value": 0.23, "unit": "deg"}},
        "suitability": {"stories": {"3d_face_recognition_1_to_n": {"verdict": "fail"}}},
    }
    (d / "keyfigures.json").write_text(json.dumps(doc))
    return d


def test_compare_two_cameras(tmp_path):
    a = keyfigures(tmp_path, "a", "Basler blaze-101", 88.0, -2.0)
    b = keyfigures(tmp_path, "b", "pmd flexx2 VGA", 72.0, 17.0)
    assert invoke("compare", a, b, "-o", tmp_path / "cmp") == 0
    result = json.loads((tmp_path / "cmp" / "compare.json").read_text())
    assert result["cameras"] == ["Basler blaze-101", "pmd flexx2 VGA"]
    assert result["figures"]["ied_pixels_at_hyperfocal"] == {"Basler blaze-101": 88.0, "pmd flexx2 VGA": 72.0}
    assert result["figures"]["z_trueness_q90_mm"] == {"Basler blaze-101": None, "pmd flexx2 VGA": None}
    assert result["better"]["ied_pixels_at_hyperfocal"] == "higher"  # ISO/IEC 39794-5: at least 90 px
    assert result["better"]["z_accuracy_2000mm_pct"] == "zero" and result["better"]["z_trueness_q90_mm"] == "lower"
    page = (tmp_path / "cmp" / "compare.html").read_text()
    assert "plots/comparison.png" in page and "plots/ied_coverage.png" in page and "fail" in page
    assert (tmp_path / "cmp" / "plots" / "comparison.png").stat().st_size > 5000


def test_same_model_twice_gets_distinct_labels(tmp_path):
    a = keyfigures(tmp_path, "a", "Intel RealSense D455", 59.0, 1.0)
    b = keyfigures(tmp_path, "b", "Intel RealSense D455", 61.0, 1.0)
    assert invoke("compare", a, b, "-o", tmp_path / "cmp") == 0
    assert json.loads((tmp_path / "cmp" / "compare.json").read_text())["cameras"] == [
        "Intel RealSense D455", "Intel RealSense D455 (2)"]


def test_compare_refuses_non_evaluations(tmp_path, capsys):
    empty = tmp_path / "empty"
    empty.mkdir()
    assert invoke("compare", empty, "-o", tmp_path / "cmp") == 2
    assert "no keyfigures.json" in capsys.readouterr().err
    bad = tmp_path / "bad"
    bad.mkdir()
    (bad / "keyfigures.json").write_text("{not json")
    assert invoke("compare", bad, "-o", tmp_path / "cmp") == 2


def _with_uncertainty(tmp_path, name, model, figures):
    """An evaluation with the given figures, each (value, expanded uncertainty or None)."""
    d = tmp_path / name
    d.mkdir()
    doc = {"camera": {"model": model},
           "figures": {k: {"value": v, "unit": "mm", **({"expanded_uncertainty": u} if u is not None else {})}
                       for k, (v, u) in figures.items()}}
    (d / "keyfigures.json").write_text(json.dumps(doc))
    return d


def test_differences_within_the_combined_uncertainty_are_not_distinguishable(tmp_path):
    # trueness: 1.00 +- 0.10 and 1.12 +- 0.10 differ by 0.12 < sqrt(0.1^2 + 0.1^2) = 0.141; 1.50 by 0.38 and 0.50
    # sphere spacing (closer to 0 is better): -0.30 and +0.32 differ by 0.62 but their magnitudes by 0.02 < 0.05
    a = _with_uncertainty(tmp_path, "a", "Basler blaze-101", {"z_trueness_q90_mm": (1.00, 0.10),
                                                               "sphere_spacing_error_mm": (-0.30, 0.03)})
    b = _with_uncertainty(tmp_path, "b", "pmd flexx2 VGA", {"z_trueness_q90_mm": (1.12, 0.10),
                                                             "sphere_spacing_error_mm": (0.32, 0.04)})
    c = _with_uncertainty(tmp_path, "c", "Intel RealSense D455", {"z_trueness_q90_mm": (1.50, 0.10),
                                                                   "sphere_spacing_error_mm": (0.31, None)})
    assert invoke("compare", a, b, c, "-o", tmp_path / "cmp") == 0
    result = json.loads((tmp_path / "cmp" / "compare.json").read_text())
    assert result["not_distinguishable"] == {"z_trueness_q90_mm": [["Basler blaze-101", "pmd flexx2 VGA"]],
                                             "sphere_spacing_error_mm": [["Basler blaze-101", "pmd flexx2 VGA"]]}
    assert result["expanded_uncertainty"]["sphere_spacing_error_mm"] == {"Basler blaze-101": 0.03,
                                                                          "pmd flexx2 VGA": 0.04}
    page = (tmp_path / "cmp" / "compare.html").read_text()
    assert "1.12 &plusmn; 0.1" in page and page.count("not distinguishable from") == 4
