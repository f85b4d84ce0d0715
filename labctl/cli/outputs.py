"""Checks of the files and directories a command will write, before it spends time computing.

A missing or unwritable output location is bad input (exit 2) and is reported
naming the option and the path, instead of a traceback after the work is done.
Writability is tried by creating a file there, not asked of the permissions:
root passes every permission check, yet cannot create a file in /proc.
"""

from __future__ import annotations

import errno
import os
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import click

from labctl.errors import InputError

ADVICE = "choose a directory on a writable disk"


class OutputFile(click.Path):
    """A file to write, as a Path; refuses a name ending in '/' (a directory), which Path would silently
    strip, so that ``-o newdir/`` does not create a file named ``newdir``."""

    def __init__(self, example: str) -> None:
        super().__init__(dir_okay=False, path_type=Path)
        self.example = example

    def convert(self, value: Any, param: click.Parameter | None, ctx: click.Context | None) -> Any:
        """Click's conversion, after refusing an empty name and a directory name."""
        _refuse_empty(value, param)
        if isinstance(value, str) and value.endswith(("/", os.sep)):
            raise InputError(f"{_option(param)} {value} names a directory; give a file name in it, e.g. "
                             f"{value}{self.example}")
        return super().convert(value, param, ctx)


class OutputDirectory(click.Path):
    """A directory to write into, as a Path; refuses an empty name, which Path would read as the current directory."""

    def __init__(self) -> None:
        super().__init__(file_okay=False, path_type=Path)

    def convert(self, value: Any, param: click.Parameter | None, ctx: click.Context | None) -> Any:
        """Click's conversion, after refusing an empty name."""
        _refuse_empty(value, param)
        return super().convert(value, param, ctx)


def _option(param: click.Parameter | None) -> str:
    return param.opts[0] if param is not None and param.opts else "the output"


def _refuse_empty(value: Any, param: click.Parameter | None) -> None:
    if isinstance(value, str) and not value.strip():
        raise InputError(f"{_option(param)} {value!r} is empty: give the output's name")


def _try_creating_a_file(directory: Path, option: str, path: Path) -> None:
    try:
        handle, name = tempfile.mkstemp(prefix=".labctl-write-test-", dir=directory)
    except OSError as exc:
        raise InputError(f"{option} {path}: no file can be created in {directory} ({exc.strerror}); {ADVICE}") from None
    os.close(handle)
    os.unlink(name)


def output_file(path: Path, option: str, *, force: bool | None = None) -> Path:
    """``path`` if a file can be written there: its directory exists and a file can be created in it.

    ``force``: None when the command may replace an existing file; False refuses an
    existing file (``--force`` overwrites it).
    """
    directory = path.parent
    if not directory.is_dir():
        raise InputError(f"directory {directory} for {option} does not exist")
    if path.is_dir():
        raise InputError(f"{option} {path} is a directory, not a file")
    if force is False and path.exists():
        raise InputError(f"{option} {path} already exists; add --force to overwrite it")
    _try_creating_a_file(directory, option, path)
    return path


def png_file(path: Path, option: str) -> Path:
    """``path`` as a PNG figure to write: named ``.png`` and writable (:func:`output_file`)."""
    if path.suffix.lower() != ".png":
        raise InputError(f"{option} {path}: the figure is written as PNG; name it {path.with_suffix('.png')}")
    return output_file(path, option)


def output_directory(path: Path, option: str = "-o") -> Path:
    """``path`` as an existing directory in which files can be created (created with its parents if needed).

    Call it after the inputs are validated: a command that fails on its input leaves no empty folder behind.
    """
    try:
        path.mkdir(parents=True, exist_ok=True)
    except FileExistsError:
        raise InputError(f"{option} {path} is a file, not a directory") from None
    except OSError as exc:
        parent = next((p for p in path.parents if p.is_dir()), None)
        refused = parent is not None and exc.errno in (errno.ENOENT, errno.EACCES, errno.EROFS)
        where = f" ({parent} accepts no new entries)" if refused else ""
        raise InputError(f"cannot create the directory {path} for {option}: {exc.strerror}{where}; {ADVICE}") from None
    _try_creating_a_file(path, option, path)
    return path


@contextmanager
def output_directory_for(path: Path, option: str = "-o") -> Iterator[Path]:
    """:func:`output_directory` for the work in the ``with`` block: the folders it made are removed again
    when the work fails before writing anything into them."""
    made = [p for p in (path, *path.parents) if not p.exists()]
    output_directory(path, option)
    try:
        yield path
    except BaseException:
        for folder in made:  # innermost first; one that holds something stays, and so do its parents
            try:
                folder.rmdir()
            except OSError:
                break
        raise
