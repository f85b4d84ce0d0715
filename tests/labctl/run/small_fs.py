"""Small real file systems for fault tests: a loop-mounted ext4 or a tmpfs (root only), and a filler that
takes their free space the way another process would."""

from __future__ import annotations

import os
import subprocess
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest


def run_or_skip(command: list[str], ok: tuple[int, ...] = (0,)) -> None:
    """Run a set-up command (mkfs, mount, e2fsck); skip the test with its error when it exits otherwise than ``ok``."""
    done = subprocess.run(command, capture_output=True, text=True)
    if done.returncode not in ok:
        pytest.skip(f"{' '.join(command)} failed: {done.stderr.strip()}")


def make_ext4(image: Path, size_mb: int, features: tuple[str, ...] = ()) -> None:
    """A sparse ``size_mb`` image file holding an empty ext4 (``features``: mkfs.ext4 ``-O`` list entries)."""
    with open(image, "wb") as f:
        f.truncate(size_mb * 2**20)
    # -m 0: no blocks reserved for root, so "free" means free for this root-run test too
    run_or_skip(["mkfs.ext4", "-q", "-F", "-m", "0", *(["-O", ",".join(features)] if features else []), str(image)])


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
        make_ext4(image, size_mb, ("^extents", "^64bit") if kind == "ext4-noextents" else ())
        run_or_skip(["mount", "-o", "loop", str(image), str(mnt)])
    else:
        run_or_skip(["mount", "-t", "tmpfs", "-o", f"size={size_mb}m", "tmpfs", str(mnt)])
    try:
        yield mnt
    finally:
        unmount(mnt)


def unmount(mnt: Path) -> None:
    """Unmount ``mnt``. Where a process still holds a file there, the mount is detached all the same (lazily: the
    kernel frees it when the file is closed), so that no test leaves it behind, and the test fails naming it."""
    busy = subprocess.run(["umount", str(mnt)], capture_output=True, text=True)
    if busy.returncode != 0:
        subprocess.run(["umount", "-l", str(mnt)], check=True)
        raise AssertionError(f"{mnt} could not be unmounted ({busy.stderr.strip()}); detached lazily")


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

    def __init__(self, root: Path, size_mb: int) -> None:
        self.backing, self.mnt, self.size_mb = root / "backing", root / "failing-mnt", size_mb
        self.image = self.backing / "disk.img"

    def create(self, backing_mb: int) -> None:
        """Mount a ``backing_mb`` tmpfs, make the image on it and mount the image (skips when not root or when
        a set-up command fails, with the reason)."""
        if os.geteuid() != 0:
            pytest.skip("mounting a failing loop device needs root")
        self.backing.mkdir()
        self.mnt.mkdir()
        run_or_skip(["mount", "-t", "tmpfs", "-o", f"size={backing_mb}m", "tmpfs", str(self.backing)])
        make_ext4(self.image, self.size_mb)
        run_or_skip(["mount", "-o", "loop", str(self.image), str(self.mnt)])

    def repair(self) -> None:
        """Unmount, grow the device's store to the image's size, check the file system (e2fsck exits 1 when
        it corrected errors, more when some are left) and mount it again."""
        subprocess.run(["umount", str(self.mnt)], check=True)
        subprocess.run(["mount", "-o", f"remount,size={2 * self.size_mb}m", str(self.backing)], check=True)
        checked = subprocess.run(["e2fsck", "-f", "-y", str(self.image)], capture_output=True, text=True)
        assert checked.returncode in (0, 1), checked.stdout + checked.stderr
        subprocess.run(["mount", "-o", "loop", str(self.image), str(self.mnt)], check=True)

    def close(self) -> None:
        """Unmount what is mounted: the file system, then its store (``unmount``: both, even where the first was
        busy)."""
        busy = []
        for mounted in (self.mnt, self.backing):
            if os.path.ismount(mounted):
                try:
                    unmount(mounted)
                except AssertionError as exc:
                    busy.append(str(exc))
        if busy:
            raise AssertionError("; ".join(busy))


@contextmanager
def failing_disk(root: Path, size_mb: int, backing_mb: int) -> Iterator[FailingDisk]:
    """A :class:`FailingDisk`, unmounted (and its store freed) on exit, also on failure and after a set-up
    that stopped half-way."""
    disk = FailingDisk(root, size_mb)
    try:
        disk.create(backing_mb)
        yield disk
    finally:
        disk.close()
