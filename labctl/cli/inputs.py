"""Checks of what a command reads beyond click's own: a path given twice, numbers that are not finite."""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import click

from labctl.batch.inputs import RUN_SUFFIXES


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


class Number(click.ParamType):
    """A finite number (no nan, no inf), optionally above 0 (``positive``) or at least ``minimum`` (``why`` says
    what the minimum means)."""

    name = "number"

    def __init__(self, *, positive: bool = False, minimum: float | None = None, why: str = "") -> None:
        self.positive = positive
        self.minimum = minimum
        self.why = why

    def convert(self, value: Any, param: click.Parameter | None, ctx: click.Context | None) -> float:
        """``value`` as a float, or click's usage error naming the option and the value."""
        number = click.FLOAT.convert(value, param, ctx)
        if not math.isfinite(number):
            self.fail(f"{value!r} is not a finite number", param, ctx)
        if self.positive and number <= 0:
            self.fail(f"{value!r} is not positive", param, ctx)
        if self.minimum is not None and number < self.minimum:
            self.fail(f"{value!r} is below {self.minimum:g}{self.why}", param, ctx)
        return number


POSITIVE = Number(positive=True)


def warn_run_suffix(output: Path, option: str = "-o") -> None:
    """Warn when a run file to be written is not named ``.h5``/``.hdf5``: a directory given to ``labctl batch
    runs`` would not find it."""
    if output.suffix not in RUN_SUFFIXES:
        warn(f"{option} {output}: run files are named .h5 (labctl batch runs finds only *.h5 and *.hdf5 in a "
             f"directory); name it {output.with_suffix('.h5')}")
