"""Basler blaze ToF cameras, via pypylon (default) or harvesters, both on Basler's blaze GenTL producer.

A blaze is reached only through Basler's GenTL producer for blaze (pylon's device class
``BaslerGTC/Basler/GenTL_Producer_for_Basler_blaze_101_cameras``), shipped with pylon's
"Supplementary Package for blaze" (older pylon) or the blaze component of the pylon
installer. pypylon's wheel brings pylon's USB and GigE transport layers only: without
that producer it cannot see a blaze, and :class:`PylonBlazeCamera` says so.

Features (Basler product documentation, blaze-101; pypylon's blaze sample): components
``Range`` (``Coord3D_ABC32f``, mm), ``Intensity`` (``Mono16``) and ``Confidence``
(``Confidence16``) via ``ComponentSelector``/``ComponentEnable``/``PixelFormat``;
``OperatingMode`` (e.g. ``ShortRange``/``LongRange``), ``ExposureTime`` (µs),
``FastMode``, ``FilterSpatial``, ``FilterTemporal``, ``OutlierRemoval``,
``ConfidenceThreshold``, ``DepthMin``/``DepthMax`` (mm). pypylon API: ``pylon.TlFactory``,
``pylon.InstantCamera``, ``RetrieveResult``, ``GrabResult.GetDataContainer()`` with
components of ``ComponentType_Range``/``_Intensity``/``_Confidence``.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from drivers.camera.frames import import_sdk
from drivers.camera.gentl import (
    Component,
    GenTLCamera,
    GenTLProfile,
    NodeMap,
    Scan3d,
    device_temperatures,
    enable_components,
    frame_from_parts,
    read_scan3d,
    readable,
)
from drivers.device import CameraDevice
from drivers.errors import CameraDisconnected, DeviceError, DroppedFrame, MissingSDKError, not_connected
from drivers.protocols import CameraInfo, DeviceIdentity, Frame

DEVICE_CLASS = "BaslerGTC/Basler/GenTL_Producer_for_Basler_blaze_101_cameras"
INSTALL_PRODUCER = (
    "install Basler's GenTL producer for blaze (pylon Supplementary Package for blaze, or the blaze "
    "component of the pylon installer)"
)
PRODUCER_HINT = f"{INSTALL_PRODUCER} and put its directory on GENICAM_GENTL64_PATH"
INSTALL_PYPYLON = "pip install pypylon, plus Basler's GenTL producer for blaze"

COMPONENTS = (
    Component("range", "Range", "Coord3D_ABC32f", ("Coord3D_ABC32f",)),
    Component("intensity", "Intensity", "Mono16", ("Mono16",)),
    Component("confidence", "Confidence", "Confidence16", ("Confidence16", "Mono16")),
)
SETTINGS = ("mode", "filters", "fast_mode", "confidence_threshold", "depth_range_mm")
READ_BACK = (
    "OperatingMode", "ExposureTime", "FastMode", "FilterSpatial", "FilterTemporal", "OutlierRemoval",
    "ConfidenceThreshold", "DepthMin", "DepthMax",
)  # fmt: skip


def apply_settings(nodes: NodeMap, exposure_us: float | None, settings: Mapping[str, Any]) -> dict[str, Any]:
    """Campaign settings → blaze features; returns the features as the camera reports them.

    ``mode``: ``"default"`` keeps the camera's operating mode, anything else is an
    ``OperatingMode`` entry. ``filters``: spatial, temporal and outlier filters on/off.
    ``fast_mode``, ``confidence_threshold``, ``depth_range_mm`` = [min, max].
    """
    mode = settings.get("mode", "default")
    if mode != "default":
        entries = nodes.entries("OperatingMode")
        if mode not in entries:
            raise DeviceError(nodes.device, f"mode {mode!r} is not an OperatingMode of this blaze; use one of {entries}")
        nodes.set("OperatingMode", mode)
    if "filters" in settings:
        for feature in ("FilterSpatial", "FilterTemporal", "OutlierRemoval"):
            nodes.set(feature, bool(settings["filters"]))
    if "fast_mode" in settings:
        nodes.set("FastMode", bool(settings["fast_mode"]))
    if "confidence_threshold" in settings:
        nodes.set("ConfidenceThreshold", int(settings["confidence_threshold"]))
    if "depth_range_mm" in settings:
        low, high = settings["depth_range_mm"]
        nodes.set("DepthMin", int(low))
        nodes.set("DepthMax", int(high))
    if exposure_us is not None:
        if nodes.has("ExposureAuto"):
            nodes.set("ExposureAuto", "Off")
        nodes.set("ExposureTime", float(exposure_us))
    applied = {name: value for name in READ_BACK if (value := readable(nodes, name)) is not None}
    if "ExposureTime" in applied:
        applied["exposure_us"] = applied.pop("ExposureTime")
    return {"mode": mode, **{k: v for k, v in settings.items() if k != "mode"}, **applied}


def _apply_for_gentl(nodes: NodeMap, exposure_us: float | None, settings: Mapping[str, Any]) -> dict[str, Any]:
    if readable(nodes, "GenDCStreamingMode") == "On":
        nodes.set("GenDCStreamingMode", "Off")  # multi-part buffers, which harvesters splits into parts
    return apply_settings(nodes, exposure_us, settings)


PROFILE = GenTLProfile(
    backend="blaze",
    label="Basler blaze",
    producer_hint=PRODUCER_HINT,
    model_pattern="blaze",
    components=COMPONENTS,
    apply_settings=_apply_for_gentl,
    fov_deg=(67.0, 51.0),  # blaze-101 datasheet
    frame_rate_hz=30.0,
    pixel_pitch_um=10.0,  # Sony IMX556 DepthSense sensor
    wavelength_nm=940.0,
    settings_keys=SETTINGS,
)


class PylonNodes:
    """A pypylon node map (``GetNode(name)`` → parameter with ``IsValid``, ``Value``, ``Symbolics``)."""

    def __init__(self, node_map: Any, device: str) -> None:
        self._map = node_map
        self.device = device

    def has(self, name: str) -> bool:
        """``GetNode(name).IsValid()`` (pypylon returns a placeholder for a missing feature)."""
        return bool(self._map.GetNode(name).IsValid())

    def _node(self, name: str) -> Any:
        node = self._map.GetNode(name)
        if not node.IsValid():
            raise DeviceError(self.device, f"the camera has no feature '{name}'")
        return node

    def get(self, name: str) -> Any:
        """The parameter's ``Value``."""
        node = self._node(name)
        try:
            return node.Value
        except Exception as exc:  # pypylon genicam exceptions: not readable now, ...
            raise DeviceError(self.device, f"cannot read '{name}': {exc}") from exc

    def set(self, name: str, value: Any) -> None:
        """Write a feature unless it already holds ``value``."""
        node = self._node(name)
        with contextlib.suppress(Exception):
            if node.Value == value:
                return
        try:
            node.Value = value
        except Exception as exc:  # pypylon genicam OutOfRange/Access/LogicalError exceptions
            raise DeviceError(self.device, f"cannot set '{name}' to {value!r}: {exc}") from exc

    def entries(self, name: str) -> list[str]:
        """An enumeration parameter's ``Symbolics``."""
        return list(getattr(self._node(name), "Symbolics", ()) or ())


