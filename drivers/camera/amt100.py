"""Schmersal AM-T100 ToF camera, via harvesters and Schmersal's GenTL producer.

The AM-T100 enables its images with its own boolean features ``TransmitRangeImage``,
``TransmitIntensityImage`` and ``TransmitConfidenceImage`` (instead of SFNC's
``ComponentSelector``), delivers the range as depth only (PFNC ``Coord3D_C32f``, integer
millimetres), the intensity as ``Mono16`` and the confidence as ``Mono16``. x and y are
back-projected from the depth with the producer's ``Scan3dFocalLength`` /
``Scan3dPrincipalPointU``/``V`` (or the ``focal_length_px`` / ``principal_point_px``
settings). Exposure is SFNC ``ExposureTime`` (µs); a range preset is written to the
``RangePreset`` enumeration. The names that are not SFNC's could not be checked against
the camera here; any feature of the camera's GenICam XML can be set with the ``nodes``
setting.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from drivers.camera.gentl import Component, GenTLCamera, GenTLProfile, NodeMap, readable
from drivers.errors import DeviceError

PRODUCER_HINT = (
    "install Schmersal's GenTL producer for the AM-T100 and put its directory on GENICAM_GENTL64_PATH "
    "(or set devices.camera.producer to the .cti file)"
)
RANGE_PRESET_FEATURE = "RangePreset"
COMPONENTS = (
    Component("range", "TransmitRangeImage", None, ("Coord3D_C32f",), enable_node=True),
    Component("intensity", "TransmitIntensityImage", None, ("Mono16",), enable_node=True),
    Component("confidence", "TransmitConfidenceImage", None, ("Mono16",), enable_node=True),
)
SETTINGS = ("range_preset",)


def apply_settings(nodes: NodeMap, exposure_us: float | None, settings: Mapping[str, Any]) -> dict[str, Any]:
    """``range_preset`` (an entry of the ``RangePreset`` enumeration) and exposure (``ExposureTime``, µs)."""
    if "range_preset" in settings:
        preset = str(settings["range_preset"])
        entries = nodes.entries(RANGE_PRESET_FEATURE)
        if preset not in entries:
            raise DeviceError(nodes.device, f"range_preset {preset!r} is not one of {entries}")
        nodes.set(RANGE_PRESET_FEATURE, preset)
    if exposure_us is not None:
        if nodes.has("ExposureAuto"):
            nodes.set("ExposureAuto", "Off")
        nodes.set("ExposureTime", float(exposure_us))
    read_back = {"range_preset": readable(nodes, RANGE_PRESET_FEATURE), "exposure_us": readable(nodes, "ExposureTime")}
    return {**settings, **{key: value for key, value in read_back.items() if value is not None}}


PROFILE = GenTLProfile(
    backend="amt100",
    label="Schmersal AM-T100",
    producer_hint=PRODUCER_HINT,
    model_pattern="T100",
    components=COMPONENTS,
    apply_settings=apply_settings,
    fov_deg=(67.0, 51.0),  # datasheet (Thesis 2024, Table 6-1)
    frame_rate_hz=60.0,
    pixel_pitch_um=float("nan"),  # not published
    wavelength_nm=850.0,
    range_component="",
    settings_keys=SETTINGS,
)


def amt100_camera(
    serial: str | None = None, *, producers: Sequence[str | Path] | None = None, timeout_s: float = 5.0
) -> GenTLCamera:
    """An AM-T100 adapter (``producers`` default: the ``.cti`` files on ``GENICAM_GENTL64_PATH``)."""
    return GenTLCamera(PROFILE, producers=producers, serial=serial, timeout_s=timeout_s)
