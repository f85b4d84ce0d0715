"""Small real file systems for fault tests: a loop-mounted ext4 or a tmpfs (root only), and a filler that
takes their free space the way another process would."""

from __future__ import annotations

import os
import subprocess
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest


@contextmanager
def small_fs(kind: str, root: Path, size_mb: int) -> Iterator[Path]:
    """A ``size_mb`` file system of ``kind`` mounted under ``root``: ``ext4`` on a loop device, ``ext4-noextents``
    (ext4 without extents, where fallocate(2) is not supported), or ``tmpfs``;
    unmounted (and its image removed) on exit, also on failure. Skips the test when not root or when the
    mount fails, with the reason."""
    if os.geteuid() != 0:
        pytest.skip("mounting a small file system needs root")
    mnt = root / f"{kind}-mnt"
    mnt.mkdir()
    if kind.startswith("ext4"):
        image = root / "fs.img"
        with open(image, "wb") as f:
            f.truncate(size_mb * 2**20)
        # -m 0: no blocks reserved for root, so "free" means free for this root-run test too
        features = ["-O", "^extents,^64bit"] if kind == "ext4-noextents" else []
        made = subprocess.run(["mkfs.ext4", "-q", "-F", "-m", "0", *features, str(image)], capture_output=True, text=True)
        if made.returncode != 0:
            pytest.skip(f"mkfs.ext4 failed: {made.stderr.strip()}")
        command = ["mount", "-o", "loop", str(image), str(mnt)]
    else:
        command = ["mount", "-t", "tmpfs", "-o", f"size={size_mb}m", "tmpfs", str(mnt)]
    mounted = subprocess.run(command, capture_output=True, text=True)
    if mounted.returncode != 0:
        pytest.skip(f"{' '.join(command)} failed: {mounted.stderr.strip()}")
    try:
        yield mnt
    finally:
        subprocess.run(["umount", str(mnt)], check=True)


def fill(mnt: Path, leave: int) -> Path:
    """Take the free space of ``mnt`` but ``leave`` bytes, in one preallocated file (like fallocate(1))."""
    stat = os.statvfs(mnt)
    filler = mnt / "filler"
    fd = os.open(filler, os.O_CREAT | os.O_WRONLY, 0o600)
    try:
        os.posix_fallocate(fd, 0, stat.f_bfree * stat.f_frsize - leave)
    finally:
        os.close(fd)
    return filler