def pylon_transport_layers(pylon: Any) -> list[str]:
    """Device classes of the transport layers pylon can load (``TlFactory.EnumerateTls``)."""
    return [tl.GetDeviceClass() for tl in pylon.TlFactory.GetInstance().EnumerateTls()]


class PylonBlazeCamera(CameraDevice):
    """A blaze through pypylon as a :class:`~drivers.protocols.DepthCamera` (``serial``: which one)."""

    def __init__(self, serial: str | None = None, *, timeout_s: float = 5.0) -> None:
        self.serial = serial
        self.timeout_s = timeout_s
        super().__init__(f"Basler blaze {serial}" if serial else "Basler blaze")
        self._pylon: Any = None
        self._camera: Any = None
        self._nodes: PylonNodes | None = None
        self._scan3d = Scan3d()
        self._tick_hz = 1e9
        self._settings: dict[str, Any] = {}

    def connect(self) -> None:
        """Find the blaze through the blaze GenTL producer's transport layer and open it; its identity
        is vendor, model, serial number and device version from pylon's device info."""
        if self._camera is not None:
            return
        pylon = self._pylon = import_sdk("pypylon.pylon", self.name, INSTALL_PYPYLON)
        layers = pylon_transport_layers(pylon)
        if DEVICE_CLASS not in layers:
            raise MissingSDKError(
                self.name,
                f"pypylon is installed but its transport layers are {layers}: pypylon alone cannot see a blaze. "
                f"To fix: {INSTALL_PRODUCER}, or use sdk = \"harvesters\" with the producer's .cti",
            )
        wanted = pylon.DeviceInfo()
        wanted.SetDeviceClass(DEVICE_CLASS)
        if self.serial is not None:
            wanted.SetSerialNumber(self.serial)
        try:
            camera = pylon.InstantCamera(pylon.TlFactory.GetInstance().CreateFirstDevice(wanted))
            camera.Open()
        except Exception as exc:  # pylon RuntimeException: no such device, in use elsewhere
            which = f"the blaze with serial {self.serial}" if self.serial else "a blaze"
            raise DeviceError(self.name, f"cannot open {which}: {exc}") from exc
        self._camera = camera
        self._nodes = PylonNodes(camera.GetNodeMap(), self.name)
        try:
            enable_components(self._nodes, COMPONENTS)
            self._nodes.set("ComponentSelector", "Range")
            self._scan3d = read_scan3d(self._nodes)
            self._tick_hz = float(readable(self._nodes, "GevTimestampTickFrequency", 1e9))
        except Exception:
            self.close()
            raise
        info = camera.GetDeviceInfo()
        self._identity = DeviceIdentity(
            "blaze", f"{info.GetVendorName()} {info.GetModelName()}", info.GetSerialNumber(), info.GetDeviceVersion()
        )

    def close(self) -> None:
        """Stop grabbing and close the camera (idempotent)."""
        self.safe_state()
        camera, self._camera, self._nodes = self._camera, None, None
        if camera is not None:
            with contextlib.suppress(Exception):
                camera.Close()

    def safe_state(self) -> None:
        """Stop grabbing (the illumination stops with it); never raises."""
        if self._camera is not None:
            with contextlib.suppress(Exception):
                self._camera.StopGrabbing()

    def settings(self) -> Mapping[str, Any]:
        """Settings as applied and read back."""
        return dict(self._settings)

    def info(self) -> CameraInfo:
        """Resolution of the range component, datasheet FOV and optics, frame rate of the camera."""
        nodes = self._ready()
        nodes.set("ComponentSelector", "Range")
        return CameraInfo(
            width=int(nodes.get("Width")), height=int(nodes.get("Height")), fov_deg=PROFILE.fov_deg,
            pixel_pitch_um=PROFILE.pixel_pitch_um,
            frame_rate_hz=float(readable(nodes, "AcquisitionFrameRate", PROFILE.frame_rate_hz)),
            wavelength_nm=PROFILE.wavelength_nm, confidence_dtype="uint16",
        )

    def configure(self, exposure_us: float | None, settings: Mapping[str, Any]) -> None:
        """Apply :func:`apply_settings` (grabbing stopped) and re-read the Scan3d scaling."""
        nodes = self._ready()
        unknown = sorted(set(settings) - set(SETTINGS))
        if unknown:
            raise DeviceError(self.name, f"unknown setting(s) {unknown}; this backend knows {list(SETTINGS)}")
        self.safe_state()
        self._settings = apply_settings(nodes, exposure_us, settings)
        nodes.set("ComponentSelector", "Range")
        self._scan3d = read_scan3d(nodes)

    def temperatures_c(self) -> dict[str, float]:
        """The SFNC ``DeviceTemperature`` of each sensor the blaze names (:func:`device_temperatures`)."""
        return device_temperatures(self._ready())

    def capture(self, count: int, first_index: int = 0) -> Iterator[Frame]:
        """Grab ``count`` frames one by one (``StartGrabbingMax``, ``RetrieveResult``)."""
        self._ready()
        pylon, camera = self._pylon, self._camera
        try:
            camera.StartGrabbingMax(count, pylon.GrabStrategy_OneByOne)
        except Exception as exc:
            raise CameraDisconnected(self.name, f"cannot start grabbing: {exc}") from exc
        try:
            for k in range(first_index, first_index + count):
                yield self._retrieve(k)
        finally:
            self.safe_state()

    def _ready(self) -> PylonNodes:
        if self._nodes is None:
            raise not_connected(self.name)
        return self._nodes

    def _retrieve(self, k: int) -> Frame:
        pylon = self._pylon
        try:
            result = self._camera.RetrieveResult(round(self.timeout_s * 1000), pylon.TimeoutHandling_Return)
        except Exception as exc:  # the camera vanished
            raise CameraDisconnected(self.name, f"grabbing frame {k} failed: {exc}") from exc
        if result is None or not result.IsValid():
            raise DroppedFrame(self.name, f"no frame {k} within {self.timeout_s} s")
        try:
            if not result.GrabSucceeded():
                raise DroppedFrame(self.name, f"frame {k} incomplete: {result.GetErrorDescription()}")
            arrays = _container_arrays(pylon, result.GetDataContainer(), self.name)
            stamp = result.GetTimeStamp() / self._tick_hz  # device clock ticks (GevTimestampTickFrequency)
        finally:
            result.Release()
        return frame_from_parts(arrays, self._scan3d, stamp, self.name)


