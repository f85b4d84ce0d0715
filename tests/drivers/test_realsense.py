"""RealSense backend against real librealsense: frames injected into an ``rs.software_device``
(through a syncer, not a pipeline), recordings of it written by ``rs.recorder`` and played back,
and the real D435 recording played back from its ``.bag``."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pyrealsense2 as rs
import pytest

from drivers.camera.realsense import RealSenseCamera, depth_filters, frame_from_frameset
from drivers.errors import DeviceError
from drivers.protocols import DepthCamera
from tests.shared_data import shared_data

BAG = shared_data("realsense_d4xx_640x480.bag")
W, H, FPS = 64, 48, 30
FX, FY, PPX, PPY = 50.0, 51.0, 31.5, 23.25


IDENTITY = ("Intel RealSense D455", "233722070123", "5.16.0.1")
TEMPERATURES_C = {"asic": 41.5, "projector": 36.0}
"""The ASIC and projector temperatures the software camera reports (read-only options)."""
"""Product name, serial number and firmware the software camera reports (``rs.camera_info``)."""


class SoftwareCamera:
    """A librealsense software device with a depth (z16, 1 mm units) and a left IR (y8) stream;
    with ``record_to``, ``rs.recorder`` writes what it streams to that file (on :meth:`close`)."""

    def __init__(self, record_to: Path | None = None) -> None:
        self.device = rs.software_device()
        self.device.create_matcher(rs.matchers.default)
        for field, value in zip((rs.camera_info.name, rs.camera_info.serial_number, rs.camera_info.firmware_version),
                                IDENTITY, strict=True):
            self.device.register_info(field, value)
        self.sensor = self.device.add_sensor("Stereo Module")
        intrinsics = rs.intrinsics()
        intrinsics.width, intrinsics.height = W, H
        intrinsics.fx, intrinsics.fy, intrinsics.ppx, intrinsics.ppy = FX, FY, PPX, PPY
        intrinsics.model, intrinsics.coeffs = rs.distortion.brown_conrady, [0.0] * 5
        self.depth = self._stream(rs.stream.depth, 0, rs.format.z16, 2, intrinsics)
        self.ir = self._stream(rs.stream.infrared, 1, rs.format.y8, 1, intrinsics)
        self.sensor.add_read_only_option(rs.option.depth_units, 0.001)
        self.sensor.add_read_only_option(rs.option.asic_temperature, TEMPERATURES_C["asic"])
        self.sensor.add_read_only_option(rs.option.projector_temperature, TEMPERATURES_C["projector"])
        self.recorder = rs.recorder(str(record_to), self.device) if record_to is not None else None
        self.syncer = rs.syncer(100)  # a queue, so no frameset is dropped while the test feeds frames
        self.sensor.open([self.depth, self.ir])
        self.sensor.start(self.syncer)
        self._keep: list[np.ndarray] = []

    def _stream(self, kind: object, index: int, fmt: object, bpp: int, intrinsics: object) -> object:
        stream = rs.video_stream()
        stream.type, stream.index, stream.uid = kind, index, index
        stream.width, stream.height, stream.fps, stream.bpp, stream.fmt = W, H, FPS, bpp, fmt
        stream.intrinsics = intrinsics
        return self.sensor.add_video_stream(stream).as_video_stream_profile()

    def push(self, k: int, depth_mm: np.ndarray, ir: np.ndarray) -> None:
        """Inject frame ``k`` of both streams, time-stamped k frame periods (ms) apart."""
        for profile, pixels, bpp in ((self.depth, depth_mm.astype(np.uint16), 2), (self.ir, ir.astype(np.uint8), 1)):
            self._keep.append(pixels)  # librealsense reads the buffer after on_video_frame returns
            frame = rs.software_video_frame()
            frame.pixels, frame.bpp, frame.stride = pixels, bpp, bpp * W
            frame.timestamp, frame.domain, frame.frame_number = k * (1000 // FPS), rs.timestamp_domain.hardware_clock, k
            frame.profile = profile
            if bpp == 2:
                frame.depth_units = 0.001
            self.sensor.on_video_frame(frame)

    def framesets(self) -> list[object]:
        """Every frameset the syncer has ready that holds both depth and IR."""
        found = []
        while frames := self.syncer.poll_for_frames():
            if frames.get_depth_frame() and frames.get_infrared_frame(1):
                found.append(frames)
        return found

    def close(self) -> None:
        """Stop streaming; a recording is complete once its recorder is released."""
        self.sensor.stop()
        self.sensor.close()
        self.recorder = None


@pytest.fixture
def software() -> Iterator[SoftwareCamera]:
    camera = SoftwareCamera()
    yield camera
    camera.close()


def scene(k: int) -> tuple[np.ndarray, np.ndarray]:
    """A tilted plane (mm) with a hole of zeros, and an IR pattern."""
    u, v = np.meshgrid(np.arange(W), np.arange(H))
    depth = 1200 + 3 * u + 2 * v + k
    depth[10:14, 20:30] = 0
    return depth, (u * 3 + v + k) % 256


def write_recording(path: Path, frames: int) -> Path:
    """A recording at ``path`` of ``frames`` frames of :func:`scene`, as the software camera streamed
    them (name it ``.db3``: librealsense's recorder writes ROS 2 bags and refuses other names)."""
    camera = SoftwareCamera(record_to=path)
    for k in range(frames):
        camera.push(k, *scene(k))
    camera.close()
    return path


def synced(software: SoftwareCamera, count: int) -> list[object]:
    found: list[object] = []
    for k in range(count + 1):  # the syncer pairs streams from the second frame on
        software.push(k, *scene(k))
        found += software.framesets()
    return found


def test_point_cloud_is_the_pinhole_back_projection(software: SoftwareCamera) -> None:
    frames = synced(software, 3)
    assert len(frames) >= 2
    frame = frame_from_frameset(frames[-1], rs.pointcloud())
    k = frames[-1].get_depth_frame().get_frame_number()
    depth, ir = scene(k)
    u, v = np.meshgrid(np.arange(W), np.arange(H))
    valid = depth > 0
    assert frame.z.dtype == np.float32 and frame.z.shape == (H, W)
    assert np.allclose(frame.z[valid], depth[valid], atol=1e-3)
    assert np.allclose(frame.x[valid], ((u - PPX) / FX * depth)[valid], atol=1e-3)
    assert np.allclose(frame.y[valid], ((v - PPY) / FY * depth)[valid], atol=1e-3)
    for channel in (frame.x, frame.y, frame.z):
        assert np.isnan(channel[~valid]).all()
    assert np.array_equal(frame.intensity, ir.astype(np.float32))
    assert np.array_equal(frame.confidence, valid.astype(np.float32))
    assert frame.timestamp == pytest.approx(k * (1000 // FPS) / 1000.0)


def test_post_processing_keeps_the_geometry(software: SoftwareCamera) -> None:
    frames = synced(software, 4)
    filters = depth_filters(rs)
    for frameset in frames:
        frame = frame_from_frameset(frameset, rs.pointcloud(), filters)
    valid = np.isfinite(frame.z)
    u, v = np.meshgrid(np.arange(W), np.arange(H))
    depth, _ = scene(frames[-1].get_depth_frame().get_frame_number())
    assert valid.mean() > 0.9
    assert np.allclose(frame.z[valid], depth[valid], rtol=0.01)  # a smooth plane survives the filters
    assert np.allclose(frame.x[valid], ((u - PPX) / FX * frame.z)[valid], atol=1e-2)


def test_a_frameset_without_ir_is_a_dropped_frame(software: SoftwareCamera) -> None:
    software.push(0, *scene(0))
    depth_only = software.syncer.poll_for_frames()
    assert depth_only.get_depth_frame() and not depth_only.get_infrared_frame(1)
    with pytest.raises(DeviceError, match="without the left infrared frame"):
        frame_from_frameset(depth_only, rs.pointcloud())
    assert np.isnan(frame_from_frameset(depth_only, rs.pointcloud(), infrared=False).intensity).all()


# ------------------------------------------------------------------ the real recording
@pytest.fixture
def playback() -> Iterator[RealSenseCamera]:
    camera = RealSenseCamera(playback=BAG)
    camera.connect()
    yield camera
    camera.close()


def test_recording_identity_and_info(playback: RealSenseCamera) -> None:
    assert isinstance(playback, DepthCamera)
    identity = playback.identity()
    assert (identity.model, identity.serial, identity.firmware) == ("Intel RealSense D435", "728612070259", "05.09.14.00")
    info = playback.info()
    assert (info.width, info.height, info.frame_rate_hz, info.pixel_pitch_um) == (640, 480, 6.0, 3.0)
    fov_h = np.degrees(2 * np.arctan(320 / 390.431))
    assert info.fov_deg[0] == pytest.approx(fov_h, abs=0.05)


def test_every_stack_starts_at_the_beginning_of_the_recording(playback: RealSenseCamera) -> None:
    playback.configure(None, {})
    first = [f.meta["frame_number"] for f in playback.capture(2)]
    again = [f.meta["frame_number"] for f in playback.capture(1)]
    resumed = [f.meta["frame_number"] for f in playback.capture(1, first_index=1)]
    assert (first, again, resumed) == ([169, 170], [169], [170])


def test_a_recording_gives_the_temperatures_recorded_with_it(tmp_path: Path) -> None:
    camera = RealSenseCamera(playback=write_recording(tmp_path / "warm.db3", 3))
    camera.connect()
    try:
        assert camera.temperatures_c() == TEMPERATURES_C
    finally:
        camera.close()


def test_the_real_recording_holds_its_cameras_temperatures(playback: RealSenseCamera) -> None:
    temperatures = playback.temperatures_c()
    assert set(temperatures) == {"asic", "projector"}
    assert all(15.0 < t < 60.0 for t in temperatures.values())  # a D435 in a room, not a default of 0


def test_a_stack_longer_than_the_recording_is_an_error(playback: RealSenseCamera) -> None:
    with pytest.raises(DeviceError, match="recording ended after 2 frame"):
        list(playback.capture(3))


def test_a_recording_takes_filters_but_no_device_options(playback: RealSenseCamera) -> None:
    playback.configure(None, {"filters": True})
    assert np.isfinite(next(iter(playback.capture(1))).z).mean() > 0.9
    with pytest.raises(DeviceError, match=r"cannot set \['projector', 'exposure_us'\] on a recording"):
        playback.configure(1000.0, {"projector": False})
    with pytest.raises(DeviceError, match=r"unknown setting\(s\) \['gain'\]"):
        playback.configure(None, {"gain": 2})


def test_a_written_recording_plays_back_the_frames_streamed(tmp_path: Path) -> None:
    camera = RealSenseCamera(playback=write_recording(tmp_path / "scene.db3", 3))
    camera.connect()
    try:
        identity = camera.identity()
        assert (identity.model, identity.serial, identity.firmware) == IDENTITY
        camera.configure(None, {})
        frames = list(camera.capture(3))
        assert [frame.meta["frame_number"] for frame in frames] == [0, 1, 2]
        for k, frame in enumerate(frames):
            depth, ir = scene(k)
            valid = depth > 0
            assert np.allclose(frame.z[valid], depth[valid], atol=1e-3) and np.isnan(frame.z[~valid]).all()
            assert np.array_equal(frame.intensity, ir.astype(np.float32))
        with pytest.raises(DeviceError, match="recording ended after 3 frame"):
            list(camera.capture(4))
    finally:
        camera.close()


def test_missing_files_and_devices() -> None:
    with pytest.raises(DeviceError, match="recording /nonexistent.bag does not exist"):
        RealSenseCamera(playback="/nonexistent.bag").connect()
    with pytest.raises(DeviceError, match="not a readable RealSense recording"):
        RealSenseCamera(playback=__file__).connect()
    if not rs.context().query_devices().size():
        with pytest.raises(DeviceError, match="no RealSense device is connected"):
            RealSenseCamera(serial="123").connect()
