"""pmd flexx2 ToF camera, live or from a ``.rrf`` recording, via pmd Royale's Python wrapper ``roypy``.

roypy ships with pmd's Royale SDK, not on PyPI. Royale API (Royale SDK documentation and its
Python samples ``sample_retrieve_data.py``, ``roypy_sample_utils.py``): ``roypy.CameraManager``
(``getConnectedCameraList``, ``createCamera(id)``; ``createCamera(path)`` opens a ``.rrf``
recording), the camera device (``initialize``, ``getUseCases``/``setUseCase``,
``setExposureMode``/``setExposureTime`` in µs, ``registerDataListener``, ``startCapture``,
``stopCapture``, ``getCameraName``, ``getId``, ``getMaxSensorWidth``/``Height``,
``getFrameRate``) and ``roypy.IDepthDataListener``, whose ``onNewData(data)`` receives
each frame's ``DepthData`` (``width``, ``height``, ``timeStamp`` in µs, and per point x, y, z
in m, noise, gray value and depth confidence, 0 = invalid).
"""

from __future__ import annotations

import contextlib
import queue
from collections.abc import Iterator, Mapping
from pathlib import Path
from types import ModuleType
from typing import Any

import numpy as np

from drivers.camera.frames import import_sdk, invalidate
from drivers.device import CameraDevice
from drivers.errors import CameraDisconnected, DeviceError, DroppedFrame, not_connected
from drivers.protocols import CameraInfo, DeviceIdentity, Frame

INSTALL = (
    "roypy is part of pmd's Royale SDK and not on PyPI: install Royale for this platform from pmd "
    "(pmdtec.com, registration required) and add its python directory (roypy.py and _roypy) to PYTHONPATH"
)
FOV_DEG = (56.0, 44.0)
"""flexx2 datasheet field of view."""
WAVELENGTH_NM = 940.0
SETTINGS = ("use_case",)


def points_of(data: Any) -> np.ndarray:
    """A DepthData frame as an (H, W, 6) float32 array: x, y, z (m), noise, gray value, depth confidence.

    Newer roypy versions give the array at once (``npoints()``); older ones per point
    (``getX``, ``getY``, ``getZ``, ``getNoise``, ``getGrayValue``, ``getDepthConfidence``).
    """
    if hasattr(data, "npoints"):
        return np.array(data.npoints(), np.float32).reshape(data.height, data.width, -1)[..., :6]
    getters = (data.getX, data.getY, data.getZ, data.getNoise, data.getGrayValue, data.getDepthConfidence)
    count = data.getNumPoints()
    return np.array([[get(i) for get in getters] for i in range(count)], np.float32).reshape(data.height, data.width, 6)


def frame_from_points(points: np.ndarray, timestamp_us: float) -> Frame:
    """A :class:`Frame` (mm) from :func:`points_of`'s array; depth confidence 0 marks invalid points."""
    confidence = points[..., 5]
    x, y, z = invalidate(points[..., 0] * 1000.0, points[..., 1] * 1000.0, points[..., 2] * 1000.0, confidence == 0)
    return Frame(x, y, z, points[..., 4].astype(np.float32), confidence.astype(np.uint16), timestamp_us / 1e6)


