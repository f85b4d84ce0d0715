"""GenICam GenTL plumbing shared by the Basler blaze and the Schmersal AM-T100, via harvesters.

A GenTL producer (a ``.cti`` library from the camera vendor) exposes the camera; harvesters
(https://github.com/genicam/harvesters, ``harvesters.core.Harvester``: ``add_file``,
``update``, ``device_info_list``, ``create``; ``ImageAcquirer``: ``remote_device.node_map``,
``start``, ``fetch``, ``stop``, ``destroy``) is the consumer. Producers are found in the
directories of ``GENICAM_GENTL64_PATH`` (GenTL standard, "Finding the GenTL Producer").

3D cameras deliver several components per frame (GenICam SFNC 2.x, "Multi-part" and
"Scan3dControl"): a range component as 3D coordinates (PFNC ``Coord3D_ABC32f``, its planar
form as three parts ``Coord3D_A32f``/``B32f``/``C32f``, or only the depth ``Coord3D_C32f``),
an intensity image (``Mono8``/``Mono16``) and a confidence map (``Confidence8/16`` or
``Mono16``). Coordinates are scaled by ``Scan3dCoordinateScale``/``Offset`` per coordinate
(or their ``Chunk`` counterparts when chunk data carry them per frame) and invalid points
carry ``Scan3dInvalidDataValue``; a depth-only component is back-projected with
``Scan3dFocalLength`` and ``Scan3dPrincipalPointU``/``V``.
"""

from __future__ import annotations

import contextlib
import itertools
import os
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal, Protocol

import numpy as np

from drivers.camera.frames import backproject, import_sdk, invalidate, pinhole_fov_deg
from drivers.device import CameraDevice
from drivers.errors import CameraDisconnected, DeviceError, DroppedFrame, MissingSDKError, not_connected
from drivers.protocols import CameraInfo, DeviceIdentity, Frame

INSTALL = "pip install harvesters (it installs the genicam package too)"
PATH_VARIABLE = "GENICAM_GENTL64_PATH"

Role = Literal["range", "intensity", "confidence"]


def producers_on_path(environ: Mapping[str, str] = os.environ) -> list[Path]:
    """The ``.cti`` files in the directories listed in ``GENICAM_GENTL64_PATH``."""
    found: list[Path] = []
    for directory in environ.get(PATH_VARIABLE, "").split(os.pathsep):
        if directory and Path(directory).is_dir():
            found.extend(sorted(Path(directory).glob("*.cti")))
    return found


class NodeMap(Protocol):
    """GenApi feature access by name, whichever SDK provides the node map."""

    device: str

    def has(self, name: str) -> bool:
        """Whether the camera has the feature."""

    def get(self, name: str) -> Any:
        """The feature's value; DeviceError if missing or not readable."""

    def set(self, name: str, value: Any) -> None:
        """Write the feature; DeviceError naming feature and value if the camera refuses."""

    def entries(self, name: str) -> list[str]:
        """The symbolic entries of an enumeration feature."""


class GenApiNodes:
    """A harvesters (genicam) node map: ``has_node``, ``get_node(name).value``, ``symbolics``."""

    def __init__(self, node_map: Any, device: str) -> None:
        self._map = node_map
        self.device = device

    def has(self, name: str) -> bool:
        """``NodeMap.has_node``."""
        return bool(self._map.has_node(name))

    def _node(self, name: str) -> Any:
        if not self.has(name):
            raise DeviceError(self.device, f"the camera has no feature '{name}'")
        return self._map.get_node(name)

    def get(self, name: str) -> Any:
        """``get_node(name).value``."""
        try:
            return self._node(name).value
        except DeviceError:
            raise
        except Exception as exc:  # genicam.genapi exceptions: not readable now, ...
            raise DeviceError(self.device, f"cannot read '{name}': {exc}") from exc

    def set(self, name: str, value: Any) -> None:
        """Write a feature unless it already holds ``value`` (a read-only feature may be right already)."""
        node = self._node(name)
        with contextlib.suppress(Exception):
            if node.value == value:
                return
        try:
            node.value = value
        except Exception as exc:  # genicam.genapi OutOfRange/Access/LogicalError exceptions
            raise DeviceError(self.device, f"cannot set '{name}' to {value!r}: {exc}") from exc

    def entries(self, name: str) -> list[str]:
        """An enumeration's ``symbolics``."""
        return list(getattr(self._node(name), "symbolics", ()) or ())


