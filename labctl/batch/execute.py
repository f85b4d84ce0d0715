"""Submit one task per run to the Dask client and follow them: a progress bar over runs, failures reported
as they come, every run's summary returned in submission order."""

from __future__ import annotations

import queue
import uuid
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

from labctl.batch.interrupt import POLL_S, CtrlC
from labctl.batch.tasks import Summary, error_message

if TYPE_CHECKING:
    from distributed import Client, Future


@dataclass(frozen=True)
class Job:
    """One task: ``function(*args)`` returns the run's summary; ``name`` names its outputs."""

    name: str
    label: str  # what the run is (its file, or the sweep point's parameters) for messages
    function: Callable[..., Summary]
    args: tuple[Any, ...]


class BatchProgress:
    """Runs done out of the batch's runs with elapsed time and ETA on stderr; a line per failed run (on a
    terminal a live bar, otherwise a line per finished run)."""

    def __init__(self, total: int, quiet: bool = False) -> None:
        self.console = Console(stderr=True, quiet=quiet, highlight=False, soft_wrap=True)
        self.live = self.console.is_terminal
        self.progress = Progress(TextColumn("{task.description:<30.30}"), BarColumn(), MofNCompleteColumn(),
                                 TextColumn("runs"), TimeElapsedColumn(), TextColumn("ETA"), TimeRemainingColumn(),
                                 console=self.console, disable=not self.live)
        self.total = total
        self.finished = 0
        self.failed = 0
        self._task = self.progress.add_task("batch", total=max(total, 1))

    def __enter__(self) -> BatchProgress:
        self.progress.start()
        return self

    def message(self, text: str) -> None:
        self.console.print(text, markup=False)

    def done(self, job: Job, summary: Summary) -> None:
        self.finished += 1
        failed = summary.get("status") != "ok"
        self.failed += failed
        self.progress.update(self._task, advance=1, description=f"{job.name} ({self.failed} failed)")
        if failed:
            self.message(f"{job.name} failed ({job.label}): {summary.get('error')}")
        elif not self.live:
            self.message(f"{self.finished}/{self.total} {job.name} done in {summary.get('seconds', 0):.1f} s")

    def __exit__(self, *exc: object) -> None:
        self.progress.stop()


def run_jobs(client: Client, jobs: Sequence[Job], progress: BatchProgress, ctrl_c: CtrlC) -> list[Summary]:
    """Every job as a Dask task (one worker process each, as many at once as the cluster has threads); the
    summaries in the order of ``jobs``. A task lost on the cluster (a worker killed, e.g. out of memory)
    is reported like a failed run. Ctrl-C (``ctrl_c``, checked every :data:`POLL_S` while waiting) cancels
    the tasks still pending and raises KeyboardInterrupt."""
    batch = uuid.uuid4().hex[:8]
    finished: queue.SimpleQueue[Future] = queue.SimpleQueue()
    futures: dict[Future, Job] = {}
    for job in jobs:
        future = client.submit(job.function, *job.args, key=f"labctl-{batch}-{job.name}", pure=False)
        future.add_done_callback(finished.put)  # called on a thread of the client's
        futures[future] = job
    summaries: dict[str, Summary] = {}
    try:
        while len(summaries) < len(jobs):
            ctrl_c.check()
            try:
                future = finished.get(timeout=POLL_S)
            except queue.Empty:
                continue
            job = futures[future]
            try:
                summary = future.result()
            except Exception as exc:  # the task itself never raises: this is the cluster losing it
                summary = {"status": "failed", "error": f"the task was lost on the cluster: {error_message(exc)}"}
            summary["name"] = job.name
            summaries[job.name] = summary
            progress.done(job, summary)
    except KeyboardInterrupt:
        client.cancel(list(futures))
        raise
    return [summaries[job.name] for job in jobs]
