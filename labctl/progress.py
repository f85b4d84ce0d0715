"""Progress with ETA on stderr (rich), plus one log line per finished step."""

from __future__ import annotations

import sys

from rich.console import Console
from rich.progress import (
    BarColumn,
    MofNCompleteColumn,
    Progress,
    TextColumn,
    TimeElapsedColumn,
    TimeRemainingColumn,
)


class Reporter:
    """Shows frames captured out of the plan's total and the estimated time left."""

    def __init__(self, quiet: bool = False) -> None:
        self.console = Console(stderr=True, quiet=quiet, highlight=False)
        self.progress = Progress(
            TextColumn("{task.description}"),
            BarColumn(),
            MofNCompleteColumn(),
            TextColumn("frames"),
            TimeElapsedColumn(),
            TextColumn("ETA"),
            TimeRemainingColumn(),
            console=self.console,
            transient=False,
        )
        self._task = None

    def start(self, total_frames: int, done_frames: int) -> None:
        self.progress.start()
        self._task = self.progress.add_task("run", total=total_frames, completed=done_frames)

    def step(self, step_id: str) -> None:
        if self._task is not None:
            self.progress.update(self._task, description=step_id)

    def frames(self, n: int = 1) -> None:
        if self._task is not None:
            self.progress.advance(self._task, n)

    def message(self, text: str) -> None:
        self.console.print(text, markup=False)
        if not self.console.is_terminal:
            sys.stderr.flush()

    def stop(self) -> None:
        self.progress.stop()
