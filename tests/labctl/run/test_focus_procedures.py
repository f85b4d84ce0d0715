"""checkerboard / boehler_star / xy_sweep plans; distance_mm = "best_focus" resolved at run time."""

import dataclasses
import re

import h5py
import pytest

from labctl.cli import main
from labctl.errors import InputError
from labctl.evaluation.evaluate import evaluate_runs
from labctl.run.config import parse_campaign
from tests.conftest import campaign_text

EDGE = """
[[procedure]]
kind = "slanted_edge"
start_mm = 200
stop_mm = 1400
step_mm = 100
frames = 6
exposure_table = [[100, 60], [200, 250], [400, 1000]]
"""
BOARD = """
[[procedure]]
kind = "checkerboard"
frames = 4
"""
STARS = """
[[procedure]]
kind = "boehler_star"
segments = [72, 24]
gap_mm = 250
frames = 4
"""


def invoke(*args) -> int:
    with pytest.raises(SystemExit) as info:
        main([str(a) for a in args])
    return info.value.code


def test_best_focus_needs_an_earlier_slanted_edge():
    with pytest.raises(InputError, match=r'procedure\[0\] \(checkerboard\) takes distance_mm = "best_focus"'):
        parse_campaign(campaign_text(procedures=BOARD + EDGE))
    assert len(parse_campaign(campaign_text(procedures=EDGE + BOARD)).steps()) == 27


def test_star_plan_and_validation():
    steps = parse_campaign(campaign_text(procedures=STARS.replace("segments = [72, 24]", "segments = 24")
                                         .replace("frames = 4", "frames = 4\ndistance_mm = 600"))).steps()
    assert len(steps) == 1 and steps[0].distance_mm == 850 and steps[0].target_params["segments"] == 24
    with pytest.raises(InputError, match="segments must be 72, 24"):
        parse_campaign(campaign_text(procedures=STARS.replace("[72, 24]", "36")))
    with pytest.raises(InputError, match="travel_mm"):  # star at 3900 mm + 250 mm gap
        parse_campaign(campaign_text(procedures=STARS.replace("frames = 4", "frames = 4\ndistance_mm = 3900")))


def test_xy_sweep_is_a_wall_sweep_without_reference():
    text = campaign_text(procedures="""
    [[procedure]]
    kind = "xy_sweep"
    start_mm = 1000
    stop_mm = 2000
    step_mm = 500
    frames = 3
    """)
    steps = parse_campaign(text).steps()
    assert [(s.procedure, s.target, s.distance_mm) for s in steps] == [
        ("xy_sweep", "wall", 1000), ("xy_sweep", "wall", 1500), ("xy_sweep", "wall", 2000)]


def test_best_focus_is_resolved_from_the_run_and_recorded(tmp_path, write_campaign, small_model, capsys):
    """One best focus: the run log, the key figure and the distance the board and the stars are placed at."""
    campaign = write_campaign(procedures=EDGE + BOARD + STARS)
    out = tmp_path / "r.h5"
    model = small_model(width=192, height=144)
    model.write_text(model.read_text().replace("[camera_overrides]", "[effects.defocus]\nhyperfocal_mm = 400\n"
                                                                      "[camera_overrides]"))
    assert invoke("run", campaign, "--sim", "--model", model, "-o", out) == 0
    logged = capsys.readouterr()
    focus = re.search(r"best focus: (\d+) mm", logged.out + logged.err)
    assert focus is not None
    evaluation = evaluate_runs([out])
    assert evaluation.figures["best_focus_distance_mm"].value == float(focus.group(1))
    assert evaluation.geometry.checkerboard.placed_mm == float(focus.group(1))
    assert {s.placed_mm for s in evaluation.geometry.stars} == {float(focus.group(1))}
    with h5py.File(out, "r") as f:
        assert f["steps/00026_checkerboard"].attrs["distance_mm"] == float(focus.group(1))
        board = dict(f["steps/00026_checkerboard"].attrs)
        star = dict(f["steps/00027_boehler_star"].attrs)
        assert board["distance_source"] == "best_focus" and star["distance_source"] == "best_focus"
        # the nearest sharp distance lies on the slanted-edge grid, past the hyperfocal distance
        assert board["distance_mm"] % 100 == 0 and 400 <= board["distance_mm"] <= 1000
        assert star["distance_mm"] == board["distance_mm"] + 250
        assert f["steps/00001_slanted_edge"].attrs["distance_source"] == "campaign"
    # resume recomputes the same distance from the same steps
    with h5py.File(out, "r+") as f:
        del f["steps/00028_boehler_star"]
        f.attrs["status"] = "aborted"
    assert invoke("resume", out, "--quiet") == 0
    with h5py.File(out, "r") as f:
        assert f["steps/00028_boehler_star"].attrs["distance_mm"] == star["distance_mm"]


def test_a_sharpness_peak_at_the_end_of_the_sweep_is_a_warning():
    """The AM-T100 case: SFR area still rising at the last position. Best focus is the nearest position within
    5 % of the highest (smoothed) area, and the warning says the sharpest distance may lie farther."""
    from labctl.evaluation.sharpness import SharpnessPosition, SharpnessResult, _summarize
    from tests.labctl.evaluation.test_plausibility import edge

    def position(distance, area):
        measured = dataclasses.replace(edge(0.3), sfr_area=area)
        return SharpnessPosition(distance, f"{int(distance)}", "w", 1.0, measured, measured)

    areas = [0.20, 0.25, 0.30, 0.35, 0.40, 0.43, 0.44, 0.45]  # smoothed max 0.445: 0.95 x -> 0.4228
    result = SharpnessResult([position(500.0 + 100 * i, a) for i, a in enumerate(areas)], (0.1, 0.1))
    _summarize(result)
    assert result.best_focus_mm == 1000.0
    assert result.focus_warning.startswith("the sharpness peaks at the far end of the sweep (1200 mm)")
    assert any(n.startswith("warning: the sharpness peaks") for n in result.notes)
    peaked = SharpnessResult([position(500.0 + 100 * i, a) for i, a in enumerate([0.2, 0.4, 0.5, 0.4, 0.3])],
                             (0.1, 0.1))
    _summarize(peaked)
    # smoothed: 0.2, 0.4, 0.4, 0.4, 0.3: the peak is inside the sweep, its nearest position is best focus
    assert peaked.best_focus_mm == 600.0 and peaked.focus_warning is None
