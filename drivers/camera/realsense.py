"""Intel RealSense D4xx active-stereo cameras, live or from a ``.bag`` / ``.db3`` recording, via pyrealsense2.

librealsense Python API (https://intelrealsense.github.io/librealsense/python_docs/):
``rs.pipeline`` / ``rs.config`` stream depth (z16) and the left infrared imager
(``rs.stream.infrared``, index 1); ``rs.pointcloud.calculate`` back-projects a depth
frame through the stream's intrinsics into vertices in metres; the post-processing
blocks ``rs.disparity_transform``, ``rs.spatial_filter`` and ``rs.temporal_filter``
filter depth; sensor options ``rs.option.exposure`` (µs), ``enable_auto_exposure``,
``emitter_enabled``, ``laser_power`` and ``visual_preset`` configure the depth module.
A recording plays through ``rs.config.enable_device_from_file(path, repeat_playback=False)``
with ``playback.set_real_time(False)`` set on the device the config resolves, before ``pipeline.start``,
so no frame is dropped (in real-time playback the pipeline drops a frame the reader is late for).

Frames: x, y, z in mm from the SDK's point cloud, NaN where the depth is 0 (no match);
intensity = the left IR image (NaN if a recording has no IR stream); confidence = 1
where the depth is valid, 0 elsewhere (RealSense delivers no confidence map).
"""

from __future__ import annotations

import contextlib
import time
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path
from types import ModuleType
from typing import Any

import numpy as np

from drivers.camera.frames import import_sdk, invalidate
from drivers.device import CameraDevice
from drivers.errors import CameraDisconnected, DeviceError, DroppedFrame, not_connected
from drivers.libusb import ensure_libusb
from drivers.protocols import CameraInfo, DeviceIdentity, Frame

INSTALL = "pip install pyrealsense2 libusb-package (or the system package libusb-1.0-0 instead of libusb-package)"
WAVELENGTH_NM = 850.0
"""D4xx IR projector and IR-pass imagers (Intel RealSense D400 Series datasheet, "Projector")."""
PIXEL_PITCH_UM = {"D415": 1.4, "D435": 3.0, "D455": 3.0, "D457": 3.0}
"""Depth imager pixel size by product (D400 Series datasheet, "Depth Module Imager": OV2740 1.4 µm,
OV9282/OV9782 3 µm)."""
VISUAL_PRESETS = ("custom", "default", "hand", "high_accuracy", "high_density", "medium_density")
SETTINGS = ("mode", "projector", "laser_power", "filters")
"""Campaign ``settings`` keys this backend understands."""


def sdk(device: str = "RealSense camera") -> ModuleType:
    """pyrealsense2, with libusb resolved first (drivers.libusb)."""
    ensure_libusb()
    return import_sdk("pyrealsense2", device, INSTALL)


def depth_filters(rs: ModuleType) -> list[Any]:
    """Post-processing in the disparity domain, as librealsense recommends (rs-post-processing):
    depth→disparity, spatial (edge-preserving), temporal, disparity→depth. Decimation and hole
    filling are left out: they change the resolution or invent depth."""
    return [rs.disparity_transform(True), rs.spatial_filter(), rs.temporal_filter(), rs.disparity_transform(False)]


def frame_from_frameset(
    frames: Any,
    pointcloud: Any,
    filters: Sequence[Any] = (),
    infrared: bool = True,
    device: str = "RealSense camera",
) -> Frame:
    """One :class:`Frame` from a librealsense frameset (depth and, with ``infrared``, IR index 1).

    The depth frame runs through ``filters``, then ``pointcloud.calculate`` gives vertices in
    metres (librealsense ``rs2_deproject_pixel_to_point`` per pixel), returned in mm.
    """
    depth = frames.get_depth_frame()
    if not depth:
        raise DroppedFrame(device, "frameset without a depth frame")
    for block in filters:
        depth = block.process(depth)
    depth = depth.as_depth_frame()
    height, width = depth.get_height(), depth.get_width()
    vertices = np.asanyarray(pointcloud.calculate(depth).get_vertices()).view(np.float32).reshape(height, width, 3)
    raw = np.asanyarray(depth.get_data())
    x, y, z = invalidate(vertices[..., 0] * 1000.0, vertices[..., 1] * 1000.0, vertices[..., 2] * 1000.0, raw == 0)
    if infrared:
        ir = frames.get_infrared_frame(1)
        if not ir:
            raise DroppedFrame(device, "frameset without the left infrared frame")
        intensity = np.asanyarray(ir.get_data()).astype(np.float32)
    else:
        intensity = np.full((height, width), np.nan, np.float32)
    confidence = (raw != 0).astype(np.float32)
    return Frame(x, y, z, intensity, confidence, timestamp=depth.get_timestamp() / 1000.0,
                 meta={"frame_number": depth.get_frame_number()})


