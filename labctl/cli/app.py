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

import click

from drivers.protocols import CameraInfo
from labctl.cli import analyze as cli_analyze
from labctl.cli import batch as cli_batch
from labctl.cli import devices as cli_devices
from labctl.cli import export as cli_export
from labctl.cli import info as cli_info
from labctl.cli import reconcile as cli_reconcile
from labctl.cli import simulate as cli_sim
from labctl.cli.inputs import distinct, warn, warn_run_suffix
from labctl.cli.outputs import OutputDirectory, OutputFile, output_directory_for, output_file
from labctl.errors import InputError, LabctlError
from labctl.run.compression import COMPRESSIONS
from labctl.run.config import Campaign, load_campaign, model_camera_mismatch, parse_campaign
from labctl.run.diskspace import ensure_free, format_bytes
from labctl.run.filekind import describe, is_binary_data, not_a_run_file
from labctl.run.lab import Lab, build_real_lab, build_sim_lab
from labctl.run.operator import Operator
from labctl.run.overrides import ATTRIBUTE as OVERRIDES_ATTRIBUTE
from labctl.run.overrides import apply_overrides, encode_history, history_entries, parse_overrides, recorded_overrides
from labctl.run.planning import expected_run_bytes, format_duration, schedule
from labctl.run.progress import EvaluationProgress, Reporter
from labctl.run.runner import Runner, bring_to_safe_state, close_all, connect_lab
from labctl.run.salvage import carry_over, inspect
from labctl.run.store import DamagedRunFile, RunWriter, existing_output_advice, labctl_version, now_iso
from metrics.jsonsafe import dumps_strict
from procedures.steps import Step
from sim.model import ModelError, default_model_text, load_model, parse_model


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
    config, _ = load_campaign(campaign)
    planned = schedule(config)
    total = sum(p.duration_s for p in planned)
    compression = compression or config.runner.compression
    raw_bytes, file_bytes = expected_run_bytes(config, compression)
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
        }
        click.echo(dumps_strict(doc, indent=2))
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


# ---------------------------------------------------------------------- run
def _sim_lab_from(campaign: Campaign, model_text: str, model_source: str, seed: int) -> Lab:
    model = parse_model(model_text, model_source)
    return build_sim_lab(campaign, model, seed)


def _same_camera(campaign: Campaign, model_camera: str, campaign_path: Path, model_path: Path) -> None:
    """Refuse a model of another camera than the campaign's: the run file would record one camera's campaign
    holding another camera's data, and reconcile and the reports would compare the wrong camera."""
    why = model_camera_mismatch(campaign.devices.camera.backend, model_camera)
    if why is not None:
        profile = campaign.devices.camera.sim_profile
        raise InputError(f"--model {model_path} does not fit campaign {campaign_path}: {why}. Give a model with "
                         f"camera = \"{profile}\", or set backend = \"{model_camera}\" under [devices.camera] of the "
                         "campaign to simulate that camera")


def _ensure_room(run_file: Path, campaign: Campaign, compression: str, steps: list[Step], camera: CameraInfo) -> None:
    """Refuse to start (exit 1) when the disk cannot hold the expected size of the steps to run."""
    raw, expected = expected_run_bytes(campaign, compression, steps, camera)
    ensure_free(run_file, expected, f"the run's {len(steps)} remaining step(s) (about {format_bytes(expected)} "
                                    f"with compression {compression}; {format_bytes(raw)} uncompressed)")


def _operator(lab: Lab, reporter: Reporter, interactive: bool) -> Operator:
    """The command's one operator: it answers the connect-time questions and the campaign's prompts."""
    return Operator(automatic=lab.simulated and not interactive, report=reporter.message)