def readable(nodes: NodeMap, name: str, default: Any = None) -> Any:
    """A feature's value, or ``default`` if the camera lacks it or it is not readable now."""
    if not nodes.has(name):
        return default
    try:
        return nodes.get(name)
    except DeviceError:
        return default


def device_temperatures(nodes: NodeMap) -> dict[str, float]:
    """The GenICam SFNC ``DeviceTemperature`` (degrees Celsius) of every sensor ``DeviceTemperatureSelector``
    names (e.g. ``Sensor``, ``Mainboard``), or of the one sensor a camera without the selector has (``device``);
    empty where the camera lacks the feature or cannot read it now."""
    if not nodes.has("DeviceTemperature"):
        return {}
    sensors = nodes.entries("DeviceTemperatureSelector") if nodes.has("DeviceTemperatureSelector") else []
    if not sensors:
        value = readable(nodes, "DeviceTemperature")
        return {} if value is None else {"device": float(value)}
    found: dict[str, float] = {}
    for sensor in sensors:
        try:
            nodes.set("DeviceTemperatureSelector", sensor)
        except DeviceError:
            continue
        value = readable(nodes, "DeviceTemperature")
        if value is not None:
            found[sensor] = float(value)
    return found


@dataclass(frozen=True)
class Component:
    """One image component a backend needs, and how to switch it on.

    ``name`` is the ``ComponentSelector`` entry (``enable_node`` None) or a boolean node that
    enables the component on its own (``enable_node`` set, e.g. the AM-T100's
    ``TransmitRangeImage``). ``formats`` are the data formats it may arrive in.
    """

    role: Role
    name: str
    pixel_format: str | None
    formats: tuple[str, ...]
    enable_node: bool = False


def enable_components(nodes: NodeMap, components: Sequence[Component]) -> None:
    """Switch the wanted components on (with their pixel format) and, where the camera has a
    ``ComponentSelector``, every other component off if it lets them be switched off (SFNC
    "ComponentSelector/ComponentEnable"); parts of components nobody asked for are ignored."""
    selectable = nodes.has("ComponentSelector")
    wanted = {c.name for c in components if not c.enable_node}
    if selectable:
        for entry in nodes.entries("ComponentSelector"):
            if entry not in wanted:
                nodes.set("ComponentSelector", entry)
                with contextlib.suppress(DeviceError):  # some cameras always send some components
                    nodes.set("ComponentEnable", False)
    for component in components:
        if component.enable_node:
            nodes.set(component.name, True)
            continue
        if not selectable:
            raise DeviceError(nodes.device, f"the camera has no ComponentSelector to enable '{component.name}'")
        nodes.set("ComponentSelector", component.name)
        nodes.set("ComponentEnable", True)
        if component.pixel_format is not None:
            nodes.set("PixelFormat", component.pixel_format)


@dataclass(frozen=True)
class Scan3d:
    """Coordinate scaling and intrinsics of the range component (SFNC "Scan3dControl")."""

    scale: tuple[float, float, float] = (1.0, 1.0, 1.0)
    offset: tuple[float, float, float] = (0.0, 0.0, 0.0)
    invalid_value: float | None = None
    focal_px: float | None = None
    principal_px: tuple[float, float] | None = None
    unit: str = "Millimeter"


