"""Lossless compression of run-file frames: an HDF5 filter from ``hdf5plugin``, or none.

Default ``blosc-lz4``: the Blosc filter (HDF5 registered filter 32001) with LZ4 at level 5
after byte shuffle (each value's bytes grouped, so the slowly varying exponent and high
mantissa bytes of float depth sit together). On the blaze-101 demo run it stores 1.72x less
than raw at about 0.85x the raw write rate, well above twice the fastest camera's frame rate
(bench/recording.py; gzip + shuffle stores 1.9x less but writes 7 frames/s; zstd 1.7-1.8x at
under 60 frames/s; Blosc2 and bit shuffle were slower at the same ratio). Importing
``hdf5plugin`` registers the filter with h5py, for writing and reading; elsewhere the file
reads with any HDF5 that has the Blosc plugin (``HDF5_PLUGIN_PATH``, docs/runfile.md).
"""

from __future__ import annotations

from typing import Any

import h5py
import hdf5plugin

COMPRESSIONS = ("blosc-lz4", "none")
DEFAULT = "blosc-lz4"
ESTIMATED_RATIO = {"blosc-lz4": 1.7, "none": 1.0}
# hdf5plugin registers its filters at import only where HDF5 has none of that id yet. With HDF5_PLUGIN_PATH at
# hdf5plugin's own plugin folder (as its documentation advises for other HDF5 tools), HDF5 finds the Blosc
# plugin there and loads it by itself, and that copy fails in its callback on every dataset it would compress
# ("error during user callback"). Registering hdf5plugin's Blosc filter in place of whatever HDF5 found makes
# labctl work with any plugin path.
hdf5plugin.register("blosc", force=True)
"""Raw bytes / stored bytes assumed for planning (measured 1.72 on the blaze-101 demo run;
real noise compresses somewhat worse, so free-space checks never rely on it)."""


def dataset_options(compression: str) -> dict[str, Any]:
    """Keyword arguments of ``create_dataset`` for one of :data:`COMPRESSIONS`."""
    if compression == "blosc-lz4":
        return dict(hdf5plugin.Blosc(cname="lz4", clevel=5, shuffle=hdf5plugin.Blosc.SHUFFLE))
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


def describe(dataset: h5py.Dataset) -> str:
    """The filters of a stored dataset, e.g. ``blosc (32001)``, or ``none``."""
    plist = dataset.id.get_create_plist()
    names = []
    for i in range(plist.get_nfilters()):
        code, _flags, _values, name = plist.get_filter(i)
        label = name.decode(errors="replace") if isinstance(name, bytes) else str(name)
        names.append(f"{label or 'filter'} ({code})")
    return ", ".join(names) if names else "none"
