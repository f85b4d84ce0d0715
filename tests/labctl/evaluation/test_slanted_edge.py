"""Issue: sharpness over distance. Procedure plan, end-to-end hyperfocal recovery, analyze sfr CLI."""

import json
import math

import pytest

from labctl.cli import main
from labctl.evaluation.evaluate import evaluate_runs
from labctl.run.config import parse_campaign
from sim.profiles import PROFILES
from tests.conftest import campaign_text
from tests.shared_data import shared_data

DATA = shared_data("sfrmat3_h_edge_mono.tif").parent


def invoke(*args) -> int:
    with pytest.raises(SystemExit) as info:
        main([str(a) for a in args])
    return info.value.code


def slanted(extra: str = "", start=100, stop=2000, step=100, frames=10) -> str:
    return f"""
    [[procedure]]
    kind = "slanted_edge"
    start_mm = {start}
    stop_mm = {stop}
    step_mm = {step}
    frames = {frames}
    {extra}
    """


def test_plan_sweeps_chart_then_white_sheet_with_two_prompts():
    text = campaign_text(procedures=slanted("exposure_table = [[100, 100], [300, 300], [500, 1000]]",
                                             start=100, stop=600))
    steps = parse_campaign(text).steps()
    assert [s.target for s in steps] == ["slanted_edge"] * 6 + ["white_sheet"] * 6
    assert [s.distance_mm for s in steps] == [100, 200, 300, 400, 500, 600, 600, 500, 400, 300, 200, 100]
    assert [s.prompt is not None for s in steps] == [True] + [False] * 5 + [True] + [False] * 5
    assert "mount the slanted-edge chart" in steps[0].prompt and "white sheet" in steps[6].prompt
    assert [s.exposure_us for s in steps[:6]] == [100, 100, 300, 300, 1000, 1000]


def test_exposure_table_must_ascend():
    from labctl.errors import InputError

    with pytest.raises(InputError, match="ascending"):
        parse_campaign(campaign_text(procedures=slanted("exposure_table = [[300, 100], [100, 300]]")))


# Thesis 2024, Table C-1 style exposure tables keep the white sheet below saturation at close range
EXPOSURES = {
    "blaze101": "exposure_table = [[100, 60], [200, 250], [400, 1000]]",
    "amt100": "exposure_table = [[100, 60], [200, 250], [400, 1000]]",
    "flexx2": "exposure_table = [[100, 60], [200, 250], [400, 1000]]",
    "d455": "camera_settings = { projector = false }",  # the projector's dots would ruin the edge (Thesis 2024, 6.2.1)
}
BACKENDS = {"blaze101": "blaze", "amt100": "amt100", "flexx2": "flexx2", "d455": "realsense"}


@pytest.mark.parametrize("profile", sorted(PROFILES))
def test_simulated_sweep_finds_the_profiles_hyperfocal_distance(profile, tmp_path, write_campaign):
    """Issue must-show: within one step (100 mm) of the hyperfocal distance the profile was given."""
    model = tmp_path / "m.toml"
    from sim.model import default_model_text

    model.write_text(default_model_text(profile) + "[camera_overrides]\nwidth = 192\nheight = 144\n")
    campaign = write_campaign(backend=BACKENDS[profile], procedures=slanted(EXPOSURES[profile]))
    out = tmp_path / "r.h5"
    assert invoke("run", campaign, "--sim", "--model", model, "-o", out, "--quiet") == 0
    evaluation = evaluate_runs([out])
    given = PROFILES[profile].hyperfocal_mm
    found = evaluation.figures["hyperfocal_distance_mm"].value
    assert abs(found - given) <= 100, (profile, found, given)
    best = evaluation.figures["best_focus_distance_mm"].value
    assert best >= found
    sensor_h = PROFILES[profile].fov_h_deg / 192
    res_h = evaluation.figures["intensity_resolution_h_deg"].value
    assert sensor_h < res_h < 4 * sensor_h  # imagery resolution is worse than the sensor's, not absurdly
    ied = evaluation.figures["ied_pixels_at_hyperfocal"].value  # pinhole: f = (W / 2) / tan(FOV / 2)
    assert ied == pytest.approx(62.5 * 96 / math.tan(math.radians(PROFILES[profile].fov_h_deg / 2)) / found, rel=1e-9)
    angular = evaluation.figures["ied_pixels_at_hyperfocal_angular"].value
    assert angular == pytest.approx(62.5 / (math.tan(math.radians(sensor_h)) * found), rel=1e-9) and angular > ied


def test_evaluate_writes_sharpness_report(tmp_path, write_campaign, small_model):
    campaign = write_campaign(procedures=slanted(EXPOSURES["blaze101"], start=200, stop=1200, step=200, frames=4))
    out = tmp_path / "r.h5"
    assert invoke("run", campaign, "--sim", "--model", small_model(width=160, height=120), "-o", out, "--quiet") == 0
    assert invoke("evaluate", out, "-o", tmp_path / "ev", "--quiet", "--no-pdf") == 0
    doc = json.loads((tmp_path / "ev" / "keyfigures.json").read_text())
    assert len(doc["slanted_edge"]) == 6
    assert {"sfr10_h", "sfr50_v", "sfr_area_h", "resolution_v_mm", "valid_h"} <= set(doc["slanted_edge"][0])
    report = (tmp_path / "ev" / "report.html").read_text()
    assert "plots/sharpness.png" in report and "plots/intensity_resolution.png" in report


# ------------------------------------------------------------------------------------- labctl analyze sfr
@pytest.mark.parametrize("name,sfr50,sfr10", [("sfrmat3_h_edge_mono.tif", 0.196231, 0.329342),
                                              ("sfrmat3_v_edge_mono.tif", 0.195566, 0.325254)])
def test_analyze_sfr_json_matches_sfrmat5(name, sfr50, sfr10, capsys):
    assert invoke("analyze", "sfr", f"{DATA}/{name}", "--json") == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["sfr50"] == pytest.approx(sfr50, rel=0.01) and doc["sfr10"] == pytest.approx(sfr10, rel=0.01)
    assert set(doc) >= {"sfr10", "sfr50", "sfr_area", "angle_deg", "frequency", "sfr"}
    assert len(doc["frequency"]) == len(doc["sfr"]) and doc["sfr"][0] == pytest.approx(1.0)


def test_analyze_sfr_roi_and_errors(capsys, tmp_path):
    assert invoke("analyze", "sfr", f"{DATA}/sfrmat3_v_edge_mono.tif", "--roi", "0,20,125,260", "--json") == 0
    assert json.loads(capsys.readouterr().out)["sfr50"] == pytest.approx(0.1956, rel=0.02)
    assert invoke("analyze", "sfr", tmp_path / "missing.png") == 2
    assert invoke("analyze", "sfr", f"{DATA}/sfrmat3_v_edge_mono.tif", "--roi", "0,0,-5,10") == 2
    blank = tmp_path / "blank.npy"
    import numpy as np

    np.save(blank, np.ones((50, 50)))
    assert invoke("analyze", "sfr", blank) == 2
    assert "no" in capsys.readouterr().err.lower()