def read_scan3d(nodes: NodeMap, prefix: str = "") -> Scan3d:
    """Scan3d parameters of the selected component; ``prefix="Chunk"`` reads the per-frame chunk values."""
    scale, offset = [1.0, 1.0, 1.0], [0.0, 0.0, 0.0]
    selector = f"{prefix}Scan3dCoordinateSelector"
    if nodes.has(selector):
        for k, coordinate in enumerate(("CoordinateA", "CoordinateB", "CoordinateC")):
            if coordinate in nodes.entries(selector):
                nodes.set(selector, coordinate)
                scale[k] = float(readable(nodes, f"{prefix}Scan3dCoordinateScale", 1.0))
                offset[k] = float(readable(nodes, f"{prefix}Scan3dCoordinateOffset", 0.0))
    invalid = None
    if readable(nodes, f"{prefix}Scan3dInvalidDataFlag", False):
        invalid = float(readable(nodes, f"{prefix}Scan3dInvalidDataValue", 0.0))
    focal = readable(nodes, "Scan3dFocalLength")
    u, v = readable(nodes, "Scan3dPrincipalPointU"), readable(nodes, "Scan3dPrincipalPointV")
    return Scan3d(
        scale=(scale[0], scale[1], scale[2]),
        offset=(offset[0], offset[1], offset[2]),
        invalid_value=invalid,
        focal_px=float(focal) if focal else None,
        principal_px=(float(u), float(v)) if u is not None and v is not None else None,
        unit=str(readable(nodes, f"{prefix}Scan3dDistanceUnit", "Millimeter")),
    )


@dataclass(frozen=True)
class Part:
    """One part of a multi-part buffer (or the single image of a single-part buffer)."""

    data_format: str
    width: int
    height: int
    data: np.ndarray


def parts_of(buffer: Any) -> list[Part]:
    """The parts of a harvesters buffer (``buffer.payload.components``)."""
    return [
        Part(str(c.data_format), int(c.width), int(c.height), np.asarray(c.data))
        for c in buffer.payload.components
        if c is not None
    ]


def _coordinates(part: Part) -> dict[str, np.ndarray]:
    """Coordinate planes of a ``Coord3D_*`` part by letter: interleaved (``ABC32f``: A, B, C per
    pixel), planar (``ABC32f_Planar``: all A, then B, then C) or one plane (``C32f``)."""
    name = part.data_format.removeprefix("Coord3D_")
    letters = "".join(itertools.takewhile(str.isupper, name))
    count = len(letters)
    if name.endswith("_Planar"):
        planes = part.data.reshape(count, part.height, part.width)
        return {letter: planes[k] for k, letter in enumerate(letters)}
    pixels = part.data.reshape(part.height, part.width, count)
    return {letter: pixels[..., k] for k, letter in enumerate(letters)}


def split_parts(parts: Sequence[Part], components: Sequence[Component], device: str) -> dict[str, np.ndarray]:
    """Assign parts to roles: 3D coordinates by format (``A``, ``B``, ``C`` planes), the others to
    the first unfilled component, in the camera's component order, that takes their format
    (an intensity and a confidence map may both be ``Mono16``). Missing components raise
    :class:`DroppedFrame` (an incomplete buffer)."""
    arrays: dict[str, np.ndarray] = {}
    pending = [c for c in components if c.role != "range"]
    for part in parts:
        shape = (part.height, part.width)
        if part.data_format.startswith("Coord3D_"):
            arrays.update(_coordinates(part))
            continue
        for component in pending:
            if part.data_format in component.formats:
                arrays[component.role] = part.data.reshape(shape)
                pending.remove(component)
                break
    missing = [c.role for c in components if c.role not in arrays and c.role != "range"]
    if "C" not in arrays:
        missing.insert(0, "range")
    if missing:
        formats = [p.data_format for p in parts]
        raise DroppedFrame(device, f"buffer lacks the {', '.join(missing)} component(s) (parts: {formats})")
    return arrays


