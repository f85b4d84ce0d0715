"""Checks of the files and directories a command reads, beyond their existence: a path given twice."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import click


def warn(message: str) -> None:
    """One warning line on stderr: the input is legal but likely a mistake."""
    click.echo(f"labctl: warning: {message}", err=True)


def distinct(paths: Sequence[Path], what: str) -> list[Path]:
    """``paths`` without repeats of the same file or directory (however spelled), with a warning per repeat
    naming both spellings; the first spelling is kept."""
    kept: dict[Path, Path] = {}
    for path in paths:
        key = path.resolve()
        if key in kept:
            also = "" if str(path) == str(kept[key]) else f" (also as {path})"
            warn(f"{what} {kept[key]} given twice{also}: used once")
            continue
        kept[key] = path
    return list(kept.values())
