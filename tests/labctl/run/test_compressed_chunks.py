"""Frames compressed beside the capture (labctl.run.chunks): the file is the one HDF5's filter pipeline writes,
and a failed compression stops the step with a clear error, leaving the file valid."""

import threading

import h5py
import hdf5plugin  # noqa: F401 (registers the Blosc filter with h5py, as any reader does)
import numpy as np
import pytest

import labctl.run.chunks as chunks
from drivers.protocols import CameraInfo, DeviceIdentity, Frame
from labctl.run.chunks import THREAD_NAME, CompressionFailed
from labctl.run.compression import COMPRESSIONS, dataset_options
from labctl.run.store import CHANNELS, RunReader, RunWriter
from procedures.steps import Step

H, W = 48, 64
SENTINEL = -12345.0


def camera(confidence_dtype: str) -> CameraInfo:
    return CameraInfo(width=W, height=H, fov_deg=(67.0, 51.0), pixel_pitch_um=10.0, frame_rate_hz=30.0,
                      wavelength_nm=940.0, confidence_dtype=confidence_dtype)


def make_run(path, confidence_dtype="uint16", compression="blosc-lz4", steps=2):
    return RunWriter.create(
        path, campaign_toml="", simulated=False, devices={"camera": (DeviceIdentity("t", "cam", "S1", "1"), {})},
        camera=camera(confidence_dtype), steps=steps, compression=compression,
    )


def frames(confidence_dtype: str, n: int = 6, size: tuple[int, int] = (H, W)) -> list[Frame]:
    """Noisy depth with NaN holes, a frame without any valid pixel, a constant one, and noise that does not
    compress (stored unfiltered by the filter): every kind of chunk the filter makes, frames of ``size``."""
    h, w = size
    rng = np.random.default_rng(7)
    out = []
    for k in range(n):
        z = (1500 + rng.standard_normal((h, w))).astype(np.float32)
        z[rng.random((h, w)) < 0.2] = np.nan
        if k == 1:
            z[:] = np.nan
        if k == 2:
            z[:] = 800.0
        intensity = rng.random((h, w), np.float32) if k != 2 else np.zeros((h, w), np.float32)
        if k == 3:
            intensity = rng.integers(0, 2**32, (h, w), dtype=np.uint32).view(np.float32)
        if confidence_dtype == "uint16":
            confidence = rng.integers(0, 65536, (h, w), dtype=np.uint16)
        else:
            confidence = rng.random((h, w), np.float32)
        out.append(Frame(z * 0.1, z * -0.2, z, intensity, confidence, timestamp=k / 30))
    return out


def write_step(run: RunWriter, index: int, stack: list[Frame]) -> None:
    writer = run.begin_step(Step(index=index, procedure="depth_sweep", target="wall", frames=len(stack)), None)
    for k, f in enumerate(stack):
        writer.write(k, f)
    writer.commit({})


def compress_threads() -> set[threading.Thread]:
    return {t for t in threading.enumerate() if t.name.startswith(THREAD_NAME)}


@pytest.mark.parametrize("compression", COMPRESSIONS)
@pytest.mark.parametrize("confidence_dtype", ["uint16", "float32"])
def test_file_reads_back_bit_exact_with_plain_h5py(tmp_path, compression, confidence_dtype):
    """Every bit of every channel, NaN frames included, read by h5py with hdf5plugin's filters alone."""
    path = tmp_path / "r.h5"
    stack = frames(confidence_dtype)
    run = make_run(path, confidence_dtype, compression)
    write_step(run, 0, stack)
    run.set_status("complete")
    run.close()
    with h5py.File(path, "r") as f:
        g = f["steps/00000_depth_sweep"]
        for name in CHANNELS:
            expected = np.stack([getattr(frame, name) for frame in stack])
            stored = g[name][...]
            assert stored.dtype == expected.dtype and g[name].chunks == (1, H, W), name
            assert stored.tobytes() == expected.tobytes(), name
        np.testing.assert_array_equal(g["timestamp"][...], [k / 30 for k in range(len(stack))])