def frame_from_parts(
    arrays: Mapping[str, np.ndarray],
    scan3d: Scan3d,
    timestamp: float,
    device: str,
    intrinsics: tuple[float, tuple[float, float]] | None = None,
) -> Frame:
    """A :class:`Frame` in mm from split parts. Coordinates equal to the invalid-data value, and
    z ≤ 0, become NaN. Depth-only data (no A/B planes) are back-projected with the Scan3d
    focal length and principal point, or ``intrinsics`` = (focal px, (cx, cy)) if given."""
    to_mm = {"Millimeter": 1.0, "Meter": 1000.0}.get(scan3d.unit)
    if to_mm is None:
        raise DeviceError(device, f"unsupported Scan3dDistanceUnit {scan3d.unit!r}")
    raw_c = np.asarray(arrays["C"], np.float32)
    invalid = raw_c == np.float32(scan3d.invalid_value) if scan3d.invalid_value is not None else None
    z = (raw_c * scan3d.scale[2] + scan3d.offset[2]) * to_mm
    if "A" in arrays and "B" in arrays:
        x = (np.asarray(arrays["A"], np.float32) * scan3d.scale[0] + scan3d.offset[0]) * to_mm
        y = (np.asarray(arrays["B"], np.float32) * scan3d.scale[1] + scan3d.offset[1]) * to_mm
    else:
        if intrinsics is None and (scan3d.focal_px is None or scan3d.principal_px is None):
            raise DeviceError(
                device,
                "the camera delivers depth only (Coord3D_C) and no Scan3dFocalLength / Scan3dPrincipalPointU/V: "
                "set the camera settings focal_length_px and principal_point_px",
            )
        focal, principal = intrinsics if intrinsics is not None else (scan3d.focal_px, scan3d.principal_px)
        x, y = backproject(z.astype(np.float32), (focal, focal), principal)
    x, y, z = invalidate(x, y, z, invalid)
    shape = z.shape
    intensity = np.asarray(arrays["intensity"], np.float32) if "intensity" in arrays else np.full(shape, np.nan, np.float32)
    if "confidence" in arrays:
        confidence = np.asarray(arrays["confidence"]).astype(np.uint16)
    else:
        confidence = np.isfinite(z).astype(np.float32)
    return Frame(x, y, z, intensity, confidence, timestamp)


@dataclass(frozen=True)
class GenTLProfile:
    """What differs between GenTL cameras: components, settings, datasheet values, install hint."""

    backend: str
    label: str
    producer_hint: str
    model_pattern: str
    components: tuple[Component, ...]
    apply_settings: Callable[[NodeMap, float | None, Mapping[str, Any]], dict[str, Any]]
    fov_deg: tuple[float, float]
    frame_rate_hz: float
    pixel_pitch_um: float
    wavelength_nm: float
    range_component: str = "Range"
    settings_keys: tuple[str, ...] = ()


GENERIC_SETTINGS = ("nodes", "focal_length_px", "principal_point_px")
"""Settings every GenTL camera takes: ``nodes`` = {feature: value} set as given (after the
backend's own settings), and intrinsics for depth-only cameras whose producer lacks them."""


