"""The operator's prompts: one at every change of target, planned and listed; Ctrl-C at a prompt
stops the run at once (exit 130, run resumable); resume re-confirms the mounted target."""

from __future__ import annotations

import json
import textwrap
from pathlib import Path

import h5py
import pytest

from labctl.cli import main
from labctl.run.config import load_campaign
from tests.conftest import run_labctl
from tests.pty_terminal import Terminal

ROOT = Path(__file__).resolve().parents[3]
EXAMPLES = sorted((ROOT / "examples").glob("*.toml")) + sorted((ROOT / "examples" / "demo").glob("*.toml"))


def what_is_mounted(step) -> tuple[str, object]:
    """The target as the operator handles it: a star swap (72 -> 24 segments) is a change as well."""
    return step.target, step.target_params.get("segments")


@pytest.mark.parametrize("campaign", EXAMPLES, ids=lambda p: str(p.relative_to(ROOT)))
def test_every_change_of_target_in_the_example_campaigns_has_a_planned_prompt(
    campaign: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    steps = load_campaign(campaign)[0].steps()
    with pytest.raises(SystemExit) as done:
        main(["plan", str(campaign), "--json"])
    assert done.value.code == 0
    planned = json.loads(capsys.readouterr().out)["steps"]
    assert [p["prompt"] for p in planned] == [s.prompt for s in steps]
    before = ("wall", None)  # the lab at rest: the camera looks at the bare wall
    changes = 0
    for step in steps:
        if what_is_mounted(step) != before:
            changes += 1
            assert step.prompt, f"{step.step_id}: {before[0]} -> {step.target} without an operator prompt"
        before = what_is_mounted(step)
    with pytest.raises(SystemExit):
        main(["plan", str(campaign)])
    listed = capsys.readouterr().out.count("operator: ")
    assert listed == sum(1 for s in steps if s.prompt) >= changes
    if any(s.target == "slanted_edge" for s in steps):
        chart = next(s for s in steps if s.target == "slanted_edge")
        assert chart.prompt.startswith("mount the slanted-edge chart on the wall")


def test_a_return_to_the_wall_and_a_first_target_are_prompted(write_campaign) -> None:
    procedures = """
    [[procedure]]
    kind = "checkerboard"
    distance_mm = 1500

    [[procedure]]
    kind = "xy_sweep"
    start_mm = 1000
    stop_mm = 2000
    step_mm = 500

    [[procedure]]
    kind = "face_mask"
    distance_mm = 1000

    [[procedure]]
    kind = "offset_calibration"
    """
    steps = load_campaign(write_campaign(procedures=textwrap.dedent(procedures)))[0].steps()
    prompts = [s.prompt for s in steps]
    assert prompts[0].startswith("mount the checkerboard")
    assert prompts[1] == "remove the checkerboard: the camera must see the bare white wall only"
    assert prompts[2:4] == [None, None]  # the rest of the sweep: same wall
    assert prompts[4].startswith("mount the silicone face mask")
    assert prompts[5] == "remove the silicone face mask: the camera must see the bare white wall only"


CHART_CAMPAIGN = """
[[procedure]]
kind = "offset_calibration"
frames = 3

[[procedure]]
kind = "slanted_edge"
start_mm = 1000
stop_mm = 1000
frames = 3
"""


@pytest.mark.slow
def test_ctrl_c_at_a_prompt_aborts_at_once_and_the_run_resumes(tmp_path: Path, write_campaign, small_model) -> None:
    campaign, model, out = write_campaign(procedures=CHART_CAMPAIGN), small_model(), tmp_path / "run.h5"
    terminal = Terminal("run", campaign, "--sim", "--interactive", "--model", model, "-o", out)
    try:
        terminal.expect(r"OPERATOR: mount the slanted-edge chart.*\n.*Press Enter when done \(Ctrl-C aborts safely\)")
        terminal.type("\x03")  # Ctrl-C, nothing else: no Enter follows
        assert terminal.wait() == 130, terminal.output
    finally:
        terminal.close()
    assert "interrupted by the operator (Ctrl-C); devices are in their safe state" in terminal.output
    assert f"Continue with: labctl resume {out}" in terminal.output
    assert "Traceback" not in terminal.output
    with h5py.File(out, "r") as f:
        assert f.attrs["status"] == "aborted"
        assert [k for k, g in f["steps"].items() if g.attrs["complete"]] == ["00000_offset_calibration"]
    resumed = run_labctl("resume", out)
    assert resumed.returncode == 0, resumed.stderr
    # the next step prompts on its own (mount the chart), so no extra re-confirmation is asked
    assert "operator (simulated): mount the slanted-edge chart" in resumed.stderr
    assert "resuming at" not in resumed.stderr
    with h5py.File(out, "r") as f:
        assert f.attrs["status"] == "complete"
        assert list(f["steps"]) == ["00000_offset_calibration", "00001_slanted_edge", "00002_slanted_edge"]


@pytest.mark.slow
def test_resume_in_a_target_block_reconfirms_the_target(tmp_path: Path, write_campaign, small_model) -> None:
    procedures = """
    [[procedure]]
    kind = "xy_sweep"
    start_mm = 1000
    stop_mm = 2000
    step_mm = 500
    frames = 2
    """
    campaign, model, out = write_campaign(procedures=textwrap.dedent(procedures)), small_model(), tmp_path / "run.h5"
    assert run_labctl("run", campaign, "--sim", "--model", model, "-o", out, "--quiet").returncode == 0
    with h5py.File(out, "r+") as f:  # as a run stopped after its second step leaves it
        del f["steps/00002_xy_sweep"]
        f.attrs["status"] = "aborted"
    terminal = Terminal("resume", out, "--interactive")
    try:
        terminal.expect(r"OPERATOR: resuming at 00002_xy_sweep: check that the camera sees the bare white wall")
        terminal.expect("Press Enter when done")
        assert terminal.process.poll() is None  # it waits for the operator
        terminal.type("\r")
        assert terminal.wait() == 0, terminal.output
    finally:
        terminal.close()
    with h5py.File(out, "r") as f:
        assert f.attrs["status"] == "complete" and len(f["steps"]) == 3
        assert f["steps/00002_xy_sweep"].attrs["complete"]
