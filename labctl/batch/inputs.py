"""The run files of a batch: file names, glob patterns and directories, expanded and named."""

from __future__ import annotations

import glob
import os
from collections.abc import Sequence
from pathlib import Path

from labctl.errors import InputError
from labctl.run.filekind import not_a_run_file

#: suffixes of run files (docs/runfile.md)
RUN_SUFFIXES = (".h5", ".hdf5")


def expand_runs(arguments: Sequence[str]) -> list[Path]:
    """Every run file named by ``arguments``: a file as it is, a directory's ``*.h5`` / ``*.hdf5`` files
    (recursively), a glob pattern's matches (``**`` crosses directories). Sorted, each once; InputError naming
    the argument that matches nothing, or a file named as such that is not HDF5 (found ones are reported by
    their tasks)."""
    found: dict[Path, None] = {}
    for argument in arguments:
        path = Path(argument)
        if path.is_dir():
            matches = sorted(p for p in path.rglob("*") if p.suffix in RUN_SUFFIXES and p.is_file())
            if not matches:
                raise InputError(f"directory {argument} holds no run file (*.h5, *.hdf5)")
        elif path.is_file():
            if (wrong := not_a_run_file(path)) is not None:  # named by the user: refused before any task
                raise InputError(wrong)
            matches = [path]
        elif glob.has_magic(argument):
            matches = sorted(Path(p) for p in glob.glob(argument, recursive=True) if Path(p).is_file())
            if not matches:
                raise InputError(f"pattern {argument} matches no file")
        else:
            raise InputError(f"run file {argument} does not exist")
        for match in matches:
            found.setdefault(match.resolve(), None)
    if not found:
        raise InputError("no run file given")
    return sorted(found)


def run_names(paths: Sequence[Path]) -> list[str]:
    """A short unique name per run for its output directory: the path below the runs' common directory,
    without the suffix, with ``/`` as ``__`` (``lot3/unit07.h5`` -> ``lot3__unit07``)."""
    if len(paths) == 1:
        return [paths[0].stem]
    common = Path(os.path.commonpath([p.parent for p in paths]))
    return ["__".join(p.relative_to(common).with_suffix("").parts) for p in paths]
