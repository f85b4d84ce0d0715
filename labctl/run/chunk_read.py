"""Reading a stack of frames chunk by chunk, decompressed in worker threads (docs/runfile.md, Storage).

HDF5 runs a dataset's filters on one thread, in the thread that reads. The run file stores each frame of a
channel as one chunk (labctl.run.chunks), so :func:`read_stack` reads each frame's chunk as it is stored (HDF5's
direct chunk read: no filter pipeline, no chunk cache) and has a pool of worker threads decompress it with the
``blosc`` package straight into the frame of the output array (Blosc releases the GIL). Only the calling thread
touches HDF5; the workers see bytes and numpy arrays only. The bytes are those the
Blosc filter would give (the same C-Blosc format, labctl.run.compression).

Only the layout the writer makes is read this way: a chunked dataset of chunks of one whole frame, with no filter
or the Blosc filter alone, read into an array of its own shape and type. Anything else, a frame whose chunk was
never written (HDF5 gives the fill value) and a chunk that is not a Blosc buffer of one frame go through h5py.
"""

from __future__ import annotations

from concurrent.futures import Executor

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


def _decompress(chunk: bytes, frame: np.ndarray) -> None:
    blosc.decompress_ptr(chunk, frame.ctypes.data)


def read_stack(dataset: h5py.Dataset, out: np.ndarray, pool: Executor) -> np.ndarray:
    """The whole of ``dataset`` in ``out`` (C-contiguous, as h5py's ``read_direct`` takes it; returned), the same
    array h5py reads: where :func:`direct_readable`, each frame's chunk read as stored (in this thread: only it
    touches HDF5) and decompressed into its frame by ``pool``'s threads; else, and for a frame whose chunk was
    never written (h5py gives the fill value) or is not one frame's data, read by h5py."""
    if not direct_readable(dataset, out):
        dataset.read_direct(out)
        return out
    blosc_filter = _filters(dataset) == [BLOSC_FILTER]
    origin = (0,) * (dataset.ndim - 1)
    pending = []
    try:
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
                pending.append(pool.submit(_decompress, chunk, frame))
            else:
                dataset.read_direct(out, np.s_[k], np.s_[k])
    finally:
        for done in pending:
            done.result()
    return out