class GenTLCamera(CameraDevice):
    """A 3D camera behind a GenTL producer, via harvesters, as a :class:`~drivers.protocols.DepthCamera`.

    ``producers``: ``.cti`` files to load (default: those on ``GENICAM_GENTL64_PATH``);
    ``serial``: which camera (default: the only one whose model or vendor contains the
    profile's ``model_pattern``). Acquisition runs only during :meth:`capture`, so every
    stack starts with fresh buffers; ``timeout_s`` bounds the wait for each buffer.
    """

    def __init__(
        self,
        profile: GenTLProfile,
        *,
        producers: Sequence[str | Path] | None = None,
        serial: str | None = None,
        timeout_s: float = 5.0,
    ) -> None:
        self.profile = profile
        self.producers = [Path(p) for p in producers] if producers is not None else None
        self.serial = serial
        self.timeout_s = timeout_s
        super().__init__(f"{profile.label} {serial}" if serial else profile.label)
        self._harvester: Any = None
        self._acquirer: Any = None
        self._nodes: GenApiNodes | None = None
        self._scan3d = Scan3d()
        self._intrinsics: tuple[float, tuple[float, float]] | None = None
        self._settings: dict[str, Any] = {}
        self._timeout_error: type[Exception] = TimeoutError

    # -- DepthCamera ----------------------------------------------------------------

    def connect(self) -> None:
        """Load the producers, find the camera, open it and enable its components; the identity is
        vendor, model, serial number and firmware version of the GenTL device."""
        if self._acquirer is not None:
            return
        core = import_sdk("harvesters.core", self.name, INSTALL)
        self._timeout_error = import_sdk("genicam.gentl", self.name, INSTALL).TimeoutException
        producers = self.producers if self.producers is not None else producers_on_path()
        missing = [str(p) for p in producers if not p.is_file()]
        if missing:
            raise MissingSDKError(self.name, f"GenTL producer file(s) {missing} do not exist; {self.profile.producer_hint}")
        if not producers:
            raise MissingSDKError(
                self.name,
                f"no GenTL producer (.cti) found in {PATH_VARIABLE}={os.environ.get(PATH_VARIABLE, '')!r}; "
                f"{self.profile.producer_hint}",
            )
        harvester = core.Harvester()
        try:
            for producer in producers:
                harvester.add_file(str(producer))
            harvester.update()
            index, info = self._choose(harvester.device_info_list, producers)
            self._acquirer = harvester.create(index)
        except DeviceError:
            harvester.reset()
            raise
        except Exception as exc:  # genicam/harvesters errors while loading or opening
            harvester.reset()
            raise DeviceError(self.name, f"cannot open the camera through {[str(p) for p in producers]}: {exc}") from exc
        self._harvester = harvester
        self._nodes = GenApiNodes(self._acquirer.remote_device.node_map, self.name)
        try:
            enable_components(self._nodes, self.profile.components)
            self._scan3d = self._read_scan3d()
        except Exception:
            self.close()
            raise
        firmware = readable(self._nodes, "DeviceFirmwareVersion") or getattr(info, "version", "")
        self._identity = DeviceIdentity(
            backend=self.profile.backend,
            model=f"{info.vendor} {info.model}",
            serial=str(info.serial_number),
            firmware=str(firmware),
        )

    def close(self) -> None:
        """Stop acquisition, release the camera and unload the producers (idempotent)."""
        self.safe_state()
        acquirer, harvester = self._acquirer, self._harvester
        self._acquirer = self._harvester = self._nodes = None
        if acquirer is not None:
            with contextlib.suppress(Exception):
                acquirer.destroy()
        if harvester is not None:
            with contextlib.suppress(Exception):
                harvester.reset()

    def safe_state(self) -> None:
        """Stop acquisition (the ToF illumination stops with it); never raises."""
        if self._acquirer is not None:
            with contextlib.suppress(Exception):
                if self._acquirer.is_acquiring():
                    self._acquirer.stop()

    def settings(self) -> Mapping[str, Any]:
        """Settings as applied (read back from the camera where it reports them)."""
        return dict(self._settings)

    def info(self) -> CameraInfo:
        """Resolution of the range component; FOV from its intrinsics when the producer gives
        them, else the datasheet's; frame rate from ``AcquisitionFrameRate`` or the datasheet."""
        nodes = self._ready()
        self._select_range(nodes)
        width, height = int(nodes.get("Width")), int(nodes.get("Height"))
        focal = self._intrinsics[0] if self._intrinsics else self._scan3d.focal_px
        fov = pinhole_fov_deg(width, height, (focal, focal)) if focal else self.profile.fov_deg
        rate = float(readable(nodes, "AcquisitionFrameRate", self.profile.frame_rate_hz))
        has_confidence = any(c.role == "confidence" for c in self.profile.components)
        return CameraInfo(
            width=width, height=height, fov_deg=fov, pixel_pitch_um=self.profile.pixel_pitch_um,
            frame_rate_hz=rate, wavelength_nm=self.profile.wavelength_nm,
            confidence_dtype="uint16" if has_confidence else "float32",
        )

    def configure(self, exposure_us: float | None, settings: Mapping[str, Any]) -> None:
        """Apply the backend's settings and exposure (camera's own feature names), then the
        generic ``nodes``; re-read the Scan3d scaling."""
        nodes = self._ready()
        known = set(self.profile.settings_keys) | set(GENERIC_SETTINGS)
        unknown = sorted(set(settings) - known)
        if unknown:
            raise DeviceError(self.name, f"unknown setting(s) {unknown}; this backend knows {sorted(known)}")
        self.safe_state()
        backend_settings = {k: v for k, v in settings.items() if k not in GENERIC_SETTINGS}
        applied = self.profile.apply_settings(nodes, exposure_us, backend_settings)
        for name, value in dict(settings.get("nodes", {})).items():
            nodes.set(name, value)
            applied.setdefault("nodes", {})[name] = nodes.get(name)
        if "focal_length_px" in settings or "principal_point_px" in settings:
            try:
                cx, cy = settings["principal_point_px"]
                self._intrinsics = (float(settings["focal_length_px"]), (float(cx), float(cy)))
            except (KeyError, TypeError, ValueError) as exc:
                raise DeviceError(
                    self.name, "focal_length_px (number) and principal_point_px ([cx, cy]) go together"
                ) from exc
            applied["focal_length_px"], applied["principal_point_px"] = self._intrinsics[0], list(self._intrinsics[1])
        self._scan3d = self._read_scan3d()
        self._settings = applied

    def temperatures_c(self) -> dict[str, float]:
        """The SFNC ``DeviceTemperature`` of each sensor (:func:`device_temperatures`)."""
        return device_temperatures(self._ready())

    def capture(self, count: int, first_index: int = 0) -> Iterator[Frame]:
        """Start acquisition, yield ``count`` frames (``ImageAcquirer.fetch``), stop acquisition."""
        nodes = self._ready()
        acquirer = self._acquirer
        chunk = bool(readable(nodes, "ChunkModeActive", False)) and nodes.has("ChunkScan3dCoordinateSelector")
        try:
            acquirer.start()
        except Exception as exc:
            raise CameraDisconnected(self.name, f"cannot start acquisition: {exc}") from exc
        try:
            for k in range(first_index, first_index + count):
                yield self._fetch(k, nodes, chunk)
        finally:
            self.safe_state()

    # -- helpers ----------------------------------------------------------------------

    def _ready(self) -> GenApiNodes:
        if self._nodes is None:
            raise not_connected(self.name)
        return self._nodes

    def _choose(self, infos: Sequence[Any], producers: Sequence[Path]) -> tuple[int, Any]:
        found = [f"{i.vendor} {i.model} (serial {i.serial_number})" for i in infos]
        if self.serial is not None:
            matches = [k for k, i in enumerate(infos) if str(i.serial_number) == self.serial]
        else:
            pattern = self.profile.model_pattern.lower()
            matches = [k for k, i in enumerate(infos) if pattern in f"{i.vendor} {i.model}".lower()]
        if len(matches) == 1:
            return matches[0], infos[matches[0]]
        wanted = f"with serial {self.serial}" if self.serial else f"whose model contains '{self.profile.model_pattern}'"
        if not matches:
            raise DeviceError(
                self.name,
                f"no device {wanted} among the GenTL devices {found or '(none)'} of {[str(p) for p in producers]}",
            )
        raise DeviceError(self.name, f"several devices match {wanted}: {found}; set the camera's serial")

    def _select_range(self, nodes: NodeMap) -> None:
        if nodes.has("ComponentSelector") and self.profile.range_component in nodes.entries("ComponentSelector"):
            nodes.set("ComponentSelector", self.profile.range_component)

    def _read_scan3d(self) -> Scan3d:
        nodes = self._ready()
        self._select_range(nodes)
        return read_scan3d(nodes)

    def _fetch(self, k: int, nodes: GenApiNodes, chunk: bool) -> Frame:
        try:
            with self._acquirer.fetch(timeout=self.timeout_s) as buffer:
                parts = split_parts(parts_of(buffer), self.profile.components, self.name)
                arrays = {key: value.copy() for key, value in parts.items()}  # the buffer is requeued on exit
                try:
                    stamp = buffer.timestamp_ns / 1e9 or time.monotonic()
                except Exception:  # producers without GenTL BUFFER_INFO_TIMESTAMP_NS
                    stamp = time.monotonic()
                scan3d = self._scan3d
                if chunk:  # per-frame scaling from the buffer's chunk data, where the camera sends it
                    with contextlib.suppress(DeviceError):
                        scan3d = read_scan3d(nodes, "Chunk")
        except self._timeout_error as exc:
            raise DroppedFrame(self.name, f"no buffer for frame {k} within {self.timeout_s} s") from exc
        except (DeviceError, DroppedFrame):
            raise
        except Exception as exc:  # genicam.gentl errors: the device or its stream went away
            raise CameraDisconnected(self.name, f"acquisition of frame {k} failed: {exc}") from exc
        return frame_from_parts(arrays, scan3d, stamp, self.name, self._intrinsics)
