"""A run on real adapters (serial devices on their pty emulators, the RealSense recording as camera),
stopped by Ctrl-C at an operator prompt, resumed with its serial devices on new ports
(``labctl resume --port``), and the validation of those overrides."""

from __future__ import annotations

import json
import textwrap
from pathlib import Path

import h5py
import pytest

from labctl.cli import main
from sim.emulators import DimetixEmulator, ZaberEmulator
from tests.conftest import run_labctl
from tests.labctl.run.test_real_lab import STEP, campaign
from tests.pty_terminal import Terminal

CHART = textwrap.dedent("""
    [[procedure]]
    kind = "slanted_edge"
    start_mm = 1200
    stop_mm = 1200
    frames = 1
""")


def zaber() -> ZaberEmulator:
    return ZaberEmulator(mm_per_microstep=STEP, travel_mm=400.0, speed_mm_s=2000.0, start_mm=150.0)


def stage_section(port: str) -> str:
    return f'protocol = "zaber"\nport = "{port}"\nmm_per_microstep = {STEP}'


@pytest.mark.slow
def test_ctrl_c_at_a_prompt_leaves_the_devices_safe_and_resume_moves_them_to_new_ports(tmp_path: Path) -> None:
    path, run_file = tmp_path / "campaign.toml", tmp_path / "run.h5"
    with zaber() as stage, DimetixEmulator(distance_mm=1234.5) as laser:
        path.write_text(campaign(stage_section(stage.port), laser.port).replace("frames = 2", "frames = 1") + CHART)
        old_ports = {"stage": stage.port, "laser": laser.port}
        terminal = Terminal("run", path, "-o", run_file)
        try:
            terminal.expect(r"OPERATOR: mount the slanted-edge chart.*\n.*Press Enter when done", timeout=120)
            terminal.type("\x03")
            assert terminal.wait() == 130, terminal.output
        finally:
            terminal.close()
        assert "devices are in their safe state" in terminal.output and "Traceback" not in terminal.output
        with stage.lock:
            assert stage.commands[-2:] == ["stop", "get pos"] and not stage.moving
        assert not laser.laser_on
        # the adapters come back on other ports; the old pseudo-terminals go away
        new_stage, new_laser = zaber().start(), DimetixEmulator(distance_mm=1500.0).start()
    with h5py.File(run_file, "r") as f:
        assert f.attrs["status"] == "aborted" and len(f["steps"]) == 4  # offset + three wall positions
    stage, laser = new_stage, new_laser
    try:
        assert not set(old_ports.values()) & {stage.port, laser.port}
        terminal = Terminal("resume", run_file, "--port", f"stage={stage.port}", "--port", f"laser={laser.port}")
        try:
            terminal.expect(f"stage port: {stage.port}")
            terminal.expect(r"OPERATOR: mount the slanted-edge chart.*\n.*Press Enter when done", timeout=120)
            terminal.type("\x03")
            assert terminal.wait() == 130, terminal.output
        finally:
            terminal.close()
        # a later resume keeps the recorded stage port; the laser moved once more
        third_laser = DimetixEmulator(distance_mm=1600.0).start()
        ports = {"stage": stage.port, "laser": laser.port, "third laser": third_laser.port}
        try:
            terminal = Terminal("resume", run_file, "--port", f"laser={third_laser.port}")
            try:
                terminal.expect(r"OPERATOR: mount the slanted-edge chart.*\n.*Press Enter when done", timeout=120)
                terminal.type("\r")
                terminal.expect(r"OPERATOR: cover the slanted-edge chart with the white sheet.*\n.*Press Enter when done")
                terminal.type("\r")
                assert terminal.wait() == 0, terminal.output
            finally:
                terminal.close()
            assert not third_laser.laser_on
        finally:
            third_laser.stop()
        with stage.lock:
            assert stage.commands.count("home") == 2  # both resumes drove the stage on its new port
    finally:
        stage.stop()
        laser.stop()
    with h5py.File(run_file, "r") as f:
        assert f.attrs["status"] == "complete" and len(f["steps"]) == 6
        assert list(f["steps/00004_slanted_edge"].attrs["laser_readings_mm"]) == [1600.0, 1600.0]  # the last laser
        history = json.loads(f.attrs["device_overrides_json"])
    assert [(e["role"], e["field"], e["value"], e["previous"]) for e in history] == [
        ("stage", "port", ports["stage"], old_ports["stage"]), ("laser", "port", ports["laser"], old_ports["laser"]),
        ("laser", "port", ports["third laser"], ports["laser"])]
    assert all(e["time"].endswith("+00:00") for e in history)


