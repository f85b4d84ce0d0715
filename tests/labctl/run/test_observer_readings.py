"""What a watched run tells its observer about the reference instruments: the laser's reading and the robot's
and the stage's positions read back from the devices once they moved, and the robot's pose while it moves."""

from __future__ import annotations

from pathlib import Path

import pytest

from drivers.protocols import RobotPose
from labctl.run.campaign import run_campaign
from labctl.run.config import parse_campaign
from labctl.run.lab import simulated_lab
from labctl.run.observer import RunObserver
from labctl.run.progress import Reporter
from tests.conftest import SMALL_MODEL, campaign_text

ANGLES = [-20.0, -5.0, 10.0]
"""``angles_deg = [-20, 10, 15]``: from -20 to 10 deg in steps of 15."""
RADIUS_MM = 700.0


class Recorder(RunObserver):
    def __init__(self) -> None:
        self.events: list[tuple[str, object]] = []

    def step(self, planned, lab_time_left_s) -> None:  # type: ignore[no-untyped-def]
        self.events.append(("step", planned.step))

    def robot_pose(self, pose: RobotPose) -> None:
        self.events.append(("moving", pose))

    def readings(self, laser_mm, robot, stage_mm) -> None:  # type: ignore[no-untyped-def]
        self.events.append(("readings", (laser_mm, robot, stage_mm)))


def test_a_watched_run_reads_the_robot_and_the_stage_back(tmp_path: Path) -> None:
    text = campaign_text(
        extra_devices='[devices.robot]\nhost = "127.0.0.1"\n',
        procedures=f"""
        [[procedure]]
        kind = "remission_angle"
        materials = ["ptfe"]
        angles_deg = [-20, 10, 15]
        radius_mm = {RADIUS_MM}
        frames = 2
        """,
    )
    campaign = parse_campaign(text)
    lab = simulated_lab(campaign, SMALL_MODEL.format(camera="blaze101", width=32, height=24))
    recorder = Recorder()
    run_campaign(campaign, text, lab, tmp_path / "run.h5", reporter=Reporter(quiet=True),
                 observer=recorder)
    steps = [event for kind, event in recorder.events if kind == "step"]
    assert [s.robot_angle_deg for s in steps] == ANGLES
    for k, step in enumerate(steps):
        start = recorder.events.index(("step", step))
        end = recorder.events.index(("step", steps[k + 1])) if k + 1 < len(steps) else len(recorder.events)
        between = recorder.events[start + 1:end]
        moving = [pose for kind, pose in between if kind == "moving"]
        assert moving and moving[-1] == RobotPose(step.robot_angle_deg, RADIUS_MM)  # the pose it arrived at
        (laser, robot, stage), = [value for kind, value in between if kind == "readings"]
        assert robot == RobotPose(step.robot_angle_deg, RADIUS_MM) and stage == pytest.approx(0.0)
        assert laser is None or laser > 0


def test_an_unwatched_run_asks_the_devices_nothing_more(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Without an observer the stage is never asked for its position: the read-back is for those watching."""
    from sim.devices import SimStage

    def refuse(self: SimStage) -> float:
        raise AssertionError("position read back in an unwatched run")

    monkeypatch.setattr(SimStage, "position_mm", refuse)
    text = campaign_text()
    campaign = parse_campaign(text)
    lab = simulated_lab(campaign, SMALL_MODEL.format(camera="blaze101", width=32, height=24))
    result = run_campaign(campaign, text, lab, tmp_path / "run.h5", reporter=Reporter(quiet=True))
    assert result.status == "complete"
