"""Real signals to a real ``labctl run``: SIGTERM, SIGHUP (a closed terminal), Ctrl-C twice, and
signals that arrive while the devices are being made safe. Each run must end with every device in
its safe state, the run file ``aborted`` with the signal as its reason, exit 130, and a ``resume``
that completes it.

The simulated runs are stopped after a step's progress line; the real-lab runs drive the serial
devices on their pty emulators (what the emulator received is the device's state) and play the
RealSense recording as the camera.
"""

from __future__ import annotations

import os
import signal
import time
from pathlib import Path

import h5py
import pytest

from sim.emulators import DimetixEmulator, ZaberEmulator
from tests.conftest import run_labctl
from tests.labctl.run.test_kill_resume import PROCEDURES, start_run, wait_for_line
from tests.labctl.run.test_operator_prompts import CHART_CAMPAIGN
from tests.labctl.run.test_real_lab import STEP, campaign
from tests.labctl.run.test_resume_overrides import CHART
from tests.pty_terminal import Terminal

SWEEP = [f"{i:05d}_{'offset_calibration' if i == 0 else 'depth_sweep'}" for i in range(10)]
"""The steps of PROCEDURES."""

PROMPT = r"OPERATOR: mount the slanted-edge chart.*\n.*Press Enter when done"
RESUME_PROMPT = r"OPERATOR: .*\n.*Press Enter when done"


def status(run_file: Path) -> tuple[str, str]:
    with h5py.File(run_file, "r") as f:
        return str(f.attrs["status"]), str(f.attrs.get("status_reason", ""))


def complete_steps(run_file: Path) -> list[str]:
    with h5py.File(run_file, "r") as f:
        return sorted(k for k, g in f["steps"].items() if g.attrs["complete"])


@pytest.mark.slow
@pytest.mark.parametrize(("signum", "reason"), [(signal.SIGTERM, "terminated by SIGTERM"),
                                                (signal.SIGHUP, "terminated by SIGHUP (the terminal closed)")])
def test_sigterm_and_sighup_abort_a_simulated_run_that_resume_completes(
    tmp_path: Path, write_campaign, small_model, signum: int, reason: str
) -> None:
    out = tmp_path / "run.h5"
    proc = start_run(write_campaign(procedures=PROCEDURES), small_model(width=160, height=120), out)
    wait_for_line(proc, "00001_depth_sweep complete")
    os.kill(proc.pid, signum)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 130, err
    assert f"{reason}; devices are in their safe state and {out} is marked aborted" in err
    assert f"labctl resume {out}" in err and "Traceback" not in err
    assert status(out) == ("aborted", reason)
    assert 2 <= len(complete_steps(out)) < len(SWEEP)
    resumed = run_labctl("resume", out)
    assert resumed.returncode == 0, resumed.stderr
    assert status(out)[0] == "complete" and complete_steps(out) == SWEEP


@pytest.mark.slow
def test_ctrl_c_twice_aborts_a_simulated_run_that_resume_completes(tmp_path: Path, write_campaign, small_model) -> None:
    """Ctrl-C twice in a row: whether Python runs the handler twice (the second raises KeyboardInterrupt
    wherever the run is) or once (both arrived before it ran), the abort runs in full. The second Ctrl-C
    during a device operation, for certain, is the real-lab test below."""
    out = tmp_path / "run.h5"
    proc = start_run(write_campaign(procedures=PROCEDURES), small_model(width=160, height=120), out)
    wait_for_line(proc, "00001_depth_sweep complete")
    os.kill(proc.pid, signal.SIGINT)
    os.kill(proc.pid, signal.SIGINT)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 130, err
    assert "Traceback" not in err and f"labctl resume {out}" in err
    assert status(out) == ("aborted", "interrupted by the operator (Ctrl-C)")
    assert run_labctl("resume", out).returncode == 0
    assert complete_steps(out) == SWEEP


def zaber() -> ZaberEmulator:
    return ZaberEmulator(mm_per_microstep=STEP, travel_mm=400.0, speed_mm_s=2000.0, start_mm=150.0)


def stage_section(port: str) -> str:
    return f'protocol = "zaber"\nport = "{port}"\nmm_per_microstep = {STEP}'


def wait_until(condition, timeout_s: float, what: str) -> None:
    deadline = time.monotonic() + timeout_s
    while not condition():
        assert time.monotonic() < deadline, f"{what} not within {timeout_s} s"
        time.sleep(0.01)


def exit_code(terminal: Terminal, timeout_s: float = 60.0) -> int:
    """The exit code of a run whose terminal is gone (nothing more can be read from it)."""
    try:
        return terminal.process.wait(timeout=timeout_s)
    except Exception:
        terminal.process.kill()
        raise


def resume_on_a_terminal(run_file: Path, *options: str) -> str:
    """``labctl resume`` as an operator runs it: confirm the mounted target of the next step."""
    terminal = Terminal("resume", run_file, *options)
    try:
        terminal.expect(RESUME_PROMPT, timeout=120)
        terminal.type("\r")
        assert terminal.wait(timeout=120) == 0, terminal.output
        return terminal.output
    finally:
        terminal.close()


