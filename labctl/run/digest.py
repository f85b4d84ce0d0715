"""A run file's SHA-256 (FIPS 180-4), computed once when its run is complete and kept beside it.

``labctl run`` and ``labctl resume`` end a complete run by hashing its file and writing ``RUN.h5.sha256`` in the
format of ``sha256sum`` (``<hex>  <name>``), so ``sha256sum -c RUN.h5.sha256`` checks the file against it. An
evaluation states the file's SHA-256 among the conditions of its figures (labctl/evaluation/conditions.py); it
takes it from this file, read in microseconds, where the file is no newer than it (the rule ``make`` judges
targets by: a run file changed after its hash was taken, resumed or copied without its times, is newer and is
hashed again), and hashes the file itself otherwise: a 7.6 GB sweep costs about 4 s of a core.
"""

from __future__ import annotations

import hashlib
import os
import threading
from pathlib import Path

#: the bytes :func:`sha256_of` reads at a time (large reads let hashlib work without the GIL)
CHUNK_BYTES = 8 * 1024 * 1024
SUFFIX = ".sha256"


def sha256_of(path: Path, stop: threading.Event | None = None) -> str:
    """The SHA-256 of a file's bytes, in hexadecimal; "" when ``stop`` is set before the end."""
    digest = hashlib.sha256()
    buffer = bytearray(CHUNK_BYTES)  # one buffer read into again and again: no new 8 MB object (mapped afresh) a chunk
    view = memoryview(buffer)
    with open(path, "rb", buffering=0) as f:
        while size := f.readinto(buffer):
            if stop is not None and stop.is_set():
                return ""
            digest.update(view[:size])
    return digest.hexdigest()


def digest_path(run_file: Path) -> Path:
    """Where ``run_file``'s hash is kept: ``RUN.h5.sha256`` beside it."""
    return run_file.with_name(run_file.name + SUFFIX)


def write_digest(run_file: Path) -> str:
    """Hash ``run_file`` and keep the hash beside it (written aside, then renamed into place); the hash."""
    run_file = Path(run_file)
    hexdigest = sha256_of(run_file)
    target = digest_path(run_file)
    tmp = target.with_name(f".{target.name}.writing")
    tmp.write_text(f"{hexdigest}  {run_file.name}\n")
    os.replace(tmp, target)
    return hexdigest


def kept_digest(run_file: Path) -> str | None:
    """``run_file``'s kept hash where it still holds: it names the file and the file is no newer; else None."""
    run_file = Path(run_file)
    target = digest_path(run_file)
    try:
        if os.stat(run_file).st_mtime_ns > os.stat(target).st_mtime_ns:
            return None
        text = target.read_text()
    except (OSError, UnicodeDecodeError):
        return None
    hexdigest, _, name = text.rstrip("\n").partition("  ")
    if name != run_file.name or len(hexdigest) != 64 or any(c not in "0123456789abcdef" for c in hexdigest):
        return None
    return hexdigest
