"""Basler blaze backend at the boundary of what is installed here: pypylon without Basler's blaze
GenTL producer (it must say that it cannot see a blaze), harvesters with other producers, and the
blaze settings on pylon's own camera emulator (``PYLON_CAMEMU``), which has no blaze features."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import genicam
import pytest
from pypylon import pylon

from drivers.camera.blaze import DEVICE_CLASS, blaze_camera, pylon_transport_layers
from drivers.errors import DeviceError, MissingSDKError

VIKY = Path(genicam.__file__).parent / "viky.cti"


@pytest.mark.skipif(DEVICE_CLASS in pylon_transport_layers(pylon), reason="the blaze producer is installed here")
def test_pypylon_without_the_blaze_producer_says_it_cannot_see_a_blaze() -> None:
    with pytest.raises(MissingSDKError) as caught:
        blaze_camera().connect()
    message = str(caught.value)
    assert "pypylon alone cannot see a blaze" in message
    assert "BaslerUsb" in message and "Supplementary Package for blaze" in message
    assert 'sdk = "harvesters"' in message


def test_harvesters_path_needs_the_producer(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    monkeypatch.setenv("GENICAM_GENTL64_PATH", str(tmp_path))
    with pytest.raises(MissingSDKError, match="Basler blaze: no GenTL producer .* GenTL producer for blaze"):
        blaze_camera(sdk="harvesters").connect()


def test_harvesters_path_with_only_other_cameras() -> None:
    with pytest.raises(DeviceError, match="no device whose model contains 'blaze' among .*Viky"):
        blaze_camera(sdk="harvesters", producers=[VIKY]).connect()


def test_sdk_choice() -> None:
    with pytest.raises(ValueError, match="sdk must be 'pypylon' or 'harvesters'"):
        blaze_camera(sdk="aravis")
    with pytest.raises(ValueError, match="producers apply to sdk='harvesters'"):
        blaze_camera(producers=[VIKY])


def test_blaze_settings_on_pylons_camera_emulator() -> None:
    """In a subprocess: pylon reads PYLON_CAMEMU when its transport layer factory starts."""
    script = textwrap.dedent("""
        import json
        from pypylon import pylon
        from drivers.camera.blaze import PylonNodes, apply_settings
        from drivers.errors import DeviceError
        camera = pylon.InstantCamera(pylon.TlFactory.GetInstance().CreateFirstDevice())
        camera.Open()
        nodes = PylonNodes(camera.GetNodeMap(), "emulated camera")
        result = {"applied": apply_settings(nodes, 250.0, {}), "entries": "Mono16" in nodes.entries("PixelFormat")}
        for settings in ({"mode": "ShortRange"}, {"filters": False}):
            try:
                apply_settings(nodes, None, settings)
            except DeviceError as exc:
                result.setdefault("errors", []).append(str(exc))
        camera.Close()
        print(json.dumps(result))
    """)
    env = {**os.environ, "PYLON_CAMEMU": "1", "PYTHONPATH": str(Path(__file__).resolve().parents[2])}
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, env=env, timeout=60)
    assert done.returncode == 0, done.stderr
    result = json.loads(done.stdout)
    assert result["applied"]["exposure_us"] == 250.0 and result["entries"]
    assert result["errors"] == [
        "emulated camera: the camera has no feature 'OperatingMode'",
        "emulated camera: the camera has no feature 'FilterSpatial'",
    ]
