"""Reading a stack of frames chunk by chunk, past HDF5's filter pipeline (docs/runfile.md, Storage).

The run file stores each frame of a channel as one chunk (labctl.run.chunks), so :func:`read_stack` reads each
frame's chunk as it is stored (HDF5's direct chunk read: no filter pipeline, no chunk cache) and decompresses it
with the ``blosc`` package straight into the frame of the output array (Blosc releases the GIL): no intermediate
buffer and copy per chunk, about 9 % less CPU than h5py's read of the same stacks (docs/benchmarks.md). The bytes are those the
Blosc filter would give (the same C-Blosc format, labctl.run.compression).

Only the layout the writer makes is read this way: a chunked dataset of chunks of one whole frame, with no filter
or the Blosc filter alone, read into an array of its own shape and type. Anything else, a frame whose chunk was
never written (HDF5 gives the fill value) and a chunk that is not a Blosc buffer of one frame go through h5py.
"""

from __future__ import annotations

import blosc
import h5py
import numpy as np

from labctl.run.compression import FILTER_SKIPPED

#: HDF5's registered id of the Blosc filter
BLOSC_FILTER = 32001
#: bytes of a Blosc 1.x buffer's header, which states the size of the data it holds
BLOSC_HEADER = 16


def _filters(dataset: h5py.Dataset) -> list[int]:
    plist = dataset.id.get_create_plist()
    return [plist.get_filter(i)[0] for i in range(plist.get_nfilters())]


def direct_readable(dataset: h5py.Dataset, out: np.ndarray) -> bool:
    """Whether :func:`read_stack` reads ``dataset`` into ``out`` chunk by chunk: chunks of one whole frame (the
    dataset's first axis), no filter or Blosc alone, ``out`` an array of its shape and type."""
    if dataset.ndim < 2 or dataset.chunks != (1, *dataset.shape[1:]):
        return False
    if out.shape != dataset.shape or out.dtype != dataset.dtype:
        return False
    return _filters(dataset) in ([], [BLOSC_FILTER])


def read_stack(dataset: h5py.Dataset, out: np.ndarray) -> np.ndarray:
    """The whole of ``dataset`` in ``out`` (C-contiguous, as h5py's ``read_direct`` takes it; returned), the same
    array h5py reads: where :func:`direct_readable`, each frame's chunk read as stored and decompressed into its
    frame; else, and for a frame whose chunk was never written (h5py gives the fill value) or is not one frame's
    data, read by h5py."""
    if not direct_readable(dataset, out):
        dataset.read_direct(out)
        return out
    blosc_filter = _filters(dataset) == [BLOSC_FILTER]
    origin = (0,) * (dataset.ndim - 1)
    for k in range(dataset.shape[0]):
        frame = out[k]
        try:
            mask, chunk = dataset.id.read_direct_chunk((k, *origin))
        except (RuntimeError, OSError):  # the chunk was never written
            dataset.read_direct(out, np.s_[k], np.s_[k])
            continue
        compressed = blosc_filter and not mask & FILTER_SKIPPED
        if not compressed and len(chunk) == frame.nbytes:
            frame.reshape(-1).view(np.uint8)[:] = np.frombuffer(chunk, np.uint8)
        elif compressed and len(chunk) >= BLOSC_HEADER and blosc.get_cbuffer_sizes(chunk)[0] == frame.nbytes:
            blosc.decompress_ptr(chunk, frame.ctypes.data)
        else:
            dataset.read_direct(out, np.s_[k], np.s_[k])
    return out
