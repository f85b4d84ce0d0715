"""The ``labctl`` command line (README.md, Command line).

Exit codes: 0 success, 2 invalid input (one paragraph naming the field or
file, no traceback), 1 hardware/runtime failure, 130 Ctrl-C after the devices
reached their safe state. ``--json`` prints one JSON document on stdout and
nothing else there; progress and messages go to stderr.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import click

from labctl.cli import analyze as cli_analyze
from labctl.cli import batch as cli_batch
from labctl.cli import devices as cli_devices
from labctl.cli import export as cli_export
from labctl.cli import info as cli_info
from labctl.cli import reconcile as cli_reconcile
from labctl.cli import simulate as cli_sim
from labctl.cli.console import console_options, run_console
from labctl.cli.inputs import distinct, warn, warn_run_suffix
from labctl.cli.outputs import OutputDirectory, OutputFile, output_directory_for, output_file
from labctl.errors import InputError, LabctlError
from labctl.provenance import labctl_version
from labctl.run.compression import COMPRESSIONS
from sim.errors import ModelError

if TYPE_CHECKING:
    from labctl.run.config import Campaign


def _echo_err(message: str) -> None:
    """The closing message on stderr; a terminal already gone (SIGHUP: EIO) or a closed pipe leaves the exit code to tell."""
    try:
        click.echo(message, err=True)
    except OSError:
        pass


@click.group(context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(labctl_version(), prog_name="labctl")
def cli() -> None:
    """Characterize 3D cameras: run campaigns, evaluate runs, simulate the lab.

    Sources cited in the help texts and reports (Thesis 2024 with a section number, ISO 12233:2023, ...)
    are listed in full in docs/references.md.
    """


# ---------------------------------------------------------------------- plan
@cli.command()
@click.argument("campaign", type=click.Path(dir_okay=False, path_type=Path))
@click.option("--json", "as_json", is_flag=True, help="print the plan as one JSON document")
@click.option("--compression", type=click.Choice(COMPRESSIONS), help="size estimate for this storage (default: [runner])")
def plan(campaign: Path, as_json: bool, compression: str | None) -> None:
    """Validate CAMPAIGN and list every step with its estimated lab time and the run file's size (no hardware)."""
    from labctl.jsondoc import dumps
    from labctl.reconcile.confounds import campaign_confounds
    from labctl.run.config import load_campaign
    from labctl.run.diskspace import format_bytes
    from labctl.run.planning import expected_run_bytes, format_duration, schedule

    config, _ = load_campaign(campaign)
    planned = schedule(config)
    total = sum(p.duration_s for p in planned)
    compression = compression or config.runner.compression
    raw_bytes, file_bytes = expected_run_bytes(config, compression)
    confounds = campaign_confounds(config, planned)
    if as_json:
        doc = {
            "campaign": config.campaign.name,
            "total_duration_s": round(total, 3),
            "compression": compression,
            "expected_file_bytes": file_bytes,
            "uncompressed_bytes": raw_bytes,
            "steps": [
                {
                    "step_id": p.step.step_id,
                    "procedure": p.step.procedure,
                    "target": p.step.target,
                    "distance_mm": p.step.distance_mm,
                    "distance_from": p.step.distance_from,
                    "stage_position_mm": p.stage_position_mm,
                    "robot_angle_deg": p.step.robot_angle_deg,
                    "frames": p.step.frames,
                    "exposure_us": p.step.exposure_us,
                    "prompt": p.step.prompt,
                    "start_s": round(p.start_s, 3),
                    "duration_s": round(p.duration_s, 3),
                }
                for p in planned
            ],
            "confounds": [
                {"axes": list(c.axes), "effects": [list(e) for e in c.effects], "separated": c.separated,
                 **({"by": c.how} if c.separated else {"capture": c.how})}
                for c in confounds
            ],
        }
        click.echo(dumps(doc))
        return
    size = f"run file about {format_bytes(file_bytes)}"
    if compression != "none":
        size += f" ({compression}; {format_bytes(raw_bytes)} uncompressed)"
    click.echo(f"campaign {config.campaign.name}: {len(planned)} steps, estimated lab time {format_duration(total)}, {size}")
    click.echo(f"{'step':<24} {'target':<12} {'distance':>9} {'angle':>6} {'frames':>6} {'start':>12} {'duration':>10}")
    for p in planned:
        s = p.step
        dist = f"{s.distance_mm:g}" if s.distance_mm is not None else ("focus" if s.distance_from else "-")
        angle = f"{s.robot_angle_deg:g}" if s.robot_angle_deg is not None else "-"
        click.echo(
            f"{s.step_id:<24} {s.target:<12} {dist:>9} {angle:>6} {s.frames:>6} "
            f"{format_duration(p.start_s):>12} {format_duration(p.duration_s):>10}"
        )
        if s.prompt:
            click.echo(f"{'':<24} operator: {s.prompt}")
    for c in confounds:
        (a, b), (ea, eb) = c.axes, c.effects
        what = f"{a} ({', '.join(ea)}) from {b} ({', '.join(eb)})"
        click.echo(f"tells {what}: {c.how}" if c.separated else f"cannot tell {what}; would need: {c.how}")


