"""``labctl reconcile``: the simulation-vs-measurement workflow (README.md, Command line; docs/reconcile.md)."""

from __future__ import annotations

import time
from pathlib import Path

import click

from labctl.cli.outputs import OutputDirectory, output_directory_for
from labctl.jsondoc import dumps
from labctl.reconcile.false_positives import DEFAULT_NULL_RUNS


@click.command()
@click.argument("measured", type=click.Path(dir_okay=False, path_type=Path))
@click.option("--model", "model_path", type=click.Path(dir_okay=False, path_type=Path),
              help="simulation model to correct (default: the camera's built-in model)")
@click.option("-o", "--output", required=True, type=OutputDirectory(), help="output directory")
@click.option("--json", "as_json", is_flag=True, help="print reconcile.json on stdout")
@click.option("--null-runs", "null_runs", type=click.IntRange(min=0), default=DEFAULT_NULL_RUNS, show_default=True,
              help="null replicas of the campaign every decision is judged against (0: fixed thresholds)")
@click.option("--quiet", is_flag=True, help="no progress output")
def reconcile(measured: Path, model_path: Path | None, output: Path, as_json: bool, null_runs: int,
              quiet: bool) -> None:
    """Find where the simulation disagrees with MEASURED, name the missing effects, fit them and write
    OUTPUT/reconcile.json, OUTPUT/reconcile.html and the corrected OUTPUT/model.toml. Every decision is judged
    against --null-runs simulated replicas of the measured campaign with nothing missing."""
    from labctl.reconcile.report import write_reconcile
    from labctl.reconcile.workflow import reconcile as run_reconcile
    from labctl.run.progress import Reporter
    from sim.model import load_model

    model = load_model(model_path)[0] if model_path is not None else None
    reporter = Reporter(quiet=quiet)
    start = time.monotonic()

    def progress(what: str) -> None:
        reporter.message(f"[{time.monotonic() - start:6.1f} s] {what}")

    def warn(message: str) -> None:
        click.echo(f"labctl: warning: {model_path}: {message}", err=True)

    with output_directory_for(output):
        result = run_reconcile(measured, model, progress=progress, warn=warn, null_runs=null_runs)
        report, model_file, doc = write_reconcile(result, measured, output)
    if as_json:
        click.echo(dumps(doc))
        return
    named = ", ".join(e.name for e in result.named) or "nothing significant"
    if result.not_comparable is not None:
        reporter.message(f"verdict: not_comparable ({result.not_comparable.reason}); would need: "
                         + ", ".join(result.not_comparable.procedures_needed))
    else:
        reporter.message(f"verdict: {result.verdict} ({named}); gap {result.gap_before:.3f} -> {result.gap_after:.3f} mm"
                         f" (noise floor {doc.gap_floor:.3f} mm)")
    if result.unexplained is not None:
        reporter.message(result.unexplained.message)
    if result.verdict == "none" and result.minimum_detectable:
        from labctl.reconcile.power import detectable_message

        reporter.message(detectable_message(result.minimum_detectable))
    reporter.message(f"corrected model: {model_file}")
    click.echo(f"report: {report}")