@pytest.mark.slow
def test_closing_the_terminal_of_a_real_lab_run_leaves_the_devices_safe_and_resume_completes(tmp_path: Path) -> None:
    """The terminal goes away (SSH dropped): SIGHUP, and every later write to the terminal fails with EIO."""
    path, run_file = tmp_path / "campaign.toml", tmp_path / "run.h5"
    with zaber() as stage, DimetixEmulator(distance_mm=1234.5) as laser:
        path.write_text(campaign(stage_section(stage.port), laser.port))
        terminal = Terminal("run", path, "-o", run_file)
        try:
            terminal.expect("00001_depth_sweep complete", timeout=120)
            terminal.hang_up()
            assert exit_code(terminal) == 130
        finally:
            terminal.close()
        with stage.lock:
            assert stage.commands[-2:] == ["stop", "get pos"] and not stage.moving
        with laser.lock:
            assert laser.commands[-2:] == ["c", "p"] and not laser.laser_on
        assert status(run_file) == ("aborted", "terminated by SIGHUP (the terminal closed)")
        assert len(complete_steps(run_file)) in (2, 3)
        # the same stage; the laser on a fresh pseudo-terminal, as a pty once set to 7E1 refuses those settings
        # when opened again (termios EINVAL; a real adapter does not)
        with DimetixEmulator(distance_mm=1234.5) as laser_again:
            output = resume_on_a_terminal(run_file, "--port", f"laser={laser_again.port}")
            assert laser_again.commands[-2:] == ["c", "p"]
        with stage.lock:
            assert stage.commands.count("home") == 2  # the resumed run drove the same stage
    assert "run complete" in output and "Traceback" not in output
    assert status(run_file)[0] == "complete" and len(complete_steps(run_file)) == 4


@pytest.mark.slow
def test_signals_during_the_safe_state_do_not_cut_it_short(tmp_path: Path) -> None:
    """Ctrl-C twice while the laser measures (the second stops the wait at once), then Ctrl-C, SIGTERM and
    SIGHUP while the laser is being switched off: it is switched off and the run file is marked aborted."""
    path, run_file = tmp_path / "campaign.toml", tmp_path / "run.h5"
    reply_delay_s = 2.8  # below the laser adapter's 3 s reply timeout: slow, not failed
    with zaber() as stage, DimetixEmulator(distance_mm=1234.5) as laser:
        path.write_text(campaign(stage_section(stage.port), laser.port).replace("frames = 2", "frames = 1") + CHART)
        terminal = Terminal("run", path, "-o", run_file)
        try:
            terminal.expect(PROMPT, timeout=120)
            with laser.lock:
                before = len(laser.commands)
                laser.delay_replies(reply_delay_s, count=3)  # the reading, then the safe state's stop and laser off
            terminal.type("\r")
            wait_until(lambda: "g" in laser.commands[before:], 60, "the laser reading")
            reading_sent = time.monotonic()
            while "c" not in laser.commands[before:]:  # Ctrl-C until the run reacts, as an operator would
                assert time.monotonic() - reading_sent < reply_delay_s, "Ctrl-C did not stop the wait for the laser"
                terminal.type("\x03")
                deadline = time.monotonic() + 0.3
                while "c" not in laser.commands[before:] and time.monotonic() < deadline:
                    time.sleep(0.005)
            # the safe state is under way: the laser's stop waits for its delayed reply
            terminal.type("\x03")
            os.kill(terminal.process.pid, signal.SIGTERM)
            os.kill(terminal.process.pid, signal.SIGHUP)
            assert terminal.wait(timeout=60) == 130, terminal.output
        finally:
            terminal.close()
        with laser.lock:
            assert laser.commands[before:] == ["g", "c", "p"] and not laser.laser_on
        with stage.lock:
            assert stage.commands[-2:] == ["stop", "get pos"] and not stage.moving
    assert "Traceback" not in terminal.output
    assert status(run_file) == ("aborted", "interrupted by the operator (Ctrl-C)")


@pytest.mark.slow
def test_closing_the_terminal_at_an_operator_prompt_stops_at_once(tmp_path: Path, write_campaign, small_model) -> None:
    """A run waiting for Enter when the SSH session drops: it stops at once, no output needed."""
    out = tmp_path / "run.h5"
    terminal = Terminal("run", write_campaign(procedures=CHART_CAMPAIGN), "--sim", "--interactive", "--model",
                        small_model(), "-o", out)
    try:
        terminal.expect(PROMPT)
        terminal.hang_up()
        assert exit_code(terminal) == 130
    finally:
        terminal.close()
    assert status(out) == ("aborted", "terminated by SIGHUP (the terminal closed)")
    assert complete_steps(out) == ["00000_offset_calibration"]
    resumed = run_labctl("resume", out)
    assert resumed.returncode == 0, resumed.stderr
    assert complete_steps(out) == ["00000_offset_calibration", "00001_slanted_edge", "00002_slanted_edge"]