# ---------------------------------------------------------------------- run
def _same_camera(campaign: Campaign, model_camera: str, campaign_path: Path, model_path: Path) -> None:
    """Refuse a model of another camera than the campaign's: the run file would record one camera's campaign
    holding another camera's data, and reconcile and the reports would compare the wrong camera."""
    from labctl.run.config import model_camera_mismatch

    why = model_camera_mismatch(campaign.devices.camera.backend, model_camera)
    if why is not None:
        profile = campaign.devices.camera.sim_profile
        raise InputError(f"--model {model_path} does not fit campaign {campaign_path}: {why}. Give a model with "
                         f"camera = \"{profile}\", or set backend = \"{model_camera}\" under [devices.camera] of the "
                         "campaign to simulate that camera")


INTERACTIVE_HELP = ("with --sim: ask at every operator prompt as on real hardware "
                    "(default: a simulated operator confirms at once)")


@cli.command()
@click.argument("campaign", type=click.Path(dir_okay=False, path_type=Path))
@click.option("-o", "--output", required=True, type=OutputFile("run.h5"), help="run file to create")
@click.option("--sim", is_flag=True, help="replace every device by its simulated fake")
@click.option("--model", type=click.Path(dir_okay=False, path_type=Path), help="simulation model file (with --sim)")
@click.option("--seed", type=click.IntRange(min=0), help="simulation seed (default: [sim].seed)")
@click.option("--interactive", is_flag=True, help=INTERACTIVE_HELP)
@click.option("--compression", type=click.Choice(COMPRESSIONS), help="how frames are stored (default: [runner] compression)")
@click.option("--quiet", is_flag=True, help="no progress output")
@console_options
def run(
    campaign: Path, output: Path, sim: bool, model: Path | None, seed: int | None, interactive: bool,
    compression: str | None, quiet: bool, with_console: bool, console_port: int, console_host: str | None,
) -> None:
    """Run CAMPAIGN into the run file OUTPUT."""
    from labctl.run.campaign import run_campaign
    from labctl.run.config import load_campaign
    from labctl.run.lab import build_real_lab, simulated_lab
    from labctl.run.progress import Reporter
    from labctl.run.store import refuse_existing_output
    from sim.model import load_model

    config, text = load_campaign(campaign)
    refuse_existing_output(output)
    output_file(output, "-o")
    warn_run_suffix(output)
    if (model is not None or seed is not None) and not sim:
        raise InputError("--model and --seed only apply to simulated runs (--sim)")
    if sim and model is not None:
        sim_model, model_text = load_model(model)
        _same_camera(config, sim_model.camera, campaign, model)
        lab = simulated_lab(config, model_text, seed=seed, source=str(model))
    elif sim:
        lab = simulated_lab(config, seed=seed)
    else:
        lab = build_real_lab(config)
    with run_console(with_console, console_host, console_port) as watch:
        run_campaign(config, text, lab, output, interactive=interactive, reporter=Reporter(quiet=quiet),
                     compression=compression, **watch)


@cli.command()
@click.argument("run_file", type=click.Path(dir_okay=False, path_type=Path))
@click.option("--port", "ports", multiple=True, metavar="ROLE=PORT",
              help="connect a serial device on another port, e.g. laser=/dev/ttyUSB3 (stage, laser; repeatable)")
@click.option("--host", "hosts", multiple=True, metavar="ROLE=HOST", help="connect the robot at another address, "
              "e.g. robot=192.168.1.20")
@click.option("--into", type=click.Path(dir_okay=False, path_type=Path), metavar="NEW.h5",
              help="continue a damaged RUN_FILE in the new file NEW.h5, carrying its readable complete steps over "
                   "(RUN_FILE is only read)")
@click.option("--interactive", is_flag=True, help=INTERACTIVE_HELP)
@click.option("--quiet", is_flag=True, help="no progress output")
@console_options
def resume(
    run_file: Path, ports: tuple[str, ...], hosts: tuple[str, ...], into: Path | None, interactive: bool, quiet: bool,
    with_console: bool, console_port: int, console_host: str | None,
) -> None:
    """Continue RUN_FILE at the first step that is not complete.

    The operator first confirms that the target of that step is mounted.
    --port / --host change a device's connection; the change is recorded in
    RUN_FILE and kept by later resumes. A damaged RUN_FILE (cut short, a
    flush that failed) is continued in a new file with --into NEW.h5.
    """
    from labctl.run.campaign import resume_run
    from labctl.run.overrides import parse_overrides
    from labctl.run.progress import Reporter

    new = [(role, "port", value) for role, value in parse_overrides("port", ports).items()]
    new += [(role, "host", value) for role, value in parse_overrides("host", hosts).items()]
    if into is not None:
        output_file(into, "--into")
    with run_console(with_console, console_host, console_port) as watch:
        resume_run(run_file, overrides=new, into=into, interactive=interactive, reporter=Reporter(quiet=quiet),
                   **watch)


