"""Progress with ETA on stderr (rich): frames of a run, steps of an evaluation; plus log lines."""

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


class EvaluationProgress:
    """Steps of the run files evaluated so far out of their complete steps, with the ETA.

    ``__call__`` takes the evaluation's progress text, which starts with the
    step id; a step counts once, on its first mention (a second pass over it,
    e.g. its x/y noise, shows in the description only).
    """

    def __init__(self, total_steps: int, quiet: bool = False) -> None:
        self.console = Console(stderr=True, quiet=quiet, highlight=False)
        self.progress = Progress(
            TextColumn("{task.description:<40.40}"), BarColumn(), MofNCompleteColumn(), TextColumn("steps"),
            TimeElapsedColumn(), TextColumn("ETA"), TimeRemainingColumn(), console=self.console, transient=False,
        )
        self._task = self.progress.add_task("evaluate", total=max(total_steps, 1))
        self._seen: set[str] = set()

    def __enter__(self) -> EvaluationProgress:
        self.progress.start()
        return self

    def __call__(self, what: str) -> None:
        step = what.split(" ", 1)[0]
        advance = 0 if step in self._seen else 1
        self._seen.add(step)
        self.progress.update(self._task, description=what, advance=advance)

    def __exit__(self, *exc: object) -> None:
        self.progress.update(self._task, description="evaluated", completed=self.progress.tasks[0].total)
        self.progress.stop()