class RealSenseCamera(CameraDevice):
    """A RealSense D4xx as a :class:`~drivers.protocols.DepthCamera`.

    Live (``serial``: which camera, default the only one) it streams depth and left IR at
    ``width`` × ``height`` and ``fps``; with ``playback`` it plays a ``.bag`` or ``.db3`` recording instead,
    every stack from the recording's first frame (a stack longer than the recording is an
    error). ``timeout_s`` bounds the wait for a frame.
    """

    def __init__(
        self,
        serial: str | None = None,
        playback: str | Path | None = None,
        *,
        width: int = 640,
        height: int = 480,
        fps: int = 30,
        timeout_s: float = 5.0,
        flush_frames: int = 2,
    ) -> None:
        self.serial = serial
        self.playback = Path(playback) if playback is not None else None
        self.width, self.height, self.fps = width, height, fps
        self.timeout_s = timeout_s
        self.flush_frames = flush_frames
        super().__init__(
            f"RealSense playback of {self.playback}" if self.playback else f"RealSense camera {serial or ''}".strip()
        )
        self._rs: ModuleType | None = None
        self._pipeline: Any = None
        self._profile: Any = None
        self._serial: str | None = None
        self._delivered = 0
        self._infrared = True
        self._pointcloud: Any = None
        self._filters: list[Any] = []
        self._settings: dict[str, Any] = {}
        self._exposure_us: float | None = None

    # -- DepthCamera ----------------------------------------------------------------

    def connect(self) -> None:
        """Find the camera (``rs.context().query_devices()``) and start streaming, or check the
        recording (``rs.config.resolve``) and read its streams. The identity is product name, serial
        number and firmware from ``rs.camera_info`` (a recording keeps the recorded camera's)."""
        if self._profile is not None:
            return
        rs = self._rs = sdk()
        self._pointcloud = rs.pointcloud()
        if self.playback is not None:
            self._inspect_recording(rs)
        else:
            self._find_device(rs)
            self._start()
        device = self._profile.get_device()
        info = rs.camera_info
        self._identity = DeviceIdentity(
            backend="realsense",
            model=device.get_info(info.name),
            serial=device.get_info(info.serial_number),
            firmware=device.get_info(info.firmware_version) if device.supports(info.firmware_version) else "",
        )

    def close(self) -> None:
        """Stop streaming and release the device or file (idempotent)."""
        self.safe_state()
        self._pipeline = None
        self._profile = None
        self._identity = None

    def safe_state(self) -> None:
        """Stop streaming (projector and imagers go idle); never raises."""
        if self._pipeline is not None:
            with contextlib.suppress(Exception):
                self._pipeline.stop()
        self._pipeline = None

    def settings(self) -> Mapping[str, Any]:
        """Applied settings, exposure and (for recordings) the file played."""
        current = dict(self._settings)
        if self._exposure_us is not None:
            current["exposure_us"] = self._exposure_us
        if self.playback is not None:
            current["playback"] = str(self.playback)
        return current

    def info(self) -> CameraInfo:
        """Resolution, FOV (``rs.rs2_fov`` of the depth intrinsics) and frame rate of the depth stream."""
        rs = self._rs
        if rs is None or self._profile is None:
            raise not_connected(self.name)
        stream = self._profile.get_stream(rs.stream.depth).as_video_stream_profile()
        fov = rs.rs2_fov(stream.get_intrinsics())
        model = self.identity().model
        pitch = next((value for key, value in PIXEL_PITCH_UM.items() if key in model), float("nan"))
        return CameraInfo(
            width=stream.width(), height=stream.height(), fov_deg=(float(fov[0]), float(fov[1])),
            pixel_pitch_um=pitch, frame_rate_hz=float(stream.fps()), wavelength_nm=WAVELENGTH_NM,
            confidence_dtype="float32",
        )

    def temperatures_c(self) -> dict[str, float]:
        """The depth module's ASIC and projector temperatures (``rs.option.asic_temperature``,
        ``projector_temperature``) where a sensor of the device supports them; a recording gives the values
        recorded with it."""
        rs = self._ready()
        options = {"asic": rs.option.asic_temperature, "projector": rs.option.projector_temperature}
        found: dict[str, float] = {}
        for sensor in self._profile.get_device().query_sensors():
            for name, option in options.items():
                if name not in found and sensor.supports(option):
                    with contextlib.suppress(RuntimeError):
                        found[name] = float(sensor.get_option(option))
        return found

    def configure(self, exposure_us: float | None, settings: Mapping[str, Any]) -> None:
        """Exposure (µs, auto exposure off) and ``settings``: ``mode`` (visual preset), ``projector``
        (emitter on/off), ``laser_power`` (mW), ``filters`` (post-processing on/off).

        A recording only takes ``filters``: its device options were fixed when it was recorded.
        """
        rs = self._ready()
        unknown = sorted(set(settings) - set(SETTINGS))
        if unknown:
            raise DeviceError(self.name, f"unknown setting(s) {unknown}; this backend knows {list(SETTINGS)}")
        device_options = [key for key in ("mode", "projector", "laser_power") if key in settings]
        if self.playback is not None and (exposure_us is not None or device_options):
            fixed = device_options + (["exposure_us"] if exposure_us is not None else [])
            raise DeviceError(self.name, f"cannot set {fixed} on a recording; only 'filters' applies to playback")
        if self.playback is None:
            sensor = self._profile.get_device().first_depth_sensor()
            if "mode" in settings:
                mode = str(settings["mode"])
                if mode not in VISUAL_PRESETS:
                    raise DeviceError(self.name, f"mode {mode!r} is not a visual preset; use one of {list(VISUAL_PRESETS)}")
                self._set_option(sensor, rs.option.visual_preset, float(getattr(rs.rs400_visual_preset, mode)))
            if "projector" in settings:
                self._set_option(sensor, rs.option.emitter_enabled, 1.0 if settings["projector"] else 0.0)
            if "laser_power" in settings:
                self._set_option(sensor, rs.option.laser_power, float(settings["laser_power"]))
            if exposure_us is not None:
                self._set_option(sensor, rs.option.enable_auto_exposure, 0.0)
                self._set_option(sensor, rs.option.exposure, float(exposure_us))
            self._exposure_us = float(sensor.get_option(rs.option.exposure))
        self._filters = depth_filters(rs) if settings.get("filters", False) else []
        self._settings = dict(settings)

    def capture(self, count: int, first_index: int = 0) -> Iterator[Frame]:
        """Yield ``count`` frames (``pipeline.try_wait_for_frames``); a recording restarts at its first
        frame for every stack and skips ``first_index`` frames."""
        self._ready()
        if self.playback is not None:
            self.safe_state()  # every stack plays the recording from its start
            self._start()
            skip = first_index
        else:
            if self._pipeline is None:
                self._start()
            skip = self.flush_frames  # frames queued while the lab moved are stale
        for _ in range(skip):
            self._next_frameset()
        for _ in range(count):
            frames = self._next_frameset()
            yield frame_from_frameset(frames, self._pointcloud, self._filters, self._infrared, self.name)

    # -- helpers ----------------------------------------------------------------------

    def _ready(self) -> ModuleType:
        if self._rs is None or self._profile is None:
            raise not_connected(self.name)
        return self._rs

    def _config(self) -> Any:
        """A fresh ``rs.config``: librealsense keeps a playback device's position in its config."""
        rs = self._rs
        config = rs.config()
        if self.playback is not None:
            config.enable_device_from_file(str(self.playback), False)
            config.enable_stream(rs.stream.depth)
            if self._infrared:
                config.enable_stream(rs.stream.infrared, 1)
        else:
            config.enable_device(self._serial)
            config.enable_stream(rs.stream.depth, self.width, self.height, rs.format.z16, self.fps)
            config.enable_stream(rs.stream.infrared, 1, self.width, self.height, rs.format.y8, self.fps)
        return config

    def _inspect_recording(self, rs: ModuleType) -> None:
        if not self.playback.is_file():
            raise DeviceError(self.name, f"recording {self.playback} does not exist")
        config = rs.config()
        config.enable_device_from_file(str(self.playback), False)
        try:
            profile = config.resolve(rs.pipeline_wrapper(rs.pipeline()))
        except RuntimeError as exc:
            raise DeviceError(self.name, f"{self.playback} is not a readable RealSense recording: {exc}") from exc
        sensors = profile.get_device().query_sensors()
        streams = {(p.stream_type(), p.stream_index()) for s in sensors for p in s.get_stream_profiles()}
        if not any(kind == rs.stream.depth for kind, _ in streams):
            raise DeviceError(self.name, f"{self.playback} holds no depth stream")
        self._infrared = (rs.stream.infrared, 1) in streams
        self._profile = profile

    def _find_device(self, rs: ModuleType) -> None:
        serials = [d.get_info(rs.camera_info.serial_number) for d in rs.context().query_devices()]
        if not serials:
            raise DeviceError(self.name, "no RealSense device is connected (librealsense finds none on USB)")
        if self.serial is not None and self.serial not in serials:
            raise DeviceError(self.name, f"no RealSense device with serial {self.serial}; connected: {serials}")
        if self.serial is None and len(serials) > 1:
            raise DeviceError(self.name, f"several RealSense devices are connected {serials}: set the camera's serial")
        self._serial = self.serial or serials[0]

    def _start(self) -> None:
        rs = self._rs
        pipeline = rs.pipeline()
        config = self._config()
        try:
            if self.playback is not None:
                # non-real-time before the first frame: the config keeps the playback device it resolves, and
                # start() plays that one; switched after start(), a real-time first frame could be dropped
                config.resolve(rs.pipeline_wrapper(pipeline)).get_device().as_playback().set_real_time(False)
            self._profile = pipeline.start(config)
        except RuntimeError as exc:
            raise DeviceError(self.name, f"cannot start streaming: {exc}") from exc
        self._pipeline = pipeline
        self._delivered = 0

    def _set_option(self, sensor: Any, option: Any, value: float) -> None:
        try:
            sensor.set_option(option, value)
        except RuntimeError as exc:
            raise DeviceError(self.name, f"cannot set {option} to {value}: {exc}") from exc

    def _next_frameset(self) -> Any:
        rs = self._rs
        deadline = time.monotonic() + self.timeout_s
        while True:
            try:
                ok, frames = self._pipeline.try_wait_for_frames(20)
                # "stopped" before the first frame may also be a playback whose reader has not started yet
                # (seen on a loaded machine): only the frame timeout ends a recording that delivered nothing
                ended = (
                    not ok
                    and self.playback is not None
                    and (self._delivered > 0 or time.monotonic() > deadline)
                    and self._profile.get_device().as_playback().current_status() == rs.playback_status.stopped
                )
                if ended:  # frames still queued arrive within a moment
                    ok, frames = self._pipeline.try_wait_for_frames(100)
            except RuntimeError as exc:
                raise CameraDisconnected(self.name, f"streaming failed: {exc}") from exc
            if ok:
                self._delivered += 1
                return frames
            if ended:
                raise DeviceError(
                    self.name,
                    f"the recording ended after {self._delivered} frame(s): a stack from it holds at most that many",
                )
            if time.monotonic() > deadline:
                raise DroppedFrame(self.name, f"no frame within {self.timeout_s} s")
