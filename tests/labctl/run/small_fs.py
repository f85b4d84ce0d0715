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


class FailingDisk:
    """An ext4 on a loop device whose image is a sparse file on a tmpfs smaller than the image: ext4 sees
    ``size_mb`` free, but once the tmpfs is full the device fails its writes (the kernel logs "Buffer I/O
    error", ext4 aborts its journal and goes read-only), as a dying or thin-provisioned disk does.
    ``repair()`` is what a lab would do after replacing the disk: unmount, give the device room, ``e2fsck``,
    mount again."""

    def __init__(self, root: Path, size_mb: int, backing_mb: int) -> None:
        if os.geteuid() != 0:
            pytest.skip("mounting a failing loop device needs root")
        self.backing, self.mnt, self.size_mb = root / "backing", root / "failing-mnt", size_mb
        self.backing.mkdir()
        self.mnt.mkdir()
        self._run(["mount", "-t", "tmpfs", "-o", f"size={backing_mb}m", "tmpfs", str(self.backing)])
        self.image = self.backing / "disk.img"
        with open(self.image, "wb") as f:
            f.truncate(size_mb * 2**20)
        self._run(["mkfs.ext4", "-q", "-F", "-m", "0", str(self.image)])
        self._run(["mount", "-o", "loop", str(self.image), str(self.mnt)])

    @staticmethod
    def _run(command: list[str], ok: tuple[int, ...] = (0,)) -> None:
        done = subprocess.run(command, capture_output=True, text=True)
        if done.returncode not in ok:
            pytest.skip(f"{' '.join(command)} failed: {done.stderr.strip()}")

    def repair(self) -> None:
        """Unmount, grow the device's store to the image's size, check the file system (e2fsck exits 1 when
        it corrected errors) and mount it again."""
        subprocess.run(["umount", str(self.mnt)], check=True)
        self._run(["mount", "-o", f"remount,size={2 * self.size_mb}m", str(self.backing)])
        self._run(["e2fsck", "-f", "-y", str(self.image)], ok=(0, 1))
        self._run(["mount", "-o", "loop", str(self.image), str(self.mnt)])

    def close(self) -> None:
        subprocess.run(["umount", str(self.mnt)], capture_output=True)
        subprocess.run(["umount", str(self.backing)], check=True)


@contextmanager
def failing_disk(root: Path, size_mb: int, backing_mb: int) -> Iterator[FailingDisk]:
    """A :class:`FailingDisk`, unmounted (and its store freed) on exit, also on failure."""
    disk = FailingDisk(root, size_mb, backing_mb)
    try:
        yield disk
    finally:
        disk.close()
