"""Sessions back to back on one emulated Grbl controller: whatever the previous session left
(a feed hold, an alarm, a Ctrl-C in the middle of a move), the next one connects and moves."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import h5py
import pytest
import serial

from labctl.cli import main
from labctl.run.operator import Operator, unlock_confirmation
from sim.emulators import GrblEmulator
from tests.labctl.run.test_real_lab import campaign


@pytest.fixture
def grbl() -> Iterator[GrblEmulator]:
    with GrblEmulator(homing_enabled=False, max_travel_mm=400.0, start_mm=0.0) as emulator:
        yield emulator


@dataclass
class Session:
    returncode: int
    stdout: str
    stderr: str


@pytest.fixture
def move(capsys: pytest.CaptureFixture[str]) -> Callable[..., Session]:
    """``labctl device stage --protocol grbl --port PORT --move-mm TARGET``, in-process (stdin is no terminal)."""

    def session(port: str, target: str, *extra: str) -> Session:
        with pytest.raises(SystemExit) as done:
            main(["device", "stage", "--protocol", "grbl", "--port", port, "--move-mm", target, *extra])
        out, err = capsys.readouterr()
        return Session(int(done.value.code), out, err)

    return session


#: seconds the emulator may take to act on bytes written to it (generous: its thread may wait for a loaded CPU)
ACTS_WITHIN_S = 30.0


def raw(port: str, data: bytes, grbl: GrblEmulator | None = None, state: str | None = None) -> None:
    """What an earlier session (or a terminal) sent, without waiting for answers; with ``state``, until the
    emulator's state (its ``?`` report, ``Hold`` matching ``Hold:0`` and ``Hold:1``) is that."""
    with serial.Serial(port, 115200, timeout=0.1) as link:
        link.write(data)
        link.flush()
        if grbl is not None and state is not None:
            deadline = time.monotonic() + ACTS_WITHIN_S
            while not grbl.status_state.startswith(state):
                assert time.monotonic() < deadline, f"after {data!r}: {grbl.status_state}, not {state}"
                time.sleep(0.01)


def test_two_sessions_back_to_back(grbl: GrblEmulator, move: Callable[..., Session]) -> None:
    for target in ("12.5", "12.5", "30"):
        result = move(grbl.port, target)
        assert result.returncode == 0, result.stderr
        assert result.stdout.strip() == f"{float(target):.4f} mm" and grbl.status_state == "Idle"


def test_a_session_after_a_feed_hold(grbl: GrblEmulator, move: Callable[..., Session]) -> None:
    raw(grbl.port, b"!", grbl, "Hold:0")  # the former end-of-session stop: Hold:0, where no line is answered
    result = move(grbl.port, "12.5")
    assert result.returncode == 0, result.stderr
    assert grbl.position_mm == pytest.approx(12.5) and grbl.status_state == "Idle"


def test_a_session_after_a_held_program_does_not_resume_it(grbl: GrblEmulator, move: Callable[..., Session]) -> None:
    raw(grbl.port, b"G1X300F600\n", grbl, "Run")
    raw(grbl.port, b"!", grbl, "Hold")
    result = move(grbl.port, "12.5")
    assert result.returncode == 0, result.stderr
    time.sleep(0.2)  # a resumed G1 would move on meanwhile (on a busy machine this checks less, never fails)
    assert grbl.position_mm == pytest.approx(12.5) and grbl.status_state == "Idle"  # the G1 was flushed


def test_a_session_after_an_alarm(grbl: GrblEmulator, move: Callable[..., Session]) -> None:
    raw(grbl.port, b"$J=G53G90G21X300F600\n", grbl, "Jog")  # 30 s: still jogging when the reset comes
    raw(grbl.port, b"\x18", grbl, "Alarm")  # reset while jogging: ALARM:3
    refused = move(grbl.port, "12.5")  # no terminal to ask: the alarm stays
    assert refused.returncode == 1
    assert "no terminal to ask" in refused.stderr and "stays locked" in refused.stderr
    assert "nothing moved" in refused.stderr and "Traceback" not in refused.stderr
    assert grbl.status_state == "Alarm"
    result = move(grbl.port, "12.5", "--unlock-alarm")
    assert result.returncode == 0, result.stderr
    assert grbl.position_mm == pytest.approx(12.5)
    again = move(grbl.port, "20")
    assert again.returncode == 0, again.stderr


def test_a_session_after_a_hard_limit(grbl: GrblEmulator, move: Callable[..., Session]) -> None:
    grbl.trip_hard_limit_at(40.0)
    first = move(grbl.port, "100")
    assert first.returncode == 1 and "ALARM:1: Hard limit has been triggered" in first.stderr
    result = move(grbl.port, "12.5", "--unlock-alarm")  # Grbl answered nothing until a reset
    assert result.returncode == 0, result.stderr
    assert grbl.position_mm == pytest.approx(12.5)


