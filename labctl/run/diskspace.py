"""Run-file size estimates, free-space checks and space reservations, so a full disk stops a run safely.

A frame stores x, y, z, intensity (float32) and confidence (uint16 or float32): W x H x
(16 + confidence bytes) raw. ``plan`` divides by the compression's planning ratio; the
checks before a run and before each step do not rely on compression (incompressible noise
stores at the raw size) and keep a margin for HDF5 metadata and the rest of the system.

A check cannot see another process taking the space a moment later; :func:`reserve` can: it
allocates a step's worst-case size in the run file (fallocate(2) with FALLOC_FL_KEEP_SIZE: the
blocks are the file's, its length unchanged), so the step's writes land in space the file already
owns. :func:`release` gives back what the step did not take.
"""

from __future__ import annotations

import ctypes
import errno
import os
from pathlib import Path
from typing import Any

import numpy as np

from labctl.errors import RunAborted
from labctl.run.compression import ESTIMATED_RATIO

MARGIN_BYTES = 64 * 2**20
"""Kept free beyond a step's raw size (itself 1.7x the compressed size it will take): HDF5 metadata,
the operating system, other programs."""


class DiskSpaceLow(RunAborted, OSError):
    """Not enough free space for a run or its next step: nothing of it is written (exit 1).
    An OSError too, so the runner treats it as a failure: devices safe, run aborted, resumable."""


def frame_bytes(width: int, height: int, confidence_dtype: str) -> int:
    """Raw bytes of one frame (five channels)."""
    return width * height * (4 * 4 + np.dtype(confidence_dtype).itemsize)


def expected_file_bytes(frames: int, width: int, height: int, confidence_dtype: str, compression: str) -> int:
    """Planning estimate of a run file holding ``frames`` frames."""
    return int(frames * frame_bytes(width, height, confidence_dtype) / ESTIMATED_RATIO[compression])


def free_bytes(path: Path) -> int:
    """Bytes available to this user on the file system holding ``path`` (statvfs(3): f_bavail x f_frsize)."""
    stat = os.statvfs(path)
    return stat.f_bavail * stat.f_frsize


def format_bytes(n: float) -> str:
    """``1.23 GB`` style (powers of 1000)."""
    for unit in ("B", "kB", "MB", "GB"):
        if abs(n) < 1000:
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.2f} {unit}"
        n /= 1000
    return f"{n:.2f} TB"


def ensure_free(run_file: Path, needed: int, what: str) -> None:
    """DiskSpaceLow unless the run file's file system has ``needed`` + :data:`MARGIN_BYTES` free."""
    directory = Path(run_file).resolve().parent
    free = free_bytes(directory)
    if free < needed + MARGIN_BYTES:
        raise DiskSpaceLow(
            f"not enough free space in {directory} (file system mounted at {mount_point(directory)}) for {what}: "
            f"it needs {format_bytes(needed)} plus a "
            f"{format_bytes(MARGIN_BYTES)} margin, {format_bytes(free)} are free; free space (or move the run file), "
            f"then continue"
        )



def mount_point(path: Path) -> Path:
    """The mount point of the file system holding ``path`` (an existing file or directory)."""
    current = Path(os.path.abspath(path))
    while not os.path.ismount(current):
        current = current.parent
    return current


_FALLOC_FL_KEEP_SIZE = 1  # linux/falloc.h: allocate blocks past the end of the file without changing its size


def _fallocate() -> Any:
    """libc's fallocate(2) (Linux), or None where the C library has none."""
    libc = ctypes.CDLL(None, use_errno=True)
    function = getattr(libc, "fallocate", None)
    if function is not None:
        function.argtypes = [ctypes.c_int, ctypes.c_int, ctypes.c_int64, ctypes.c_int64]
        function.restype = ctypes.c_int
    return function


def reserve(fd: int, path: Path, end: int, what: str) -> bool:
    """Allocate the blocks of file ``fd`` (the run file ``path``) up to byte ``end`` without changing its size
    (fallocate(2), FALLOC_FL_KEEP_SIZE), so that no later write below ``end`` can fail for lack of space.

    DiskSpaceLow, naming the mount point and the bytes needed, when the file system cannot provide them;
    False (nothing reserved) where the file system or C library does not support it."""
    function = _fallocate()
    if function is None:
        return False
    if function(fd, _FALLOC_FL_KEEP_SIZE, 0, end) == 0:
        return True
    err = ctypes.get_errno()
    if err in (errno.EOPNOTSUPP, errno.ENOSYS, errno.EINVAL):
        return False
    if err in (errno.ENOSPC, errno.EDQUOT):
        allocated = os.fstat(fd).st_blocks * 512
        raise DiskSpaceLow(
            f"no space left on the file system mounted at {mount_point(path)} for {what}: it needs "
            f"{format_bytes(max(0, end - allocated))} more for {path.name}, {format_bytes(free_bytes(path.parent))} "
            f"are free; free space (or move the run file), then continue")
    raise OSError(err, f"cannot reserve space for {what} in {path} ({os.strerror(err)})", str(path))


def release(fd: int) -> None:
    """Give back the blocks reserved past the end of file ``fd`` (truncating a file to its own size frees them)."""
    os.ftruncate(fd, os.fstat(fd).st_size)
