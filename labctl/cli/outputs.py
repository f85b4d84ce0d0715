"""Checks of the files and directories a command will write, before it spends time computing.

A missing or unwritable output location is bad input (exit 2) and is reported
naming the option and the path, instead of a traceback after the work is done.
"""

from __future__ import annotations

import os
from pathlib import Path

from labctl.errors import InputError


def output_file(path: Path, option: str, *, force: bool | None = None) -> Path:
    """``path`` if a file can be written there: its directory exists and is writable.

    ``force``: None when the command may replace an existing file; False refuses an
    existing file (``--force`` overwrites it).
    """
    directory = path.parent
    if not directory.is_dir():
        raise InputError(f"directory {directory} for {option} does not exist")
    if not os.access(directory, os.W_OK | os.X_OK):
        raise InputError(f"directory {directory} for {option} is not writable")
    if path.is_dir():
        raise InputError(f"{option} {path} is a directory, not a file")
    if force is False and path.exists():
        raise InputError(f"{option} {path} already exists; add --force to overwrite it")
    return path


def output_directory(path: Path, option: str = "-o") -> Path:
    """``path`` as an existing, writable directory (created with its parents if needed)."""
    try:
        path.mkdir(parents=True, exist_ok=True)
    except FileExistsError:
        raise InputError(f"{option} {path} is a file, not a directory") from None
    except OSError as exc:
        raise InputError(f"cannot create the directory {path} for {option}: {exc.strerror}") from None
    if not os.access(path, os.W_OK | os.X_OK):
        raise InputError(f"directory {path} for {option} is not writable")
    return path
