"""Stacks read chunk by chunk and decompressed by Blosc (labctl.run.chunk_read) are the arrays h5py reads,
bit for bit, for every layout: the writer's (Blosc or none, frames missing, chunks stored unfiltered) through the
direct path, anything else through h5py."""

import h5py
import hdf5plugin
import numpy as np
import pytest

from drivers.protocols import CameraInfo, DeviceIdentity
from labctl.run.chunk_read import direct_readable, read_stack
from labctl.run.compression import COMPRESSIONS
from labctl.run.store import CHANNELS, RunWriter
from procedures.steps import Step
from tests.labctl.run.test_compressed_chunks import frames

H, W = 37, 53  # odd frame sizes


def same(a: np.ndarray, b: np.ndarray) -> bool:
    return a.shape == b.shape and a.dtype == b.dtype and a.tobytes() == b.tobytes()


@pytest.mark.parametrize("compression", COMPRESSIONS)
def test_the_writers_stacks_read_chunk_by_chunk_are_h5pys(tmp_path, compression):
    """A complete step and one with only half of its frames written (the rest never allocated: h5py gives the fill
    value), every channel, read into fresh and reused buffers."""
    path = tmp_path / "run.h5"
    camera = CameraInfo(W, H, (67.0, 51.0), 10.0, 30.0, 940.0, "uint16")
    run = RunWriter.create(path, campaign_toml="", simulated=True, camera=camera, steps=2, compression=compression,
                           devices={"camera": (DeviceIdentity("t", "cam", "S1", "1"), {})})
    for index, written in ((0, 6), (1, 3)):
        writer = run.begin_step(Step(index=index, procedure="depth_sweep", target="wall", frames=6), None)
        for k, frame in enumerate(frames("uint16", 6, (H, W))[:written]):
            writer.write(k, frame)
        if written == 6:
            writer.commit({})
    run.close()
    with h5py.File(path, "r") as f:
        for group in f["steps"].values():
            for channel in CHANNELS:
                dataset = group[channel]
                expected = dataset[()]
                out = np.full(dataset.shape, 7, dataset.dtype)
                assert direct_readable(dataset, out)
                assert same(read_stack(dataset, out), expected)
                assert same(read_stack(dataset, out), expected)  # into the same buffer again


LAYOUTS = {
    "blosc, frame chunks": dict(chunks=(1, H, W), **hdf5plugin.Blosc(cname="lz4", clevel=5, shuffle=1)),
    "blosc zstd, frame chunks": dict(chunks=(1, H, W), **hdf5plugin.Blosc(cname="zstd", clevel=3, shuffle=1)),
    "none, frame chunks": dict(chunks=(1, H, W)),
    "blosc, two frames a chunk": dict(chunks=(2, H, W), **hdf5plugin.Blosc(cname="lz4", clevel=5, shuffle=1)),
    "blosc, partial edge chunks": dict(chunks=(1, 16, 32), **hdf5plugin.Blosc(cname="lz4", clevel=5, shuffle=1)),
    "gzip, frame chunks": dict(chunks=(1, H, W), compression="gzip", shuffle=True),
    "contiguous": dict(),
}


@pytest.mark.parametrize("layout", list(LAYOUTS))
@pytest.mark.parametrize("dtype", [np.float32, np.uint16, ">f4"])
def test_every_layout_reads_as_h5py_reads_it(tmp_path, layout, dtype):
    """Datasets written through h5py's filter pipeline in layouts the writer does not make (they go through h5py)
    and in those it makes (read chunk by chunk), frames 2 and 4 of 5 never written (fill value)."""
    rng = np.random.default_rng(5)
    data = (1000 * rng.random((5, H, W))).astype(dtype)
    path = tmp_path / "layout.h5"
    with h5py.File(path, "w") as f:
        dataset = f.create_dataset("stack", shape=data.shape, dtype=dtype, fillvalue=3, **LAYOUTS[layout])
        for k in (0, 1, 3):
            dataset[k] = data[k]
    with h5py.File(path, "r") as f:
        dataset = f["stack"]
        expected = dataset[()]
        out = np.empty(dataset.shape, dataset.dtype)
        assert direct_readable(dataset, out) == (layout in ("blosc, frame chunks", "blosc zstd, frame chunks",
                                                            "none, frame chunks"))
        assert same(read_stack(dataset, out), expected)


def test_a_buffer_of_another_type_is_read_into_by_h5py(tmp_path):
    """An output array of another type (h5py converts) is not read chunk by chunk."""
    path = tmp_path / "stack.h5"
    data = np.arange(3 * H * W, dtype=np.float32).reshape(3, H, W)
    with h5py.File(path, "w") as f:
        f.create_dataset("stack", data=data, chunks=(1, H, W), **hdf5plugin.Blosc(cname="lz4", clevel=5, shuffle=1))
    with h5py.File(path, "r") as f:
        dataset = f["stack"]
        as_double = np.empty(data.shape, np.float64)
        assert not direct_readable(dataset, as_double)
        assert same(read_stack(dataset, as_double), dataset[()].astype(np.float64))
