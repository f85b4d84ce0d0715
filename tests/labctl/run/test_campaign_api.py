"""The Python interface of running a campaign (labctl.run.campaign): the example of docs/campaign.md, run as
written, makes the run ``labctl run --sim`` makes; resuming a complete file runs nothing; a simulated lab
without its model is refused before anything is written."""

from __future__ import annotations

import re
from pathlib import Path

import h5py
import hdf5plugin  # noqa: F401 (the run file's compression filter)
import numpy as np
import pytest

from labctl.cli import main
from labctl.run.campaign import RunResult, resume_run, run_campaign
from labctl.run.config import load_campaign
from labctl.run.lab import build_sim_lab
from labctl.run.progress import Reporter
from sim.model import default_model_text, parse_model

DOC = Path(__file__).resolve().parents[3] / "docs" / "campaign.md"
SECTION = "## Running a campaign from Python"
#: the example's campaign: an offset calibration and the wall at 1000, 2000 and 3000 mm
PLANNED_STEPS = 1 + 3


def example() -> tuple[str, str]:
    """The campaign file and the Python script of the section, as the reader sees them."""
    text = DOC.read_text()
    section = text[text.index(SECTION):].split("\n## ")[0]
    blocks = dict(re.findall(r"```(toml|python)\n(.*?)```", section, re.S))
    return blocks["toml"], blocks["python"]


@pytest.fixture
def documented_run(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]):
    """The documented example run in an empty directory: its namespace and what it printed."""
    campaign, script = example()
    (tmp_path / "short.toml").write_text(campaign)
    monkeypatch.chdir(tmp_path)
    namespace: dict[str, object] = {}
    exec(compile(script, f"{DOC}: {SECTION}", "exec"), namespace)
    return tmp_path, namespace, capsys.readouterr().out


def test_the_documented_example_runs_the_campaign_as_labctl_run_does(documented_run) -> None:
    directory, namespace, printed = documented_run
    result = namespace["result"]
    assert isinstance(result, RunResult)
    assert (result.status, result.steps_planned, result.steps_done, result.steps_run) == (
        "complete", PLANNED_STEPS, PLANNED_STEPS, PLANNED_STEPS)
    assert result.simulated and result.discarded == ()
    assert printed == f"short.h5: complete, {PLANNED_STEPS} of {PLANNED_STEPS} steps\n"
    with pytest.raises(SystemExit) as code:
        main(["run", "short.toml", "--sim", "--seed", "3", "-o", "cli.h5", "--quiet"])
    assert code.value.code == 0
    with h5py.File(directory / "short.h5") as mine, h5py.File(directory / "cli.h5") as cli:
        assert mine.attrs["status"] == "complete" and bool(mine.attrs["simulated"])
        assert int(mine["sim"].attrs["seed"]) == 3
        assert mine.attrs["campaign_toml"] == (directory / "short.toml").read_text()
        assert len(mine["steps"]) == PLANNED_STEPS
        assert all(step.attrs["complete"] for step in mine["steps"].values())
        assert sorted(mine["steps"]) == sorted(cli["steps"])
        for name, step in mine["steps"].items():
            assert step.attrs["frames"] == 5
            for channel in ("z", "intensity"):
                np.testing.assert_array_equal(step[channel][()], cli["steps"][name][channel][()])


def test_resume_runs_the_unfinished_step_again_and_nothing_once_complete(documented_run) -> None:
    run = documented_run[0] / "short.h5"
    with h5py.File(run, "r+") as f:  # the run stopped while its last step was being written
        last = sorted(f["steps"])[-1]
        f["steps"][last].attrs["complete"] = False
        f.attrs["status"] = "aborted"
    result = resume_run(run, reporter=Reporter(quiet=True))
    assert (result.status, result.steps_done, result.steps_run, result.discarded) == (
        "complete", PLANNED_STEPS, 1, (last,))
    again = resume_run(run, reporter=Reporter(quiet=True))
    assert (again.status, again.steps_done, again.steps_run) == ("complete", PLANNED_STEPS, 0)


def test_a_simulated_lab_without_its_model_text_is_refused(write_campaign, tmp_path: Path) -> None:
    campaign, text = load_campaign(write_campaign())
    lab = build_sim_lab(campaign, parse_model(default_model_text("blaze101")), 1)  # no model text for /sim
    with pytest.raises(ValueError, match="simulated_lab"):
        run_campaign(campaign, text, lab, tmp_path / "run.h5", reporter=Reporter(quiet=True))
    assert not (tmp_path / "run.h5").exists()
