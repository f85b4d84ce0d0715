"""Run progress: step k/n and steps done, frames, the planned lab time left; one line per step event
when not on a terminal (a log file or pipe), never wrapped."""

from __future__ import annotations

import io
import re

from rich.console import Console

from labctl.run.config import load_campaign
from labctl.run.planning import format_duration, schedule
from labctl.run.progress import Reporter
from tests.conftest import run_labctl


def captured_reporter() -> tuple[Reporter, io.StringIO]:
    out = io.StringIO()
    return Reporter(console=Console(file=out, force_terminal=False, width=80, soft_wrap=True)), out


def test_log_lines_count_steps_frames_and_planned_lab_time(write_campaign):
    config, _ = load_campaign(write_campaign())
    plan = schedule(config)  # 6 steps of 8 frames
    reporter, out = captured_reporter()
    reporter.start(plan, done=set())
    for planned in plan[:3]:
        reporter.step(planned)
        reporter.frames(planned.step.frames)
    reporter.stop()
    lines = out.getvalue().splitlines()
    assert lines[0] == f"run: 6 steps (0 done), frames 0/48, lab time left {format_duration(sum(p.duration_s for p in plan))}"
    assert len(lines) == 4  # one line per event, however long
    assert max(map(len, lines)) > 80  # ... and not wrapped at the 80 columns of a non-terminal console
    third = lines[3]
    assert third.startswith("step 3/6 00002_depth_sweep (2 done): target wall, 8 frames; frames 16/48;")
    assert third.endswith(f"lab time left {format_duration(sum(p.duration_s for p in plan[2:]))}")


def test_waiting_at_a_prompt_still_shows_the_lab_time_of_the_rest(write_campaign):
    """Before a step's first frame (prompt, moves) the left time is that of the step and all after it."""
    config, _ = load_campaign(write_campaign())
    plan = schedule(config)
    reporter, _ = captured_reporter()
    reporter.start(plan, done={plan[0].step.step_id})  # resumed after the first step
    reporter.step(plan[1])
    assert reporter.lab_time_left_s() == sum(p.duration_s for p in plan[1:])
    reporter.frames(4)  # half the stack
    expected = plan[1].duration_s / 2 + sum(p.duration_s for p in plan[2:])
    assert abs(reporter.lab_time_left_s() - expected) < 1e-9


def test_run_piped_to_a_file_logs_each_step_on_one_line(write_campaign, small_model, tmp_path):
    result = run_labctl("run", write_campaign(), "--sim", "--model", small_model(), "-o", tmp_path / "r.h5")
    assert result.returncode == 0, result.stderr
    steps = [line for line in result.stderr.splitlines() if line.startswith("step ")]
    assert [re.match(r"step (\d)/6 ", s).group(1) for s in steps] == list("123456")
    assert all(re.search(r"; frames \d+/48; lab time left ", s) for s in steps)
    assert "\x1b[" not in result.stderr  # no terminal control sequences in a log