def default_sigint() -> None:
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def interrupt_when_jogging(command: list[str], grbl: GrblEmulator) -> tuple[int, str]:
    """Start ``labctl COMMAND...`` in a subprocess, send SIGINT (Ctrl-C) once the stage jogs;
    return its exit code and stderr."""
    process = subprocess.Popen(
        [sys.executable, "-m", "labctl", *command], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        preexec_fn=default_sigint,  # pytest started in the background ignores SIGINT, and so would its children
    )
    deadline = time.monotonic() + 60
    while grbl.status_state != "Jog":
        assert time.monotonic() < deadline and process.poll() is None, process.communicate()
        time.sleep(0.02)
    os.kill(process.pid, signal.SIGINT)
    _, err = process.communicate(timeout=60)
    return process.returncode, err


def test_a_session_after_ctrl_c_during_a_move(grbl: GrblEmulator, move: Callable[..., Session]) -> None:
    code, err = interrupt_when_jogging(
        ["device", "stage", "--protocol", "grbl", "--port", grbl.port, "--move-mm", "390"], grbl)  # 23 s
    assert code == 130 and "Traceback" not in err, err
    assert grbl.status_state == "Idle"  # jog cancelled, no hold left behind
    stopped = grbl.position_mm
    time.sleep(0.1)
    assert grbl.position_mm == stopped < 390.0
    result = move(grbl.port, "12.5")
    assert result.returncode == 0, result.stderr


@pytest.mark.slow
def test_a_campaign_after_a_campaign_ended_by_ctrl_c(tmp_path: Path, labctl) -> None:
    with GrblEmulator(max_travel_mm=400.0, max_rate_mm_min=120_000.0, start_mm=150.0) as grbl:
        stage = f'protocol = "grbl"\nport = "{grbl.port}"'
        slow, fast = tmp_path / "slow.toml", tmp_path / "fast.toml"
        slow.write_text(campaign(stage, None, speed_mm_s=20))  # 10 s per 200 mm step
        fast.write_text(campaign(stage, None))
        code, err = interrupt_when_jogging(["run", str(slow), "-o", str(tmp_path / "cut.h5")], grbl)
        assert code == 130, err
        assert grbl.status_state == "Idle"
        result = labctl("run", fast, "-o", tmp_path / "after.h5")
        assert result.returncode == 0, result.stderr
    with h5py.File(tmp_path / "cut.h5", "r") as f:
        assert f.attrs["status"] == "aborted"
    with h5py.File(tmp_path / "after.h5", "r") as f:
        assert f.attrs["status"] == "complete" and len(f["steps"]) == 3


@pytest.mark.slow
def test_campaigns_after_a_feed_hold_and_after_a_hard_limit(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    def run(name: str) -> tuple[int, str]:
        with pytest.raises(SystemExit) as done:
            main(["run", str(path), "-o", str(tmp_path / name), "--quiet"])
        return int(done.value.code), capsys.readouterr().err

    with GrblEmulator(max_travel_mm=400.0, max_rate_mm_min=120_000.0, start_mm=150.0) as grbl:
        path = tmp_path / "campaign.toml"
        path.write_text(campaign(f'protocol = "grbl"\nport = "{grbl.port}"', None))
        with serial.Serial(grbl.port, 115200, timeout=ACTS_WITHIN_S) as link:
            link.write(b"!?")  # a hold left behind (every line would wait unanswered), then a status request
            report = link.read_until(b">").rsplit(b"<", 1)[-1]
        assert report.startswith(b"Alarm|"), report  # answered after the hold: the power-up homing lock ignored it
        raw(grbl.port, b"$H\n", grbl, "Idle")
        raw(grbl.port, b"!", grbl, "Hold:0")
        code, err = run("after_hold.h5")
        assert (code, err) == (0, ""), err
        assert grbl.status_state == "Idle"
        grbl.trip_hard_limit_at(300.0)  # the third sweep step (400 mm) runs into a limit switch
        code, err = run("hard_limit.h5")
        assert code == 1 and "ALARM:1: Hard limit has been triggered" in err, err
        code, err = run("after_limit.h5")  # silent Grbl reset, then homed (home_on_connect)
        assert (code, err) == (0, ""), err
    for name, status in [("after_hold.h5", "complete"), ("hard_limit.h5", "aborted"), ("after_limit.h5", "complete")]:
        with h5py.File(tmp_path / name, "r") as f:
            assert f.attrs["status"] == status


def test_a_run_asks_the_operator_before_unlocking() -> None:
    reports: list[str] = []
    confirm = unlock_confirmation(Operator(automatic=True, report=reports.append))
    assert confirm("ALARM:3: Reset while in motion") is False  # a simulated operator keeps it locked
    assert reports == ["operator (simulated): ALARM:3: Reset while in motion -- keep locked"]
    unattended = unlock_confirmation(Operator(automatic=False, report=reports.append))
    assert unattended("ALARM:3") is False  # stdin is no terminal under pytest
    assert "no terminal to ask" in reports[-1] and "stays locked" in reports[-1]
