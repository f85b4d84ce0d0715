"""GenTL plumbing against a real producer: ``viky.cti`` from the genicam wheel, opened by harvesters.

Viky is a simulated GenTL device with SFNC 3D features: a ``ComponentSelector`` with
``Intensity`` (Mono8) and ``Range`` (``Coord3D_ABC32f_Planar``, delivered as the three
parts ``Coord3D_A32f``/``B32f``/``C32f``, A = column, B = row), ``Scan3d*`` and chunk
features. Buffer conversion is also checked on hand-made parts with known answers.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import genicam
import numpy as np
import pytest

from drivers.camera.gentl import (
    Component,
    GenApiNodes,
    GenTLCamera,
    GenTLProfile,
    Part,
    Scan3d,
    device_temperatures,
    frame_from_parts,
    producers_on_path,
    read_scan3d,
    split_parts,
)
from drivers.errors import DeviceError, DroppedFrame, MissingSDKError
from drivers.protocols import DepthCamera

VIKY = Path(genicam.__file__).parent / "viky.cti"
RANGE = Component("range", "Range", "Coord3D_ABC32f_Planar", ("Coord3D_ABC32f_Planar",))
INTENSITY = Component("intensity", "Intensity", "Mono8", ("Mono8",))


def viky_settings(nodes: Any, exposure_us: float | None, settings: dict[str, Any]) -> dict[str, Any]:
    """Viky has no exposure; its ball size stands in for a backend setting."""
    if "ball_size" in settings:
        nodes.set("BouncingBallSize", int(settings["ball_size"]))
    return {"ball_size": nodes.get("BouncingBallSize")}


def viky_profile(*components: Component) -> GenTLProfile:
    return GenTLProfile(
        backend="viky", label="Viky", producer_hint="it ships with the genicam wheel", model_pattern="Viky",
        components=components or (RANGE, INTENSITY), apply_settings=viky_settings, fov_deg=(60.0, 45.0),
        frame_rate_hz=20.0, pixel_pitch_um=float("nan"), wavelength_nm=float("nan"), settings_keys=("ball_size",),
    )


@pytest.fixture
def viky() -> Iterator[GenTLCamera]:
    camera = GenTLCamera(viky_profile(), producers=[VIKY], serial="1", timeout_s=2.0)
    camera.connect()
    yield camera
    camera.close()


def test_open_configure_acquire_convert(viky: GenTLCamera) -> None:
    assert isinstance(viky, DepthCamera)
    identity = viky.identity()
    assert (identity.backend, identity.model, identity.serial) == ("viky", "Machine Vision Games Ltd. Viky", "1")
    viky.configure(None, {"ball_size": 30, "nodes": {"Width": 160, "Height": 120}})
    assert viky.settings() == {"ball_size": 30, "nodes": {"Width": 160, "Height": 120}}
    info = viky.info()
    assert (info.width, info.height, info.frame_rate_hz, info.confidence_dtype) == (160, 120, 20.0, "float32")
    frames = list(viky.capture(3))
    assert len(frames) == 3 and frames[0].timestamp < frames[2].timestamp
    for frame in frames:
        assert frame.z.shape == (120, 160) and frame.x.dtype == np.float32
        valid = np.isfinite(frame.z)
        assert 0 < valid.sum() < valid.size  # the ball is in range, the background (C = 0) is not
        rows, columns = np.nonzero(valid)
        assert np.array_equal(frame.x[valid], columns.astype(np.float32))  # A = column index
        assert np.array_equal(frame.y[valid], rows.astype(np.float32))  # B = row index
        assert np.isnan(frame.x[~valid]).all() and np.isnan(frame.y[~valid]).all()
        assert frame.intensity.dtype == np.float32 and frame.intensity.max() == 255.0
        assert np.array_equal(frame.confidence, valid.astype(np.float32))


def test_a_camera_that_delivers_nothing_within_the_timeout_is_a_dropped_frame_and_acquisition_stops() -> None:
    """Viky at its slowest (1 frame/s) against a 0.25 s buffer timeout: the producer's own TimeoutException
    becomes a DroppedFrame naming the camera and the frame (what the runner retries and then aborts on), the
    acquisition is stopped, and the camera delivers again once it runs at its rate."""
    camera = GenTLCamera(viky_profile(), producers=[VIKY], serial="1", timeout_s=0.25)
    camera.connect()
    try:
        camera.configure(None, {"nodes": {"AcquisitionFrameRate": 1.0}})
        with pytest.raises(DroppedFrame, match=r"Viky.*no buffer for frame 4 within 0.25 s"):
            list(camera.capture(2, first_index=4))
        camera.configure(None, {"nodes": {"AcquisitionFrameRate": 20.0}})
        camera.timeout_s = 2.0
        frames = list(camera.capture(2))
        assert len(frames) == 2 and frames[1].timestamp > frames[0].timestamp
    finally:
        camera.close()


def test_scan3d_features_and_their_chunk_values(viky: GenTLCamera) -> None:
    nodes = GenApiNodes(viky._acquirer.remote_device.node_map, viky.name)
    nodes.set("ComponentSelector", "Range")
    assert read_scan3d(nodes) == Scan3d()  # scale 1, offset 0, mm, no invalid value, no intrinsics
    assert nodes.get("ChunkModeActive") is True
    viky._acquirer.start()
    try:
        with viky._acquirer.fetch(timeout=2.0):  # a fetched buffer fills the chunk features
            chunk = read_scan3d(nodes, "Chunk")
    finally:
        viky.safe_state()
    assert (chunk.scale, chunk.offset, chunk.unit) == ((1.0, 1.0, 1.0), (0.0, 0.0, 0.0), "Millimeter")


def test_parts_nobody_asked_for_are_ignored() -> None:
    """Viky always sends its intensity image; a range-only profile ignores that part."""
    camera = GenTLCamera(viky_profile(RANGE), producers=[VIKY], serial="2")
    camera.connect()
    try:
        frame = next(iter(camera.capture(1)))
        assert np.isnan(frame.intensity).all() and np.isfinite(frame.z).any()
    finally:
        camera.close()


def test_feature_errors_name_the_feature_and_value(viky: GenTLCamera) -> None:
    with pytest.raises(DeviceError, match="Viky 1: the camera has no feature 'ExposureTime'"):
        viky.configure(None, {"nodes": {"ExposureTime": 100.0}})
    with pytest.raises(DeviceError, match="cannot set 'Width' to 10: .*Min = 100"):
        viky.configure(None, {"nodes": {"Width": 10}})
    with pytest.raises(DeviceError, match=r"unknown setting\(s\) \['projector'\]"):
        viky.configure(None, {"projector": True})


def test_a_component_the_camera_lacks() -> None:
    confidence = Component("confidence", "Confidence", "Confidence16", ("Confidence16",))
    camera = GenTLCamera(viky_profile(RANGE, confidence), producers=[VIKY], serial="0")
    with pytest.raises(DeviceError, match="cannot set 'ComponentSelector' to 'Confidence'"):
        camera.connect()
    camera.close()


def test_choosing_the_device() -> None:
    with pytest.raises(DeviceError, match=r"no device with serial 7 among the GenTL devices \[.*Viky \(serial 0\)"):
        GenTLCamera(viky_profile(), producers=[VIKY], serial="7").connect()
    with pytest.raises(DeviceError, match="several devices match .*set the camera's serial"):
        GenTLCamera(viky_profile(), producers=[VIKY]).connect()


def test_missing_producers(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    with pytest.raises(MissingSDKError, match=r"\['/nowhere/x.cti'\] do not exist; it ships with the genicam wheel"):
        GenTLCamera(viky_profile(), producers=["/nowhere/x.cti"]).connect()
    monkeypatch.setenv("GENICAM_GENTL64_PATH", str(tmp_path))
    with pytest.raises(MissingSDKError, match=rf"no GenTL producer \(\.cti\) found in GENICAM_GENTL64_PATH='{tmp_path}'"):
        GenTLCamera(viky_profile()).connect()
    assert producers_on_path({"GENICAM_GENTL64_PATH": f"/nowhere:{VIKY.parent}"}) == [VIKY]


# ------------------------------------------------------------------ buffer conversion, known answers
def part(fmt: str, data: np.ndarray, width: int = 3, height: int = 2) -> Part:
    return Part(fmt, width, height, data.reshape(-1))


def test_interleaved_coordinates_with_scale_offset_and_invalid_value() -> None:
    points = np.arange(18, dtype=np.float32).reshape(2, 3, 3) + 1.0
    points[1, 2] = 0.0  # the invalid-data value
    arrays = split_parts([part("Coord3D_ABC32f", points)], [Component("range", "Range", None, ("Coord3D_ABC32f",))], "cam")
    frame = frame_from_parts(arrays, Scan3d(scale=(2, 2, 0.5), offset=(0, 0, 10), invalid_value=0.0), 1.5, "cam")
    assert frame.x[0, 1] == 2 * 4.0 and frame.y[0, 1] == 2 * 5.0 and frame.z[0, 1] == 0.5 * 6.0 + 10
    assert np.isnan([frame.x[1, 2], frame.y[1, 2], frame.z[1, 2]]).all()
    assert frame.timestamp == 1.5 and np.isnan(frame.intensity).all()


def test_planar_coordinates_in_metres() -> None:
    planes = np.stack([np.full((2, 3), 0.1), np.full((2, 3), -0.2), np.full((2, 3), 1.5)]).astype(np.float32)
    arrays = split_parts([part("Coord3D_ABC32f_Planar", planes)], [RANGE], "cam")
    frame = frame_from_parts(arrays, Scan3d(unit="Meter"), 0.0, "cam")
    assert (frame.x[0, 0], frame.y[0, 0], frame.z[0, 0]) == pytest.approx((100.0, -200.0, 1500.0))


def test_depth_only_is_back_projected_and_mono16_parts_keep_their_order() -> None:
    """AM-T100 style: Coord3D_C32f then intensity and confidence, both Mono16."""
    components = [
        Component("range", "TransmitRangeImage", None, ("Coord3D_C32f",), enable_node=True),
        Component("intensity", "TransmitIntensityImage", None, ("Mono16",), enable_node=True),
        Component("confidence", "TransmitConfidenceImage", None, ("Mono16",), enable_node=True),
    ]
    z = np.array([[1000, 2000, 0], [1500, 1500, 1500]], np.float32)
    parts = [part("Coord3D_C32f", z), part("Mono16", np.full(6, 700, np.uint16)), part("Mono16", np.full(6, 9, np.uint16))]
    arrays = split_parts(parts, components, "cam")
    with pytest.raises(DeviceError, match="depth only .* set the camera settings focal_length_px"):
        frame_from_parts(arrays, Scan3d(), 0.0, "cam")
    frame = frame_from_parts(arrays, Scan3d(focal_px=500.0, principal_px=(1.0, 0.5)), 0.0, "cam")
    assert frame.x[0, 1] == pytest.approx(0.0) and frame.x[1, 0] == pytest.approx(-1500 / 500)
    assert frame.y[0, 0] == pytest.approx(-0.5 * 1000 / 500) and frame.y[1, 2] == pytest.approx(0.5 * 1500 / 500)
    assert np.isnan(frame.z[0, 2]) and np.isnan(frame.x[0, 2])
    assert frame.intensity[0, 0] == 700.0 and frame.confidence.dtype == np.uint16 and frame.confidence[0, 0] == 9
    overridden = frame_from_parts(arrays, Scan3d(focal_px=500.0, principal_px=(1.0, 0.5)), 0.0, "cam", (1000.0, (0.0, 0.0)))
    assert overridden.x[1, 1] == pytest.approx(1500 / 1000)
    with pytest.raises(DroppedFrame, match="buffer lacks the confidence component"):
        split_parts(parts[:2], components, "cam")
    with pytest.raises(DroppedFrame, match="buffer lacks the range component"):
        split_parts(parts[1:], components, "cam")


class TemperatureNodes:
    """A node map with the SFNC temperature features only: ``DeviceTemperature`` reads the sensor the selector
    selects (``selector`` None: a camera without the selector)."""

    def __init__(self, sensors: dict[str, float], selector: bool = True, unreadable: tuple[str, ...] = ()) -> None:
        self.sensors, self.selector, self.unreadable = sensors, selector, unreadable
        self.selected = next(iter(sensors))

    def has(self, name: str) -> bool:
        return name == "DeviceTemperature" or (self.selector and name == "DeviceTemperatureSelector")

    def get(self, name: str) -> Any:
        if name == "DeviceTemperatureSelector":
            return self.selected
        if self.selected in self.unreadable:
            raise DeviceError("camera", "DeviceTemperature is not readable now")
        return self.sensors[self.selected]

    def set(self, name: str, value: Any) -> None:
        assert name == "DeviceTemperatureSelector" and value in self.sensors
        self.selected = value

    def entries(self, name: str) -> list[str]:
        return list(self.sensors) if name == "DeviceTemperatureSelector" else []


def test_device_temperatures_reads_every_sensor_the_selector_names() -> None:
    nodes = TemperatureNodes({"Sensor": 48.5, "Illumination": 55.25, "Mainboard": 39.0}, unreadable=("Mainboard",))
    assert device_temperatures(nodes) == {"Sensor": 48.5, "Illumination": 55.25}
    assert device_temperatures(TemperatureNodes({"Sensor": 41.0}, selector=False)) == {"device": 41.0}


def test_a_camera_without_the_temperature_feature_reports_none(viky: GenTLCamera) -> None:
    assert viky.temperatures_c() == {}
