"""Progress on stderr (rich): steps, frames and planned lab time left of a run, steps of an evaluation; log lines."""

from __future__ import annotations

import sys
from collections.abc import Collection, Sequence
from typing import Any, TextIO, cast

from rich.console import Console
from rich.progress import (
    BarColumn,
    MofNCompleteColumn,
    Progress,
    TaskID,
    TextColumn,
    TimeElapsedColumn,
    TimeRemainingColumn,
)

from labctl.run.observer import RunObserver
from labctl.run.planning import PlannedStep, format_duration


class VanishingOutput:
    """A stream (stderr) that may go away: once a write fails (EIO after the terminal closed, EPIPE after
    the reader of a pipe exited), further output is dropped, so a lost terminal never stops a run before
    its devices are safe and its file is marked. Everything else is the wrapped stream's."""

    def __init__(self, stream: TextIO) -> None:
        self.stream = stream
        self.lost = False

    def write(self, text: str) -> int:
        """Write ``text``, or drop it once the stream is gone."""
        if not self.lost:
            try:
                return self.stream.write(text)
            except OSError:
                self.lost = True
        return len(text)

    def flush(self) -> None:
        """Flush, unless the stream is gone."""
        if not self.lost:
            try:
                self.stream.flush()
            except OSError:
                self.lost = True

    def __getattr__(self, name: str) -> Any:
        return getattr(self.stream, name)


class Reporter:
    """Progress of a run: the step (k of n) and steps done, frames captured out of the plan's total,
    and the lab time left as planned (labctl.run.planning: moves, settling, laser readings, operator
    prompts and captures of the current and the remaining steps), not a frame-rate extrapolation,
    so a run waiting at a prompt shows the time the rest of the campaign still needs.

    On a terminal a live bar; otherwise (log file, pipe) one line per step event and no wrapping.
    """

    def __init__(self, quiet: bool = False, console: Console | None = None) -> None:
        output = cast(TextIO, VanishingOutput(sys.stderr))
        self.console = console or Console(file=output, quiet=quiet, highlight=False, soft_wrap=True)
        self.live = self.console.is_terminal
        self.progress = Progress(
            TextColumn("{task.description}"),
            BarColumn(),
            MofNCompleteColumn(),
            TextColumn("frames"),
            TimeElapsedColumn(),
            TextColumn("lab time left {task.fields[left]}"),
            console=self.console,
            transient=False,
            disable=not self.live,
        )
        self._task: TaskID | None = None
        self._plan: list[PlannedStep] = []
        self._done: set[str] = set()
        self._current: PlannedStep | None = None
        #: the planned time of the steps neither done nor current, and what it was summed for
        self._rest_key: tuple[int, str | None] | None = None
        self._rest_s = 0.0
        self._captured = 0
        self._frames_done = 0
        self.observer: RunObserver | None = None
        """Told of every log line as well (the live console)."""

    def start(self, plan: Sequence[PlannedStep], done: Collection[str]) -> None:
        """Begin a run of ``plan`` whose steps ``done`` are already complete (resume)."""
        self._plan = list(plan)
        self._done = {p.step.step_id for p in self._plan} & set(done)
        self._rest_key = None
        self._frames_done = sum(p.step.frames for p in self._plan if p.step.step_id in self._done)
        total = sum(p.step.frames for p in self._plan)
        self.progress.start()
        self._task = self.progress.add_task("run", total=total, completed=self._frames_done, left=self._left_text())
        if not self.live:
            self.message(f"run: {len(self._plan)} steps ({len(self._done)} done), frames {self._frames_done}/{total}, "
                         f"lab time left {self._left_text()}")

    def lab_time_left_s(self) -> float:
        """Planned lab time of the steps not done: the current one pro rata of its frames, the rest in full (their
        sum taken again only when a step starts: this is asked at every frame)."""
        current = None if self._current is None or self._current.step.step_id in self._done else self._current
        key = (len(self._done), None if current is None else current.step.step_id)
        if key != self._rest_key:
            self._rest_key = key
            self._rest_s = sum(p.duration_s for p in self._plan
                               if p.step.step_id not in self._done and p.step.step_id != key[1])
        if current is None:
            return self._rest_s
        return self._rest_s + current.duration_s * (1.0 - min(self._captured, current.step.frames)
                                                    / max(current.step.frames, 1))

    def _left_text(self) -> str:
        return format_duration(self.lab_time_left_s())

    def step(self, planned: PlannedStep) -> None:
        """A step starts (its prompt, moves and capture follow)."""
        if self._current is not None:
            self._done.add(self._current.step.step_id)
        self._current, self._captured = planned, 0
        ids = [p.step.step_id for p in self._plan]
        position = ids.index(planned.step.step_id) + 1 if planned.step.step_id in ids else len(ids)
        description = f"step {position}/{len(ids)} {planned.step.step_id} ({len(self._done)} done)"
        if self._task is not None:
            self.progress.update(self._task, description=description, left=self._left_text())
        if not self.live:
            total = sum(p.step.frames for p in self._plan)
            self.message(f"{description}: target {planned.step.target}, "
                         f"{planned.step.frames} frames; frames {self._frames_done}/{total}; "
                         f"lab time left {self._left_text()}")

    def frames(self, n: int = 1) -> None:
        self._captured += n
        self._frames_done += n
        if self._task is not None:
            self.progress.update(self._task, advance=n, left=self._left_text())

    def message(self, text: str) -> None:
        """A log line: on stderr, and to the observer."""
        if self.observer is not None:
            self.observer.message(text)
        self.console.print(text, markup=False)
        if not self.console.is_terminal:
            self.console.file.flush()

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
