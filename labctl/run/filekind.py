"""What a file given on the command line is, told from its first bytes: so that a wrong file is named for
what it is (empty, text, another HDF5 file, a run file) instead of by the error of the reader that choked on it.

A run file is HDF5: it starts with the HDF5 signature, at offset 0 or, after a user block, at 512, 1024,
2048, ... bytes (HDF5 File Format Specification, "Format Signature").
"""

from __future__ import annotations

import codecs
from pathlib import Path

HDF5_SIGNATURE = b"\x89HDF\r\n\x1a\n"
#: what a run file is, for messages that name a wrong one
RUN_FILE = "a run file is the HDF5 file 'labctl run CAMPAIGN.toml -o RUN.h5' writes"


def is_hdf5(path: Path) -> bool:
    """True if ``path`` carries the HDF5 signature (False for a file that cannot be read)."""
    try:
        with open(path, "rb") as f:
            offset = 0
            while True:
                f.seek(offset)
                head = f.read(len(HDF5_SIGNATURE))
                if head == HDF5_SIGNATURE:
                    return True
                if len(head) < len(HDF5_SIGNATURE):
                    return False
                offset = 512 if offset == 0 else 2 * offset
    except OSError:
        return False


def _text(head: bytes) -> str | None:
    """``head`` decoded, when it is printable UTF-8 text; None otherwise."""
    try:  # incremental: a character cut at the 512th byte is not an error
        text = codecs.getincrementaldecoder("utf-8")().decode(head, final=False)
    except UnicodeDecodeError:
        return None
    return text if text and all(c.isprintable() or c in "\r\n\t" for c in text) else None


def is_binary_data(path: Path) -> bool:
    """True if ``path`` holds bytes that are neither empty, text nor HDF5 (a run file whose header was
    overwritten looks like this; a wrong file given by mistake usually does not)."""
    try:
        with open(path, "rb") as f:
            head = f.read(512)
    except OSError:
        return False
    return bool(head) and not is_hdf5(path) and _text(head) is None


def describe(path: Path) -> str:
    """What ``path`` holds, as a phrase: "empty (0 bytes)", "a text file (it begins '...')", "an HDF5 file",
    or "neither text nor HDF5 (it begins with the bytes ...)"."""
    try:
        with open(path, "rb") as f:
            head = f.read(512)
    except OSError as exc:
        return f"unreadable ({exc.strerror})"
    if not head:
        return "empty (0 bytes)"
    if is_hdf5(path):
        return "an HDF5 file"
    text = _text(head)
    if text is not None:
        first = text.strip().splitlines()[0][:40] if text.strip() else ""
        return f"a text file (it begins {first!r})"
    return f"neither text nor HDF5 (it begins with the bytes {head[:8].hex(' ')})"


def not_a_run_file(path: Path) -> str | None:
    """The message for ``path`` given as a run file when it is not HDF5 at all; None when it is HDF5."""
    if is_hdf5(path):
        return None
    return f"{path} is {describe(path)}, not a labctl run file: {RUN_FILE}"