@pytest.mark.parametrize("confidence_dtype", ["uint16", "float32"])
def test_chunks_are_those_hdf5s_blosc_filter_writes(tmp_path, confidence_dtype):
    """The same filter declaration, and chunk for chunk the bytes and filter mask that h5py writing through
    HDF5's filter pipeline (hdf5plugin's Blosc filter) stores for the same frames."""
    stack = frames(confidence_dtype)
    run = make_run(tmp_path / "r.h5", confidence_dtype)
    write_step(run, 0, stack)
    run.close()
    with h5py.File(tmp_path / "r.h5", "r") as ours, h5py.File(tmp_path / "reference.h5", "w") as reference:
        masks = set()
        for name in CHANNELS:
            expected = np.stack([getattr(frame, name) for frame in stack])
            ref = reference.create_dataset(name, shape=expected.shape, dtype=expected.dtype, chunks=(1, H, W),
                                           **dataset_options("blosc-lz4"))
            for k in range(len(stack)):
                ref[k] = expected[k]
            reference.flush()
            stored = ours["steps/00000_depth_sweep"][name]
            assert stored.id.get_create_plist().get_filter(0) == ref.id.get_create_plist().get_filter(0)
            for k in range(len(stack)):
                mask, chunk = stored.id.read_direct_chunk((k, 0, 0))
                assert (mask, chunk) == ref.id.read_direct_chunk((k, 0, 0)), (name, k)
                masks.add(mask)
        assert masks == {0, 1}  # compressed chunks, and chunks the filter left unfiltered


def test_stack_before_commit_holds_every_frame_written(tmp_path):
    stack = frames("uint16")
    run = make_run(tmp_path / "r.h5")
    writer = run.begin_step(Step(index=0, procedure="alignment", target="wall", frames=len(stack)), None)
    for k, f in enumerate(stack):
        writer.write(k, f)
    assert writer.stack("z").tobytes() == np.stack([f.z for f in stack]).tobytes()
    run.close()


def test_failed_compression_stops_the_step_with_a_clear_error_and_leaves_the_file_valid(tmp_path, monkeypatch):
    path = tmp_path / "r.h5"
    good = frames("uint16", 3)
    before = compress_threads()
    run = make_run(path)
    write_step(run, 0, good)
    compress = chunks.compress_chunk

    def failing(data, compression):
        if data.dtype == np.float32 and data.flat[0] == SENTINEL:
            raise RuntimeError("forced failure")
        return compress(data, compression)

    monkeypatch.setattr(chunks, "compress_chunk", failing)
    bad = frames("uint16", 5)
    for name in ("x", "y", "z", "intensity"):
        getattr(bad[2], name).flat[0] = SENTINEL
    writer = run.begin_step(Step(index=1, procedure="depth_sweep", target="wall", frames=len(bad)), None)
    failure = r"compressing frame 2's x of step 00001_depth_sweep \(blosc-lz4\) failed: RuntimeError: forced failure"
    with pytest.raises(CompressionFailed, match=failure):
        for k, f in enumerate(bad):
            writer.write(k, f)
        writer.commit({})
    with pytest.raises(CompressionFailed, match=f"{failure}; the step cannot be completed"):
        writer.commit({})
    run.set_status("aborted", "compression failed")
    run.close()
    assert compress_threads() <= before
    with RunReader(path) as reader:
        assert reader.attrs["status"] == "aborted"
        assert [s.step_id for s in reader.steps()] == ["00000_depth_sweep"]
        assert reader.step("00000_depth_sweep").read("z").tobytes() == np.stack([f.z for f in good]).tobytes()
    resumed = RunWriter(path)
    assert resumed.discard_incomplete() == ["00001_depth_sweep"]
    resumed.close()


def test_closing_mid_step_stops_the_threads_and_the_step_stays_unfinished(tmp_path):
    """An interrupted step (Ctrl-C, a device fault): the run is marked and closed with chunks still queued."""
    path = tmp_path / "r.h5"
    before = compress_threads()
    run = make_run(path)
    writer = run.begin_step(Step(index=0, procedure="depth_sweep", target="wall", frames=6), None)
    for k, f in enumerate(frames("uint16", 4)):
        writer.write(k, f)
    run.set_status("aborted", "interrupted")
    run.close()
    assert compress_threads() <= before
    with RunReader(path) as reader:
        assert reader.attrs["status"] == "aborted" and reader.steps() == []