def _container_arrays(pylon: Any, container: Any, device: str) -> dict[str, np.ndarray]:
    """Range (A, B, C planes), intensity and confidence arrays from a pylon data container."""
    arrays: dict[str, np.ndarray] = {}
    for index in range(container.DataComponentCount):
        component = container.GetDataComponent(index)
        try:
            kind = component.ComponentType
            data = np.array(component.Array)  # copy: the component's memory is released below
            shape = (component.Height, component.Width)
            if kind == pylon.ComponentType_Range:
                points = data.reshape(*shape, -1)
                letters = "ABC" if points.shape[-1] == 3 else "C"
                arrays.update({letter: points[..., k] for k, letter in enumerate(letters)})
            elif kind == pylon.ComponentType_Intensity:
                arrays["intensity"] = data.reshape(shape)
            elif kind == pylon.ComponentType_Confidence:
                arrays["confidence"] = data.reshape(shape)
        finally:
            component.Release()
    missing = [role for role in ("C", "intensity", "confidence") if role not in arrays]
    if missing:
        raise DroppedFrame(device, f"data container lacks {missing}")
    return arrays


def blaze_camera(
    serial: str | None = None,
    *,
    sdk: str = "pypylon",
    producers: Sequence[str | Path] | None = None,
    timeout_s: float = 5.0,
) -> PylonBlazeCamera | GenTLCamera:
    """A blaze adapter: through pypylon (``sdk="pypylon"``) or harvesters with the blaze producer's
    ``.cti`` (``sdk="harvesters"``, ``producers`` default: ``GENICAM_GENTL64_PATH``)."""
    if sdk == "pypylon":
        if producers is not None:
            raise ValueError("producers apply to sdk='harvesters'; pypylon finds the blaze producer itself")
        return PylonBlazeCamera(serial, timeout_s=timeout_s)
    if sdk == "harvesters":
        return GenTLCamera(PROFILE, producers=producers, serial=serial, timeout_s=timeout_s)
    raise ValueError(f"sdk must be 'pypylon' or 'harvesters', got {sdk!r}")
