"""``labctl batch``: many runs evaluated and reconciled, and simulated campaign sweeps, on Dask (docs/scale.md)."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import click

from labctl.cli.outputs import OutputDirectory, output_directory
from labctl.errors import InputError, RunAborted

if TYPE_CHECKING:
    from labctl.batch.orchestrate import Outcome
    from labctl.run.progress import Reporter

SCHEDULER_HELP = "address of an existing Dask scheduler, e.g. tcp://10.0.0.5:8786 (default: a local cluster)"
WORKERS_HELP = "worker processes of the local cluster (default: one per core)"


def _finish(outcome: Outcome, reporter: Reporter) -> None:
    reporter.message(f"index: {outcome.index_json} and {outcome.index_csv.name}")
    click.echo(f"report: {outcome.report}")
    if outcome.failed:
        raise RunAborted(f"{outcome.failed} of {len(outcome.summaries)} runs failed (listed in {outcome.index_json}); "
                         "the others are complete")


@click.group("batch")
def batch() -> None:
    """Evaluate and reconcile many runs, or simulate a sweep of campaigns, as Dask tasks."""


@batch.command("runs")
@click.argument("runs", nargs=-1, required=True)
@click.option("-o", "--output", required=True, type=OutputDirectory(), help="output directory")
@click.option("--evaluate/--no-evaluate", default=True, show_default=True, help="labctl evaluate of every run")
@click.option("--reconcile", is_flag=True, help="labctl reconcile of every run as well")
@click.option("--model", "model_path", type=click.Path(dir_okay=False, path_type=Path),
              help="with --reconcile: the simulation model to correct (default: each camera's built-in model)")
@click.option("--scheduler", help=SCHEDULER_HELP)
@click.option("--workers", type=int, help=WORKERS_HELP)
@click.option("--quiet", is_flag=True, help="no progress output")
def runs_command(runs: Sequence[str], output: Path, evaluate: bool, reconcile: bool, model_path: Path | None,
                 scheduler: str | None, workers: int | None, quiet: bool) -> None:
    """Evaluate (and with --reconcile reconcile) every run of RUNS (files, directories, glob patterns), one
    Dask task per run: OUTPUT/runs/NAME/evaluation, OUTPUT/runs/NAME/reconcile, OUTPUT/index.json,
    OUTPUT/index.csv and OUTPUT/batch.html."""
    from labctl.batch.cluster import Cluster
    from labctl.batch.inputs import expand_runs
    from labctl.batch.orchestrate import batch_runs
    from labctl.run.progress import Reporter
    from sim.model import load_model

    if not evaluate and not reconcile:
        raise InputError("--no-evaluate without --reconcile leaves nothing to do")
    if model_path is not None and not reconcile:
        raise InputError("--model applies to --reconcile")
    model_text = load_model(model_path)[1] if model_path is not None else None
    paths = expand_runs(runs)
    cluster = Cluster(scheduler, workers)
    output_directory(output)
    outcome = batch_runs(paths, output, evaluate, reconcile, model_text,
                         str(model_path) if model_path else "built-in model", cluster, quiet)
    _finish(outcome, Reporter(quiet=quiet))


@batch.command("sweep")
@click.argument("sweep_file", type=click.Path(dir_okay=False, path_type=Path))
@click.option("-o", "--output", required=True, type=OutputDirectory(), help="output directory")
@click.option("--scheduler", help=SCHEDULER_HELP)
@click.option("--workers", type=int, help=WORKERS_HELP)
@click.option("--quiet", is_flag=True, help="no progress output")
def sweep_command(sweep_file: Path, output: Path, scheduler: str | None, workers: int | None, quiet: bool) -> None:
    """Simulate one run per point of SWEEP_FILE's grid, evaluate and/or reconcile each, one Dask task per point:
    OUTPUT/points/NAME, OUTPUT/index.json, OUTPUT/index.csv, OUTPUT/batch.html (figures over the grid; the
    reconcile's error rates on the null runs)."""
    from labctl.batch.cluster import Cluster
    from labctl.batch.orchestrate import batch_sweep
    from labctl.batch.sweep import load_sweep
    from labctl.run.progress import Reporter

    sweep = load_sweep(sweep_file)
    cluster = Cluster(scheduler, workers)
    output_directory(output)
    reporter = Reporter(quiet=quiet)
    reporter.message(f"sweep {sweep.name}: {len(sweep.points)} simulated runs over {', '.join(sweep.axes) or 'no axis'}")
    _finish(batch_sweep(sweep, output, cluster, quiet), reporter)