def _execute(
    campaign: Campaign, lab: Lab, writer: RunWriter, reporter: Reporter, operator: Operator, *, resumed: bool = False
) -> None:
    Runner(campaign, lab, writer, reporter, operator, resumed=resumed).execute()
    reporter.message(f"run complete: {writer.path}")


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
def run(
    campaign: Path, output: Path, sim: bool, model: Path | None, seed: int | None, interactive: bool,
    compression: str | None, quiet: bool
) -> None:
    """Run CAMPAIGN into the run file OUTPUT."""
    config, text = load_campaign(campaign)
    if output.exists():
        raise InputError(existing_output_advice(output))
    output_file(output, "-o")
    warn_run_suffix(output)
    if (model is not None or seed is not None) and not sim:
        raise InputError("--model and --seed only apply to simulated runs (--sim)")
    compression = compression or config.runner.compression
    reporter = Reporter(quiet=quiet)
    if sim:
        if model is not None:
            sim_model, model_text = load_model(model)
            source = str(model)
            _same_camera(config, sim_model.camera, campaign, model)
        else:
            model_text, source = default_model_text(config.devices.camera.sim_profile), "built-in profile"
        run_seed = config.sim.seed if seed is None else seed
        lab = _sim_lab_from(config, model_text, source, run_seed)
        sim_record: tuple[str, int] | None = (model_text, run_seed)
    else:
        lab = build_real_lab(config)
        sim_record = None
    operator = _operator(lab, reporter, interactive)
    connect_lab(lab, reporter.message, operator)
    try:
        _ensure_room(output, config, compression, config.steps(), lab.camera.info())
        writer = RunWriter.create(
            output,
            campaign_toml=text,
            simulated=sim,
            devices={role: (dev.identity(), dev.settings()) for role, dev in lab.devices().items()},
            camera=lab.camera.info(),
            steps=len(config.steps()),
            sim=sim_record,
            compression=compression,
        )
    except BaseException:
        bring_to_safe_state(lab, reporter.message)
        close_all(lab, reporter.message)
        raise
    try:
        _execute(config, lab, writer, reporter, operator)
    finally:
        writer.close()


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
def resume(
    run_file: Path, ports: tuple[str, ...], hosts: tuple[str, ...], into: Path | None, interactive: bool, quiet: bool
) -> None:
    """Continue RUN_FILE at the first step that is not complete.

    The operator first confirms that the target of that step is mounted.
    --port / --host change a device's connection; the change is recorded in
    RUN_FILE and kept by later resumes. A damaged RUN_FILE (cut short, a
    flush that failed) is continued in a new file with --into NEW.h5.
    """
    new = [(role, "port", value) for role, value in parse_overrides("port", ports).items()]
    new += [(role, "host", value) for role, value in parse_overrides("host", hosts).items()]
    if not run_file.is_file():
        raise InputError(f"run file {run_file} does not exist")
    if (wrong := not_a_run_file(run_file)) is not None:  # before opening it for writing, which would change it
        if is_binary_data(run_file):  # a run file whose header was overwritten, or another binary file
            raise _damaged(run_file, f"it is {describe(run_file)}: the HDF5 header is overwritten, or it was never a run file")
        raise InputError(wrong)
    reporter = Reporter(quiet=quiet)
    if into is not None:
        output_file(into, "--into")
        salvage = carry_over(run_file, into, reporter.message)
        reporter.message(f"{salvage.summary()}; the run continues in {into}")
        run_file = into
    try:
        writer = RunWriter(run_file)
        dropped = writer.discard_incomplete()
    except DamagedRunFile as exc:
        raise _damaged(run_file, str(exc)) from None
    try:
        if writer.attrs.get("status") == "complete":
            reporter.message(f"{run_file} is already complete; nothing to resume")
            return
        simulated = bool(writer.attrs.get("simulated", False))
        if new and simulated:
            raise InputError(f"{run_file} is a simulated run: --port and --host apply to runs on real hardware")
        config = parse_campaign(_stored_text(writer, "/", "campaign_toml"), f"{run_file} (stored campaign)")
        done = writer.completed()
        _ensure_room(run_file, config, writer.compression, [s for s in config.steps() if s.step_id not in done],
                     writer.camera_info())
        history = recorded_overrides(writer.attrs, str(run_file))
        config = apply_overrides(config, [(e["role"], e["field"], e["value"]) for e in history], str(run_file))
        stored, config = config, apply_overrides(config, new, str(run_file))
        history += history_entries(stored, new, now_iso())
        if simulated:
            model_text, seed = _stored_text(writer, "sim", "model_toml"), int(_stored_text(writer, "sim", "seed"))
            lab = _sim_lab_from(config, model_text, f"{run_file} (stored model)", seed)
        else:
            lab = build_real_lab(config)
        operator = _operator(lab, reporter, interactive)
        connect_lab(lab, reporter.message, operator)
        if new:
            writer.attrs[OVERRIDES_ATTRIBUTE] = encode_history(history)
        for role, field, value in new:
            reporter.message(f"{role} {field}: {value} (recorded in {run_file})")
        if dropped:
            reporter.message(f"discarded unfinished step(s): {', '.join(dropped)}")
        writer.set_status("running")
        _execute(config, lab, writer, reporter, operator, resumed=True)
    finally:
        writer.close()


def _damaged(run_file: Path, cause: str) -> InputError:
    """What a damaged run file still holds, and how to continue the run."""
    salvage = inspect(run_file)
    text = f"{run_file} is damaged ({cause}); {salvage.summary()}."
    if salvage.header is None:
        text += f" Continue the run in a new file with: labctl resume {run_file} --into NEW.h5"
    else:
        text += " Start the run again with labctl run."
    return InputError(text)


def _stored_text(writer: RunWriter, group: str, name: str) -> str:
    """A text attribute every resumable run file has; InputError naming it when missing."""
    where = writer.file[group] if group in writer.file else None
    if where is None or name not in where.attrs:
        what = f"group /{group.strip('/')}" if where is None else f"attribute {name} of {where.name}"
        raise InputError(f"{writer.path} has no {what}, which resume needs; the file is damaged or was not "
                         "written by labctl run")
    return str(where.attrs[name])


# ---------------------------------------------------------------------- evaluate
@cli.command()
@click.argument("runs", nargs=-1, required=True, type=click.Path(dir_okay=False, path_type=Path))
@click.option("-o", "--output", required=True, type=OutputDirectory(), help="output directory")
@click.option("--quiet", is_flag=True, help="no progress output")
def evaluate(runs: Sequence[Path], output: Path, quiet: bool) -> None:
    """Compute every metric RUNS allow: OUTPUT/keyfigures.json and OUTPUT/report.html."""
    from labctl.evaluation.evaluate import count_complete_steps, evaluate_runs
    from labctl.report.html import write_outputs

    runs = distinct(runs, "run file")
    steps = count_complete_steps(runs)
    reporter = Reporter(quiet=quiet)
    with output_directory_for(output):
        with EvaluationProgress(steps, quiet=quiet) as progress:
            evaluation = evaluate_runs(runs, progress=progress)
        json_path, report = write_outputs(evaluation, output)
    reporter.message(f"key figures: {json_path}")
    click.echo(f"report: {report}")


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

