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
