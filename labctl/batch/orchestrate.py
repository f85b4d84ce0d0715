"""A whole batch: its tasks on the Dask client, then the index and the report across all runs."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from labctl.batch.calibration import null_calibration
from labctl.batch.cluster import Cluster, open_client
from labctl.batch.execute import BatchProgress, Job, run_jobs
from labctl.batch.index import BatchIndex, NullCalibration, SweepSettings, counts, write_index
from labctl.batch.inputs import run_names
from labctl.batch.interrupt import deferred_ctrl_c
from labctl.batch.report import write_report
from labctl.batch.sweep import Sweep, run_point
from labctl.batch.tasks import Summary, process_run


@dataclass(frozen=True)
class Outcome:
    summaries: list[Summary]
    index_json: Path
    index_csv: Path
    report: Path
    calibration: NullCalibration | None = None  # a reconciled sweep's error rates on its null runs

    @property
    def failed(self) -> int:
        return counts(self.summaries).failed


def _run(jobs: Sequence[Job], cluster: Cluster, quiet: bool) -> list[Summary]:
    with deferred_ctrl_c() as ctrl_c, open_client(cluster) as client, BatchProgress(len(jobs), quiet) as progress:
        ctrl_c.check()  # pressed while the cluster started
        if not quiet:
            workers = len(client.scheduler_info(n_workers=-1)["workers"])
            progress.message(f"{len(jobs)} runs on {workers} Dask worker(s) at {client.scheduler.address}")
        return run_jobs(client, jobs, progress, ctrl_c)


def batch_runs(paths: Sequence[Path], outdir: Path, evaluate: bool, reconcile: bool, model_text: str | None,
               model_source: str, cluster: Cluster, quiet: bool = False) -> Outcome:
    """Evaluate and/or reconcile every run of ``paths`` as one task each into ``outdir/runs/NAME``."""
    jobs = [Job(name, str(path), process_run,
                (path, outdir / "runs" / name, evaluate, reconcile, model_text, model_source))
            for name, path in zip(run_names(paths), paths)]
    summaries = _run(jobs, cluster, quiet)
    index = BatchIndex(kind="runs", evaluate=evaluate, reconcile=reconcile, model=model_source, runs=summaries)
    json_path, csv_path = write_index(index, outdir)
    report = write_report(summaries, outdir, f"Batch of {len(paths)} runs")
    return Outcome(summaries, json_path, csv_path, report)


def batch_sweep(sweep: Sweep, outdir: Path, cluster: Cluster, quiet: bool = False) -> Outcome:
    """Simulate, evaluate and/or reconcile every point of ``sweep`` as one task each into
    ``outdir/points/NAME``; tables and plots of the figures over the grid."""
    jobs = [Job(p.name, ", ".join(f"{k} = {v}" for k, v in p.parameters.items()) or p.name, run_point,
                (p, outdir / "points" / p.name, sweep.evaluate, sweep.reconcile, sweep.keep_runs))
            for p in sweep.points]
    summaries = _run(jobs, cluster, quiet)
    figures = list(sweep.figures) + (["reconcile.gap_after"] if sweep.reconcile and "reconcile.gap_after" not in
                                     sweep.figures else [])
    calibration = null_calibration(summaries) if sweep.reconcile else None
    settings = SweepSettings(name=sweep.name, axes=sweep.axes, evaluate=sweep.evaluate, reconcile=sweep.reconcile,
                             keep_runs=sweep.keep_runs, figures=figures)
    index = BatchIndex(kind="sweep", sweep=settings, null_calibration=calibration, runs=summaries)
    json_path, csv_path = write_index(index, outdir, sweep.axes)
    report = write_report(summaries, outdir, f"Sweep {sweep.name}", sweep.axes, figures, calibration)
    return Outcome(summaries, json_path, csv_path, report, calibration)
