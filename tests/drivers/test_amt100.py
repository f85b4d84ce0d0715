"""Schmersal AM-T100 backend: its producer is not available here, so the tests cover what is
reachable: the missing producer, a producer without an AM-T100, and its settings on a real
GenICam node map (viky's) that lacks the AM-T100's features. The depth-only (Coord3D_C32f)
conversion is tested in test_gentl.py."""

from __future__ import annotations

from pathlib import Path

import genicam
import pytest
from harvesters.core import Harvester

from drivers.camera.amt100 import amt100_camera, apply_settings
from drivers.camera.gentl import GenApiNodes
from drivers.errors import DeviceError, MissingSDKError

VIKY = Path(genicam.__file__).parent / "viky.cti"


def test_missing_producer_names_what_to_install(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    monkeypatch.setenv("GENICAM_GENTL64_PATH", str(tmp_path))
    with pytest.raises(MissingSDKError, match="Schmersal AM-T100: no GenTL producer .*install Schmersal's GenTL producer"):
        amt100_camera().connect()


def test_a_producer_without_an_amt100() -> None:
    with pytest.raises(DeviceError, match="no device whose model contains 'T100' among .*Viky"):
        amt100_camera(producers=[VIKY]).connect()


def test_settings_on_a_camera_without_the_amt100_features() -> None:
    harvester = Harvester()
    harvester.add_file(str(VIKY))
    harvester.update()
    acquirer = harvester.create(0)
    try:
        nodes = GenApiNodes(acquirer.remote_device.node_map, "Viky")
        with pytest.raises(DeviceError, match="Viky: the camera has no feature 'RangePreset'"):
            apply_settings(nodes, None, {"range_preset": "Near"})
        with pytest.raises(DeviceError, match="the camera has no feature 'ExposureTime'"):
            apply_settings(nodes, 500.0, {})
        assert apply_settings(nodes, None, {}) == {}
    finally:
        acquirer.destroy()
        harvester.reset()
