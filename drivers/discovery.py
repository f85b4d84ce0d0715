"""What is connected: serial ports, RealSense devices, GenTL producers and their devices,
pylon transport layers and devices, pmd Royale cameras; with a clear line for each SDK
that is missing. Every section catches its own failures, so one broken SDK never hides
the others.

APIs: pyserial ``serial.tools.list_ports.comports``; librealsense
``rs.context().query_devices``; harvesters ``Harvester.add_file/update/device_info_list``;
pypylon ``TlFactory.EnumerateTls/EnumerateDevices``; roypy ``CameraManager.getConnectedCameraList``.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Mapping
from dataclasses import asdict, dataclass, field
from typing import Any

from drivers.camera import blaze, flexx2, gentl, realsense
from drivers.camera.frames import import_sdk
from drivers.errors import MissingSDKError


@dataclass(frozen=True)
class Section:
    """One kind of device: whether its SDK is usable, what it found, and a note (e.g. what to install)."""

    name: str
    available: bool
    devices: list[str] = field(default_factory=list)
    note: str = ""

    def as_dict(self) -> dict[str, Any]:
        """The section as plain data, for ``labctl devices --json``."""
        return asdict(self)


def serial_ports() -> Section:
    """Serial ports pyserial finds (``serial.tools.list_ports.comports``)."""
    from serial.tools import list_ports

    ports = [f"{p.device} ({p.description})" if p.description and p.description != "n/a" else p.device
             for p in list_ports.comports()]
    return Section("serial ports", True, ports)


def realsense_devices() -> Section:
    """RealSense devices librealsense sees."""
    rs = realsense.sdk("RealSense")
    info = rs.camera_info
    found = [f"{d.get_info(info.name)} serial {d.get_info(info.serial_number)}" for d in rs.context().query_devices()]
    return Section("RealSense (pyrealsense2)", True, found)


def gentl_devices(environ: Mapping[str, str]) -> Section:
    """GenTL producers on ``GENICAM_GENTL64_PATH`` and the devices each one reports (harvesters)."""
    producers = gentl.producers_on_path(environ)
    if not producers:
        return Section(
            "GenTL (harvesters)", True, [],
            f"no producer (.cti) in {gentl.PATH_VARIABLE}={environ.get(gentl.PATH_VARIABLE, '')!r}; "
            "blaze and AM-T100 need their vendor's producer there",
        )
    core = import_sdk("harvesters.core", "GenTL", gentl.INSTALL)
    found = []
    for producer in producers:
        harvester = core.Harvester()
        try:
            harvester.add_file(str(producer))
            harvester.update()
            devices = [f"{i.vendor} {i.model} serial {i.serial_number}" for i in harvester.device_info_list]
            found.append(f"{producer}: {', '.join(devices) or 'no devices'}")
        except Exception as exc:  # a producer that fails to load must not hide the others
            found.append(f"{producer}: cannot be loaded ({exc})")
        finally:
            harvester.reset()
    return Section("GenTL (harvesters)", True, found)


def pylon_devices() -> Section:
    """pylon's transport layers and devices, and whether the blaze producer is among them."""
    pylon = import_sdk("pypylon.pylon", "pylon", blaze.INSTALL_PYPYLON)
    layers = blaze.pylon_transport_layers(pylon)
    devices = [f"{d.GetModelName()} serial {d.GetSerialNumber()} ({d.GetDeviceClass()})"
               for d in pylon.TlFactory.GetInstance().EnumerateDevices()]
    note = f"transport layers {layers}"
    if blaze.DEVICE_CLASS not in layers:
        note += f"; no blaze producer, so no blaze is visible: {blaze.INSTALL_PRODUCER}"
    return Section("pylon (pypylon)", True, devices, note)


def royale_devices() -> Section:
    """pmd cameras Royale sees."""
    roypy = import_sdk("roypy", "pmd Royale", flexx2.INSTALL)
    return Section("pmd Royale (roypy)", True, [str(i) for i in roypy.CameraManager().getConnectedCameraList()])


def discover(environ: Mapping[str, str] = os.environ) -> list[Section]:
    """Every section, in a fixed order; a missing SDK or a failing scan becomes a section's note."""
    scans: list[tuple[str, Callable[[], Section]]] = [
        ("serial ports", serial_ports),
        ("RealSense (pyrealsense2)", realsense_devices),
        ("GenTL (harvesters)", lambda: gentl_devices(environ)),
        ("pylon (pypylon)", pylon_devices),
        ("pmd Royale (roypy)", royale_devices),
    ]
    sections = []
    for name, scan in scans:
        try:
            sections.append(scan())
        except MissingSDKError as exc:
            sections.append(Section(name, False, [], f"SDK missing: {exc.message}"))
        except Exception as exc:  # an SDK that is present but fails while scanning
            sections.append(Section(name, True, [], f"scan failed: {exc}"))
    return sections
