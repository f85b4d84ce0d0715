"""Campaigns on real adapters: the serial devices on their pty emulators (not the simulated
fakes) and the camera playing the real RealSense recording, through ``labctl run`` without --sim."""

from __future__ import annotations

import json
import textwrap
from collections.abc import Iterator
from pathlib import Path

import h5py
import pytest

from drivers.camera.realsense import RealSenseCamera
from drivers.laser import DimetixLaser
from drivers.robot import UR5eRobot
from drivers.stage import GrblStage, ZaberStage
from labctl.cli import main
from labctl.errors import InputError
from labctl.run.config import parse_campaign
from labctl.run.lab import build_real_lab
from sim.emulators import DimetixEmulator, GrblEmulator, ZaberEmulator
from tests.shared_data import shared_data

BAG = shared_data("realsense_d4xx_640x480.bag")
STEP = 0.000125  # Zaber mm per microstep


def lab_header(name: str, stage: str, *, backend: str = "realsense", playback: Path | str = BAG,
               speed_mm_s: float = 1000, home_on_connect: bool = True) -> str:
    """``[campaign]``, the camera playing ``playback`` and the stage (``stage``: its protocol and port lines) with
    400 mm of travel, the wall 1000 mm away at its zero."""
    return textwrap.dedent(f"""
        [campaign]
        name = "{name}"

        [devices.camera]
        backend = "{backend}"
        playback = "{playback}"

        [devices.stage]
        {stage}
        travel_mm = [0, 400]
        speed_mm_s = {speed_mm_s}
        settle_s = 0
        distance_at_zero_mm = 1000
        home_on_connect = {str(home_on_connect).lower()}
    """)


def campaign(stage: str, laser_port: str | None, extra: str = "", speed_mm_s: float = 1000) -> str:
    """Offset calibration at 1200 mm and a sweep 1000..1400 mm, 2 frames each (the recording holds 2);
    without ``laser_port`` the sweep alone."""
    laser = f"""
        [devices.laser]
        port = "{laser_port}"
        readings = 2
        {extra}

        [[procedure]]
        kind = "offset_calibration"
        distance_mm = 1200
        frames = 2
    """ if laser_port else ""
    return lab_header("emulated-lab", stage, speed_mm_s=speed_mm_s) + textwrap.dedent(f"""
        {laser}
        [[procedure]]
        kind = "depth_sweep"
        start_mm = 1000
        stop_mm = 1400
        step_mm = 200
        frames = 2
    """)


@pytest.fixture
def dimetix() -> Iterator[DimetixEmulator]:
    with DimetixEmulator(distance_mm=1234.5) as emulator:
        yield emulator


@pytest.mark.slow
@pytest.mark.parametrize("protocol", ["zaber", "grbl"])
def test_campaign_on_the_emulated_serial_devices_completes(
    protocol: str, dimetix: DimetixEmulator, tmp_path: Path, labctl
) -> None:
    emulator = (
        ZaberEmulator(mm_per_microstep=STEP, travel_mm=400.0, speed_mm_s=2000.0, start_mm=150.0)
        if protocol == "zaber"
        else GrblEmulator(max_travel_mm=400.0, max_rate_mm_min=120_000.0, start_mm=150.0)
    )
    with emulator:
        stage = f'protocol = "{protocol}"\nport = "{emulator.port}"' + (
            f"\nmm_per_microstep = {STEP}" if protocol == "zaber" else ""
        )
        path = tmp_path / "campaign.toml"
        path.write_text(campaign(stage, dimetix.port))
        run_file = tmp_path / "run.h5"
        result = labctl("run", path, "-o", run_file)
        assert result.returncode == 0, result.stderr
        assert "run complete" in result.stderr
        assert emulator.position_mm == pytest.approx(400.0, abs=1e-3)  # the last sweep position
    assert not dimetix.laser_on  # safe state at the end of the run
    with h5py.File(run_file, "r") as f:
        assert f.attrs["status"] == "complete" and not f.attrs["simulated"] and "sim" not in f
        assert f["devices/stage"].attrs["backend"] == protocol
        assert f["devices/laser"].attrs["backend"] == "dimetix" and f["devices/laser"].attrs["serial"] == "12345678"
        assert f["devices/camera"].attrs["model"] == "Intel RealSense D435"
        assert json.loads(f["devices/camera"].attrs["settings_json"])["playback"] == str(BAG)
        steps = f["steps"]
        assert list(steps) == ["00000_offset_calibration", "00001_depth_sweep", "00002_depth_sweep", "00003_depth_sweep"]
        for step_id, position in zip(steps, [200.0, 0.0, 200.0, 400.0]):
            attrs = steps[step_id].attrs
            assert attrs["complete"] and attrs["stage_position_mm"] == position
            assert list(attrs["laser_readings_mm"]) == [1234.5, 1234.5] and attrs["reference_source"] == "laser"
            assert steps[step_id]["z"].shape == (2, 480, 640)
        offset = steps["00000_offset_calibration"].attrs["camera_laser_offset_mm"]
        assert 1400.0 < offset + 1234.5 < 1700.0  # the recording's wall, about 1.5 m away
        assert steps["00002_depth_sweep"].attrs["reference_distance_mm"] == pytest.approx(1234.5 + offset)


