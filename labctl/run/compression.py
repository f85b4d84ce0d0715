"""Lossless compression of run-file frames: an HDF5 filter from ``hdf5plugin``, or none.

Default ``blosc-lz4``: the Blosc filter (HDF5 registered filter 32001) with LZ4 at level 5
after byte shuffle (each value's bytes grouped, so the slowly varying exponent and high
mantissa bytes of float depth sit together). On the blaze-101 demo run it stores 1.72x less
than raw, and the store writes it about as fast as plain writes of the raw bytes
(bench/recording.py, docs/benchmarks.md; gzip + shuffle stores 1.9x less but writes 7
frames/s; zstd 1.7-1.8x at under 60 frames/s; Blosc2 and bit shuffle were slower at the
same ratio).
Importing ``hdf5plugin`` registers the filter with h5py, for writing and reading; elsewhere
the file reads with any HDF5 that has the Blosc plugin (``HDF5_PLUGIN_PATH``, docs/runfile.md).

The store does not run frames through HDF5's filter pipeline: :func:`compress_chunk` makes
each frame's chunk as the filter would (the ``blosc`` package, the same C-Blosc 1.x format
and parameters), in worker threads (labctl.run.chunks), and the chunk is written as it is.
"""

from __future__ import annotations

from typing import Any

import blosc
import h5py
import hdf5plugin
import numpy as np

COMPRESSIONS = ("blosc-lz4", "none")
DEFAULT = "blosc-lz4"
ESTIMATED_RATIO = {"blosc-lz4": 1.7, "none": 1.0}
"""Raw bytes / stored bytes assumed for planning (measured 1.72 on the blaze-101 demo run;
real noise compresses somewhat worse, so free-space checks never rely on it)."""
BLOSC_CODEC = "lz4"
BLOSC_LEVEL = 5
FILTER_SKIPPED = 1
"""Filter mask of a chunk stored unfiltered: bit 0, the dataset's one filter, was not applied."""

blosc.set_releasegil(True)  # compress in parallel threads (blosc_compress_ctx: no shared state)
blosc.set_nthreads(1)  # one thread per chunk; the chunks of a frame are compressed side by side instead
# hdf5plugin registers its filters at import only where HDF5 has none of that id yet. With HDF5_PLUGIN_PATH at
# hdf5plugin's own plugin folder (as its documentation advises for other HDF5 tools), HDF5 finds the Blosc
# plugin there and loads it by itself, and that copy fails in its callback on every dataset it would compress
# ("error during user callback"). Registering hdf5plugin's Blosc filter in place of whatever HDF5 found makes
# labctl work with any plugin path.
hdf5plugin.register("blosc", force=True)


def dataset_options(compression: str) -> dict[str, Any]:
    """Keyword arguments of ``create_dataset`` for one of :data:`COMPRESSIONS`."""
    if compression == "blosc-lz4":
        return dict(hdf5plugin.Blosc(cname=BLOSC_CODEC, clevel=BLOSC_LEVEL, shuffle=hdf5plugin.Blosc.SHUFFLE))
    if compression == "none":
        return {}
    raise ValueError(f"unknown compression {compression!r}; one of {', '.join(COMPRESSIONS)}")


def how_to_read(compression: str) -> str:
    """The run file's root attribute ``how_to_read``: what a program needs to read the frames (docs/runfile.md),
    readable by any HDF5 reader since attributes pass through no filter."""
    if compression == "none":
        return "frames are stored uncompressed: any HDF5 reader opens them"
    return ("frames are compressed with the Blosc filter (HDF5 registered filter 32001, LZ4 + byte shuffle). "
            "Python: `import hdf5plugin` (pip install hdf5plugin) before reading them with h5py; without it h5py "
            "fails with \"can't open directory\" or \"required filter is not registered\". Other HDF5 programs "
            "(h5dump, HDFView, MATLAB): the Blosc plugin on HDF5_PLUGIN_PATH, e.g. the folder "
            "`python -c \"import hdf5plugin; print(hdf5plugin.PLUGIN_PATH)\"` prints. labctl's docs/runfile.md")


def compress_chunk(data: np.ndarray, compression: str) -> tuple[bytes | np.ndarray, int]:
    """One frame's chunk (a contiguous array) as HDF5 stores it through the filter of ``compression``
    (one of :data:`COMPRESSIONS` but ``none``): the bytes and the chunk's filter mask. Thread-safe; it
    releases the GIL while it compresses.

    The filter gives Blosc an output buffer of the chunk's own size; when the compressed chunk does not
    fit (small or incompressible data: Blosc's 16-byte header comes on top) the filter fails, and as the
    filter is optional HDF5 stores the chunk unfiltered with bit 0 of its filter mask set. So here."""
    if compression != "blosc-lz4":
        raise ValueError(f"no chunk codec for compression {compression!r}")
    compressed = blosc.compress(data, typesize=data.itemsize, clevel=BLOSC_LEVEL, shuffle=blosc.SHUFFLE,
                                cname=BLOSC_CODEC)
    if len(compressed) > data.nbytes:
        return data, FILTER_SKIPPED
    return compressed, 0


def describe(dataset: h5py.Dataset) -> str:
    """The filters of a stored dataset, e.g. ``blosc (32001)``, or ``none``."""
    plist = dataset.id.get_create_plist()
    names = []
    for i in range(plist.get_nfilters()):
        code, _flags, _values, name = plist.get_filter(i)
        label = name.decode(errors="replace") if isinstance(name, bytes) else str(name)
        names.append(f"{label or 'filter'} ({code})")
    return ", ".join(names) if names else "none"