class Flexx2Camera(CameraDevice):
    """A pmd flexx2 as a :class:`~drivers.protocols.DepthCamera`: live (``serial`` = Royale camera ID,
    default the only one) or playing a ``.rrf`` recording (``playback``)."""

    def __init__(self, serial: str | None = None, playback: str | Path | None = None, *, timeout_s: float = 5.0) -> None:
        self.serial = serial
        self.playback = Path(playback) if playback is not None else None
        self.timeout_s = timeout_s
        super().__init__(
            f"pmd flexx2 playback of {self.playback}" if self.playback else f"pmd flexx2 {serial or ''}".strip()
        )
        self._roypy: ModuleType | None = None
        self._camera: Any = None
        self._listener: Any = None
        self._frames: queue.Queue[tuple[np.ndarray, float]] = queue.Queue()
        self._settings: dict[str, Any] = {}

    def connect(self) -> None:
        """Open the camera or recording through ``CameraManager``, initialize it and register the listener;
        its identity is the camera name and ID from Royale, and the Royale version."""
        if self._camera is not None:
            return
        roypy = self._roypy = import_sdk("roypy", self.name, INSTALL)
        manager = roypy.CameraManager()
        if self.playback is not None:
            if not self.playback.is_file():
                raise DeviceError(self.name, f"recording {self.playback} does not exist")
            source = str(self.playback)
        else:
            ids = [str(i) for i in manager.getConnectedCameraList()]
            if not ids or (self.serial is not None and self.serial not in ids):
                raise DeviceError(self.name, f"no pmd camera{' ' + self.serial if self.serial else ''} connected; found {ids}")
            if self.serial is None and len(ids) > 1:
                raise DeviceError(self.name, f"several pmd cameras are connected {ids}: set the camera's serial")
            source = self.serial or ids[0]
        camera = manager.createCamera(source)
        camera.initialize()
        self._listener = _listener(roypy, self._frames)
        camera.registerDataListener(self._listener)
        self._camera = camera
        self._identity = DeviceIdentity(
            "flexx2", str(camera.getCameraName()), str(camera.getId()), f"Royale {roypy.getVersionString()}"
        )

    def close(self) -> None:
        """Stop capturing and unregister the listener (idempotent)."""
        self.safe_state()
        camera, self._camera = self._camera, None
        if camera is not None:
            with contextlib.suppress(Exception):
                camera.unregisterDataListener()

    def safe_state(self) -> None:
        """Stop capturing (the illumination stops with it); never raises."""
        if self._camera is not None:
            with contextlib.suppress(Exception):
                if self._camera.isCapturing():
                    self._camera.stopCapture()

    def settings(self) -> Mapping[str, Any]:
        """Use case and exposure as applied."""
        current = dict(self._settings)
        if self.playback is not None:
            current["playback"] = str(self.playback)
        return current

    def info(self) -> CameraInfo:
        """Sensor size (``getMaxSensorWidth``/``Height``), frame rate of the use case, datasheet FOV."""
        camera = self._ready()
        return CameraInfo(
            width=int(camera.getMaxSensorWidth()), height=int(camera.getMaxSensorHeight()), fov_deg=FOV_DEG,
            pixel_pitch_um=float("nan"), frame_rate_hz=float(camera.getFrameRate()),
            wavelength_nm=WAVELENGTH_NM, confidence_dtype="uint16",
        )

    def configure(self, exposure_us: float | None, settings: Mapping[str, Any]) -> None:
        """``use_case`` (one of ``getUseCases()``) and a manual exposure in µs; a recording takes neither."""
        camera = self._ready()
        unknown = sorted(set(settings) - set(SETTINGS))
        if unknown:
            raise DeviceError(self.name, f"unknown setting(s) {unknown}; this backend knows {list(SETTINGS)}")
        if self.playback is not None and (exposure_us is not None or settings):
            raise DeviceError(self.name, "a recording plays as recorded: no use case or exposure can be set")
        self.safe_state()
        applied: dict[str, Any] = {}
        if "use_case" in settings:
            use_cases = [str(u) for u in camera.getUseCases()]
            if settings["use_case"] not in use_cases:
                raise DeviceError(self.name, f"use case {settings['use_case']!r} is not one of {use_cases}")
            self._check(camera.setUseCase(settings["use_case"]), "setUseCase")
        if exposure_us is not None:
            self._check(camera.setExposureMode(self._roypy.ExposureMode_MANUAL), "setExposureMode")
            self._check(camera.setExposureTime(int(exposure_us)), "setExposureTime")
            applied["exposure_us"] = int(exposure_us)
        applied["use_case"] = str(camera.getCurrentUseCase())
        self._settings = applied

    def capture(self, count: int, first_index: int = 0) -> Iterator[Frame]:
        """Start capturing, collect ``count`` frames from the listener, stop capturing."""
        camera = self._ready()
        while not self._frames.empty():
            self._frames.get_nowait()
        self._check(camera.startCapture(), "startCapture")
        try:
            for k in range(first_index, first_index + count):
                try:
                    points, stamp_us = self._frames.get(timeout=self.timeout_s)
                except queue.Empty:
                    if not camera.isConnected():
                        raise CameraDisconnected(self.name, f"camera disconnected before frame {k}") from None
                    raise DroppedFrame(self.name, f"no frame {k} within {self.timeout_s} s") from None
                yield frame_from_points(points, stamp_us)
        finally:
            self.safe_state()

    def _ready(self) -> Any:
        if self._camera is None:
            raise not_connected(self.name)
        return self._camera

    def _check(self, status: Any, call: str) -> None:
        """Royale calls return a status, 0 = SUCCESS (``roypy.getErrorString``)."""
        if status not in (None, 0):
            raise DeviceError(self.name, f"{call} failed: {self._roypy.getErrorString(status)}")


def _listener(roypy: ModuleType, frames: queue.Queue[tuple[np.ndarray, float]]) -> Any:
    """An ``IDepthDataListener`` that copies every frame into ``frames`` (Royale calls it on its own thread)."""

    class StackListener(roypy.IDepthDataListener):  # type: ignore[misc, name-defined]
        """Royale calls ``onNewData`` for every captured frame."""

        def onNewData(self, data: Any) -> None:  # noqa: N802 - Royale's callback name
            """Queue the frame's points and time stamp (µs); the capture loop converts them."""
            frames.put((points_of(data), float(data.timeStamp)))

    return StackListener()
