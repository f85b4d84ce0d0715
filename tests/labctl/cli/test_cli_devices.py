"""``labctl device laser|stage|camera`` and ``labctl devices`` against real parts: the serial
emulators on pseudo-terminals, the real RealSense recording, viky.cti, the installed SDKs."""

from __future__ import annotations

import importlib.util
import json
import math
from collections.abc import Iterator
from pathlib import Path

import genicam
import h5py
import numpy as np
import pyrealsense2 as rs
import pytest
from pypylon import pylon

from drivers.camera.blaze import DEVICE_CLASS, pylon_transport_layers
from labctl.cli import main
from sim.emulators import DimetixEmulator, GrblEmulator, ZaberEmulator
from tests.shared_data import shared_data

BAG = shared_data("realsense_d4xx_640x480.bag")
F, CX, CY = 390.431, 331.388, 242.187  # depth intrinsics of the recording (data/README.md)


@pytest.fixture
def labctl_main(capsys: pytest.CaptureFixture[str]):
    """The real entry point in-process: returns (exit code, stdout, stderr)."""

    def run(*args: object) -> tuple[int, str, str]:
        with pytest.raises(SystemExit) as done:
            main([str(a) for a in args])
        out, err = capsys.readouterr()
        return int(done.value.code), out, err

    return run


@pytest.fixture
def dimetix() -> Iterator[DimetixEmulator]:
    with DimetixEmulator(distance_mm=2345.6) as emulator:
        yield emulator


# ------------------------------------------------------------------ laser and stage
def test_laser_readings_as_json(labctl_main, dimetix: DimetixEmulator) -> None:
    code, out, err = labctl_main("device", "laser", "--port", dimetix.port, "--count", "3", "--json")
    assert code == 0, err
    assert json.loads(out) == {"distances_mm": [2345.6, 2345.6, 2345.6]}
    assert not dimetix.laser_on  # left off


def test_laser_failure_exits_1_naming_the_port(labctl_main, dimetix: DimetixEmulator) -> None:
    dimetix.inject_error(252)
    code, out, err = labctl_main("device", "laser", "--port", dimetix.port)
    assert code == 1 and out == ""
    assert f"Dimetix laser on {dimetix.port}" in err and "E252: temperature too high" in err
    assert "Traceback" not in err


def test_zaber_stage_home_and_move(labctl_main) -> None:
    with ZaberEmulator(mm_per_microstep=0.000125, travel_mm=300.0, speed_mm_s=2000.0) as zaber:
        code, out, err = labctl_main("device", "stage", "--port", zaber.port, "--protocol", "zaber", "--home",
                                     "--move-mm", "42.5", "--mm-per-microstep", "0.000125", "--json")
        assert code == 0, err
        assert json.loads(out)["position_mm"] == pytest.approx(42.5)
        assert zaber.position_mm == pytest.approx(42.5)


def test_grbl_stage_home_and_move(labctl_main) -> None:
    with GrblEmulator(max_travel_mm=300.0, max_rate_mm_min=120_000.0) as grbl:
        code, out, err = labctl_main("device", "stage", "--port", grbl.port, "--protocol", "grbl", "--home",
                                     "--move-mm", "12", "--json")
        assert code == 0, err
        assert json.loads(out) == {"position_mm": pytest.approx(12.0)}
        code, out, err = labctl_main("device", "stage", "--port", grbl.port, "--protocol", "grbl", "--move-mm", "-5")
        assert code == 2 and "'--move-mm': '-5' is below 0: positions count from home" in err  # before connecting
        assert grbl.position_mm == pytest.approx(12.0)


def test_stage_bad_arguments_exit_2(labctl_main) -> None:
    code, _, err = labctl_main("device", "stage", "--port", "/dev/null", "--protocol", "zaber", "--home")
    assert code == 2 and "--mm-per-microstep is required for a Zaber stage" in err
    code, _, err = labctl_main("device", "stage", "--port", "/dev/null", "--protocol", "thorlabs")
    assert code == 2 and "'thorlabs' is not one of 'zaber', 'grbl'" in err


# ------------------------------------------------------------------ camera
def assert_valid_run_file(path: Path, frames: int, height: int, width: int) -> h5py.Group:
    """The docs/runfile.md layout of a one-step run file."""
    f = h5py.File(path, "r")
    assert f.attrs["format"] == "labctl-run" and f.attrs["format_version"] == 1
    assert f.attrs["status"] == "complete" and not f.attrs["simulated"]
    assert {"labctl_version", "created", "campaign_toml"} <= set(f.attrs)
    assert {"backend", "model", "serial", "firmware", "settings_json"} <= set(f["devices/camera"].attrs)
    camera = f["camera"].attrs
    assert (camera["width"], camera["height"]) == (width, height)
    assert {"fov_deg", "pixel_pitch_um", "frame_rate_hz", "wavelength_nm"} <= set(camera)
    assert list(f["steps"]) == ["00000_capture"] and "sim" not in f
    step = f["steps/00000_capture"]
    assert step.attrs["complete"] and step.attrs["procedure"] == "capture" and step.attrs["index"] == 0
    for name in ("x", "y", "z", "intensity", "confidence"):
        assert step[name].shape == (frames, height, width)
        assert step[name].dtype == (np.dtype(camera["confidence_dtype"]) if name == "confidence" else np.float32)
    assert step["timestamp"].shape == (frames,) and step["timestamp"].dtype == np.float64
    return step