def aborted_run(tmp_path: Path, laser_port: str) -> Path:
    """A real-hardware run file stopped after connecting (no step done): written as labctl run leaves it."""
    from drivers.protocols import CameraInfo, DeviceIdentity
    from labctl.run.config import parse_campaign
    from labctl.run.store import RunWriter

    text = campaign(stage_section("/dev/ttyUSB0"), laser_port)
    camera = CameraInfo(width=4, height=3, fov_deg=(60.0, 45.0), pixel_pitch_um=3.0, frame_rate_hz=30.0,
                        wavelength_nm=850.0)
    writer = RunWriter.create(tmp_path / "run.h5", campaign_toml=text, simulated=False,
                              devices={"camera": (DeviceIdentity("realsense", "D435", "1", "1"), {})}, camera=camera,
                              steps=len(parse_campaign(text).steps()))
    writer.set_status("aborted", "test")
    writer.close()
    return tmp_path / "run.h5"


@pytest.mark.parametrize(
    ("options", "message"),
    [
        (["--port", "camera=/dev/video0"], "--port 'camera=/dev/video0': unknown role 'camera'; --port applies to stage, laser"),
        (["--port", "lazer=/dev/ttyUSB3"], "unknown role 'lazer'"),
        (["--port", "/dev/ttyUSB3"], "--port '/dev/ttyUSB3': expected ROLE=VALUE"),
        (["--host", "stage=10.0.0.1"], "unknown role 'stage'; --host applies to robot"),
        (["--port", "laser=/dev/a", "--port", "laser=/dev/b"], "--port: laser is given twice"),
        (["--host", "robot=192.0.2.9"], "has no [devices.robot]"),
    ],
)
def test_bad_overrides_are_refused_naming_the_role(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], options: list[str], message: str
) -> None:
    run_file = aborted_run(tmp_path, "/dev/ttyUSB1")
    with pytest.raises(SystemExit) as done:
        main(["resume", str(run_file), *options, "--quiet"])
    err = capsys.readouterr().err
    assert done.value.code == 2 and message in err and "Traceback" not in err
    with h5py.File(run_file, "r") as f:
        assert "device_overrides_json" not in f.attrs and f.attrs["status"] == "aborted"


def test_an_override_that_cannot_connect_names_the_port_and_is_not_recorded(tmp_path: Path) -> None:
    run_file = aborted_run(tmp_path, "/dev/ttyUSB1")
    gone = tmp_path / "no-such-port"
    result = run_labctl("resume", run_file, "--port", f"stage={gone}")
    assert result.returncode == 1 and str(gone) in result.stderr and "Traceback" not in result.stderr
    with h5py.File(run_file, "r") as f:
        assert "device_overrides_json" not in f.attrs and f.attrs["status"] == "aborted"


def test_overrides_do_not_apply_to_simulated_runs(tmp_path: Path, write_campaign, small_model) -> None:
    campaign_file, out = write_campaign(), tmp_path / "sim.h5"
    assert run_labctl("run", campaign_file, "--sim", "--model", small_model(), "-o", out, "--quiet").returncode == 0
    with h5py.File(out, "r+") as f:
        f.attrs["status"] = "aborted"
    result = run_labctl("resume", out, "--port", "laser=/dev/ttyUSB3")
    assert result.returncode == 2 and "is a simulated run: --port and --host apply to runs on real hardware" in result.stderr