# ---------------------------------------------------------------------- evaluate
@cli.command()
@click.argument("runs", nargs=-1, required=True, type=click.Path(dir_okay=False, path_type=Path))
@click.option("-o", "--output", required=True, type=OutputDirectory(), help="output directory")
@click.option("--quiet", is_flag=True, help="no progress output")
@click.option("--pdf/--no-pdf", default=True, show_default=True,
              help="also print the report to OUTPUT/report.pdf (A4, headless Chromium)")
def evaluate(runs: Sequence[Path], output: Path, quiet: bool, pdf: bool) -> None:
    """Compute every metric RUNS allow: OUTPUT/keyfigures.json, OUTPUT/report.html and OUTPUT/report.pdf."""
    from labctl.evaluation.evaluate import count_complete_steps, evaluate_runs
    from labctl.report.html import write_outputs
    from labctl.report.pdf import print_pdf
    from labctl.run.progress import EvaluationProgress, Reporter

    runs = distinct(runs, "run file")
    steps = count_complete_steps(runs)
    reporter = Reporter(quiet=quiet)
    with output_directory_for(output):
        with EvaluationProgress(steps, quiet=quiet) as progress:
            evaluation = evaluate_runs(runs, progress=progress)
        json_path, report = write_outputs(evaluation, output)
        why_not = print_pdf(report, output / "report.pdf") if pdf else None
    reporter.message(f"key figures: {json_path}")
    click.echo(f"report: {report}")
    if pdf:
        if why_not is None:
            click.echo(f"report: {output / 'report.pdf'}")
        else:
            warn(f"report.pdf not written: {why_not}; the HTML report is complete")


@cli.command()
@click.argument("evaluations", nargs=-1, required=True, type=click.Path(file_okay=False, path_type=Path))
@click.option("-o", "--output", required=True, type=OutputDirectory(), help="output directory")
def compare(evaluations: Sequence[Path], output: Path) -> None:
    """Compare cameras side by side from EVALUATIONS (output directories of 'labctl evaluate')."""
    from labctl.report.compare import compare as write_comparison
    from labctl.report.compare import load_evaluation

    directories = distinct(evaluations, "evaluation")
    for directory in directories:  # every input readable before the output folder is made
        load_evaluation(directory)
    if len(directories) == 1:
        warn(f"one evaluation ({directories[0]}): compare puts two or more cameras side by side; "
             "this comparison shows one camera")
    with output_directory_for(output):
        click.echo(f"comparison: {write_comparison(directories, output)}")


# ---------------------------------------------------------------------- device, devices, sim, analyze
cli.add_command(cli_devices.device)
cli.add_command(cli_devices.devices)
cli.add_command(cli_sim.sim_group)
cli.add_command(cli_analyze.analyze_group)
cli.add_command(cli_export.export)
cli.add_command(cli_reconcile.reconcile)
cli.add_command(cli_info.info)
cli.add_command(cli_batch.batch)


# ---------------------------------------------------------------------- entry point
def main(argv: Sequence[str] | None = None) -> None:
    """Console entry point: maps errors to the exit codes of README.md, Command line."""
    debug = bool(os.environ.get("LABCTL_DEBUG"))
    try:
        cli.main(args=list(argv) if argv is not None else None, prog_name="labctl", standalone_mode=False)
    except click.exceptions.Exit as exc:
        sys.exit(exc.exit_code)
    except click.Abort:
        _echo_err("labctl: aborted")
        sys.exit(130)
    except click.ClickException as exc:
        exc.show()
        sys.exit(exc.exit_code)
    except (LabctlError, ModelError) as exc:  # a bad simulation model is bad input like a bad campaign
        if debug:
            raise
        _echo_err(f"labctl: error: {exc}")
        sys.exit(exc.exit_code if isinstance(exc, LabctlError) else InputError.exit_code)
    except KeyboardInterrupt:
        _echo_err("labctl: interrupted")
        sys.exit(130)
    except OSError as exc:  # a file or device the checks above did not foresee: name it, no traceback
        if debug:
            raise
        where = f"{exc.filename}: " if exc.filename else ""
        _echo_err(f"labctl: error: {where}{exc.strerror or exc}")
        sys.exit(1)
    sys.exit(0)