def test_a_device_failure_aborts_with_the_stage_stopped(
    dimetix: DimetixEmulator, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    with ZaberEmulator(mm_per_microstep=STEP, travel_mm=400.0, speed_mm_s=2000.0) as zaber:
        path = tmp_path / "campaign.toml"
        path.write_text(campaign(f'protocol = "zaber"\nport = "{zaber.port}"\nmm_per_microstep = {STEP}', dimetix.port))
        dimetix.inject_error(252, count=100)  # temperature too high: not worth retrying
        with pytest.raises(SystemExit) as done:
            main(["run", str(path), "-o", str(tmp_path / "run.h5"), "--quiet"])
        err = capsys.readouterr().err
        assert done.value.code == 1 and "E252: temperature too high" in err and "Traceback" not in err
        with zaber.lock:
            assert zaber.commands[-2:] == ["stop", "get pos"]  # safe state: stop, wait until idle
        assert not zaber.moving
    assert not dimetix.laser_on
    with h5py.File(tmp_path / "run.h5", "r") as f:
        assert f.attrs["status"] == "aborted" and "E252" in f.attrs["status_reason"]


def test_real_lab_adapters_from_the_campaign() -> None:
    text = campaign(f'protocol = "zaber"\nport = "/dev/ttyUSB0"\nmm_per_microstep = {STEP}\naxis = 2', "/dev/ttyUSB1",
                    extra="device_id = 3")
    text += textwrap.dedent("""
        [devices.robot]
        host = "192.0.2.7"
        circle_center_mm = [400, 0, 300]
        zero_pose = [900, 0, 300, 1.2091996, -1.2091996, -1.2091996]
        joint_limits_deg = [[-360, 360], [-360, 360], [-360, 360], [-360, 360], [-360, 360], [-360, 360]]
    """)
    lab = build_real_lab(parse_campaign(text))
    assert isinstance(lab.camera, RealSenseCamera) and lab.camera.playback == BAG
    assert isinstance(lab.stage, ZaberStage) and lab.stage.axis == 2 and lab.stage.home_on_connect
    assert isinstance(lab.laser, DimetixLaser) and lab.laser.device_id == 3
    assert isinstance(lab.robot, UR5eRobot) and lab.robot.circle.zero_radius_mm == pytest.approx(500.0)
    assert not lab.simulated
    grbl = build_real_lab(parse_campaign(campaign('protocol = "grbl"\nport = "/dev/ttyACM0"\naxis = "Y"', "/dev/x")))
    assert isinstance(grbl.stage, GrblStage) and grbl.stage.axis == "Y" and grbl.stage.feed_mm_min == 60_000.0


@pytest.mark.parametrize(
    ("stage", "extra", "message"),
    [
        ('protocol = "zaber"', "", "devices.stage.port is required for a run on real hardware"),
        ('protocol = "zaber"\nport = "/dev/ttyUSB0"', "", "devices.stage.mm_per_microstep is required"),
        ('protocol = "grbl"\nport = "/dev/x"', '[devices.robot]\nhost = "192.0.2.7"', "devices.robot.circle_center_mm"),
    ],
)
def test_settings_a_real_run_needs(stage: str, extra: str, message: str) -> None:
    text = campaign(stage, "/dev/ttyUSB1") + extra
    with pytest.raises(InputError, match=message):
        build_real_lab(parse_campaign(text))
