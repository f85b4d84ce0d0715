"""labctl plan: lists and times every step without touching hardware."""

import json
from pathlib import Path

import pytest

from labctl.cli import main

EXAMPLES = sorted((Path(__file__).parents[3] / "examples").glob("*.toml"))


def test_plan_json_lists_steps_with_durations(write_campaign, capsys):
    with pytest.raises(SystemExit) as info:
        main(["plan", str(write_campaign()), "--json"])
    assert info.value.code == 0
    doc = json.loads(capsys.readouterr().out)
    steps = doc["steps"]
    assert [s["step_id"] for s in steps][:2] == ["00000_offset_calibration", "00001_depth_sweep"]
    # home (0 mm) -> 2000 mm at 50 mm/s + 0.5 s settle, 5 laser readings, 8 frames at 30 fps + set-up
    assert steps[0]["duration_s"] == pytest.approx(2000 / 50 + 0.5 + 5 * 0.3 + 8 / 30 + 0.5, abs=1e-3)
    assert steps[1]["start_s"] == pytest.approx(steps[0]["duration_s"], abs=1e-3)
    assert doc["total_duration_s"] == pytest.approx(sum(s["duration_s"] for s in steps), abs=1e-2)


@pytest.mark.parametrize("example", EXAMPLES, ids=[p.name for p in EXAMPLES])
def test_shipped_examples_are_valid(example, capsys):
    with pytest.raises(SystemExit) as info:
        main(["plan", str(example)])
    assert info.value.code == 0
    assert "estimated lab time" in capsys.readouterr().out


# the sweep never stands at 2000 mm, where the offset is calibrated
SWEEP = """
[[procedure]]
kind = "offset_calibration"
distance_mm = 2000
frames = 8

[[procedure]]
kind = "depth_sweep"
start_mm = 400
stop_mm = 3400
step_mm = 500
frames = 8
{keys}
"""


def _confounds(write_campaign, capsys, keys: str) -> dict:
    with pytest.raises(SystemExit) as info:
        main(["plan", str(write_campaign(procedures=SWEEP.format(keys=keys))), "--json"])
    assert info.value.code == 0
    doc = json.loads(capsys.readouterr().out)
    return {tuple(c["axes"]): c for c in doc["confounds"]}


def test_plan_says_a_one_way_sweep_cannot_tell_a_drift_from_a_range_error(write_campaign, capsys):
    pairs = _confounds(write_campaign, capsys, "")
    time_distance = pairs[("time", "distance")]
    assert time_distance["separated"] is False
    assert "temperature_drift" in time_distance["effects"][0] and "range_scale" in time_distance["effects"][1]
    assert "return_mm = 2000" in time_distance["capture"]  # the offset position again, which the plan lacks
    # a wall alone: nothing at one distance with another signal
    assert pairs[("distance", "signal")]["separated"] is False
    assert "remission" in pairs[("distance", "signal")]["capture"]


def test_plan_says_a_returning_interleaved_sweep_tells_them_apart(write_campaign, capsys):
    pairs = _confounds(write_campaign, capsys, 'order = "interleaved"\nreturn_mm = 2000')
    assert pairs[("time", "distance")]["separated"] is True
    assert "2000 mm position is seen again" in pairs[("time", "distance")]["by"]
    assert pairs[("time", "signal")]["separated"] is True
    with pytest.raises(SystemExit):
        main(["plan", str(write_campaign(procedures=SWEEP.format(keys="")))])
    text = capsys.readouterr().out
    assert "cannot tell time (temperature_drift) from distance" in text and "return_mm = 2000" in text