def recorded_depth_mm() -> list[np.ndarray]:
    """The recording's depth frames read directly through librealsense (z16, 1 mm units). Real-time playback
    is switched off on the device the config resolves, before the pipeline starts: switched off after the start,
    a loaded machine had already dropped the first frame."""
    config = rs.config()
    config.enable_device_from_file(str(BAG), False)
    config.enable_stream(rs.stream.depth)
    pipeline = rs.pipeline()
    config.resolve(rs.pipeline_wrapper(pipeline)).get_device().as_playback().set_real_time(False)
    pipeline.start(config)
    frames = []
    while (got := pipeline.try_wait_for_frames(500))[0]:
        frames.append(np.asanyarray(got[1].get_depth_frame().get_data()).astype(np.float32))
    pipeline.stop()
    return frames


def test_camera_stack_from_the_realsense_recording(labctl_main, tmp_path: Path) -> None:
    """x, y, z of the one-step run file are the recording's depth back-projected through its
    intrinsics (pinhole), within 0.5 mm; the centre pixel of the second frame reads 1540 mm."""
    output = tmp_path / "bag.h5"
    code, out, err = labctl_main("device", "camera", "--backend", "realsense", "--playback", BAG,
                                 "--frames", "2", "-o", output, "--json")
    assert code == 0, err
    summary = json.loads(out)
    assert summary["run_file"] == str(output) and summary["frames"] == 2 and summary["step_id"] == "00000_capture"
    step = assert_valid_run_file(output, 2, 480, 640)
    x, y, z = step["x"][()], step["y"][()], step["z"][()]
    depth = recorded_depth_mm()
    assert [d[240, 320] for d in depth] == [1536.0, 1540.0]
    assert z[1, 240, 320] == pytest.approx(1540.0, abs=0.5)
    assert x[1, 240, 320] == pytest.approx((320 - CX) / F * 1540.0, abs=0.5)
    assert y[1, 240, 320] == pytest.approx((240 - CY) / F * 1540.0, abs=0.5)
    u, v = np.meshgrid(np.arange(640), np.arange(480))
    for k, recorded in enumerate(depth):
        valid = recorded > 0
        assert np.array_equal(np.isfinite(z[k]), valid)
        assert np.abs(z[k][valid] - recorded[valid]).max() < 0.5
        assert np.abs(x[k][valid] - ((u - CX) / F * recorded)[valid]).max() < 0.5
        assert np.abs(y[k][valid] - ((v - CY) / F * recorded)[valid]).max() < 0.5
    assert math.isclose(summary["valid_fraction"], float(np.mean([np.isfinite(zk).mean() for zk in z])), abs_tol=1e-6)
    device = step.file["devices/camera"].attrs
    assert (device["backend"], device["model"], device["serial"]) == ("realsense", "Intel RealSense D435", "728612070259")


def test_camera_stack_longer_than_the_recording(labctl_main, tmp_path: Path) -> None:
    output = tmp_path / "long.h5"
    code, out, err = labctl_main("device", "camera", "--backend", "realsense", "--playback", BAG,
                                 "--frames", "5", "-o", output)
    assert code == 1 and "the recording ended after 2 frame(s)" in err
    assert not output.exists()


def test_camera_errors(labctl_main, tmp_path: Path) -> None:
    code, _, err = labctl_main("device", "camera", "--backend", "blaze", "-o", tmp_path / "b.h5")
    assert code == 1 and "Basler blaze" in err and "Traceback" not in err
    code, _, err = labctl_main("device", "camera", "--backend", "realsense", "--playback", tmp_path / "none.bag",
                               "-o", tmp_path / "r.h5")
    assert code == 2 and "--playback file" in err and "does not exist" in err
    code, _, err = labctl_main("device", "camera", "--backend", "amt100", "--playback", BAG, "-o", tmp_path / "a.h5")
    assert code == 2 and "'amt100' cannot play recordings" in err
    code, _, err = labctl_main("device", "camera", "--backend", "flexx2", "-o", tmp_path / "f.h5")
    assert code == 1 and "roypy" in err
    assert list(tmp_path.iterdir()) == []


# ------------------------------------------------------------------ devices
def test_devices_lists_what_is_there(labctl_main, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("GENICAM_GENTL64_PATH", str(Path(genicam.__file__).parent))
    code, out, err = labctl_main("devices", "--json")
    assert code == 0, err
    sections = {s["name"]: s for s in json.loads(out)["sections"]}
    assert list(sections) == ["serial ports", "RealSense (pyrealsense2)", "GenTL (harvesters)", "pylon (pypylon)",
                              "pmd Royale (roypy)"]
    (viky,) = sections["GenTL (harvesters)"]["devices"]
    assert viky.startswith(str(Path(genicam.__file__).parent / "viky.cti")) and "Viky serial 2" in viky
    blaze_visible = DEVICE_CLASS in pylon_transport_layers(pylon)
    assert ("no blaze producer" in sections["pylon (pypylon)"]["note"]) != blaze_visible
    royale = sections["pmd Royale (roypy)"]
    assert royale["available"] == (importlib.util.find_spec("roypy") is not None)
    assert royale["available"] or "Royale SDK" in royale["note"]
    code, out, _ = labctl_main("devices")
    assert code == 0 and "GenTL (harvesters): " in out and "pmd Royale (roypy): " in out


def test_help_for_the_device_commands(labctl_main) -> None:
    for command in (["devices"], ["device"], ["device", "laser"], ["device", "stage"], ["device", "camera"]):
        code, out, _ = labctl_main(*command, "--help")
        assert code == 0 and "Usage: labctl" in out
