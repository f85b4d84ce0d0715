"""Running and resuming a campaign on a lab into a run file: what ``labctl run``, ``labctl resume`` and the
simulated sweep of ``labctl batch`` do, callable from Python (docs/campaign.md, Running a campaign from Python).

Both functions connect the lab, check the disk has room for the steps to run, ask the operator at every
prompt, report progress, and on any failure (a device fault, a full disk, Ctrl-C, SIGTERM, SIGHUP) put
every device in its safe state, mark the run file ``aborted`` and raise: :class:`~labctl.errors.Interrupted`
for a signal, :class:`~labctl.errors.RunAborted` for a failure, each message ending with the command that
continues the run.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from drivers.protocols import CameraInfo
from labctl.errors import InputError
from labctl.provenance import now_iso
from labctl.run.config import Campaign, parse_campaign
from labctl.run.digest import digest_path, write_digest
from labctl.run.diskspace import ensure_free, format_bytes
from labctl.run.lab import Lab, build_real_lab, simulated_lab
from labctl.run.observer import RunObserver
from labctl.run.operator import Operator, RemoteAnswers
from labctl.run.overrides import ATTRIBUTE as OVERRIDES_ATTRIBUTE
from labctl.run.overrides import apply_overrides, encode_history, history_entries, recorded_overrides
from labctl.run.planning import expected_run_bytes
from labctl.run.progress import Reporter
from labctl.run.runner import Runner, bring_to_safe_state, close_all, connect_lab
from labctl.run.salvage import carry_over, inspect
from labctl.run.store import (
    DamagedRunFile,
    FrameSink,
    RunWriter,
    refuse_existing_output,
    refuse_what_is_not_hdf5,
)
from procedures.steps import Step

Override = tuple[str, str, str]
"""A device connection changed on resume: (role, field, value), e.g. ("laser", "port", "/dev/ttyUSB3")."""


@dataclass(frozen=True)
class RunResult:
    """What a completed run or resume left in its run file."""

    run_file: Path
    status: str  # the run file's status: "complete"
    steps_planned: int  # steps of the campaign
    steps_done: int  # complete steps in the run file
    steps_run: int  # steps this call executed (0: the file was already complete)
    simulated: bool
    discarded: tuple[str, ...] = ()  # unfinished steps a resume deleted before running them again


def run_campaign(
    campaign: Campaign, campaign_toml: str, lab: Lab, run_file: str | Path, *, operator: Operator | None = None,
    interactive: bool = False, reporter: Reporter | None = None, compression: str | None = None,
    observer: RunObserver | None = None, remote: RemoteAnswers | None = None, frame_sink: FrameSink | None = None,
) -> RunResult:
    """Run ``campaign`` (``campaign_toml``: its text, stored in the run file) on the not yet connected ``lab``
    into the new file ``run_file``, as ``labctl run`` does.

    ``operator`` answers the prompts (default: :func:`default_operator`; ``interactive`` asks on the terminal
    in a simulated lab too); ``reporter`` shows progress on stderr (default: ``Reporter()``); ``compression``
    stores the frames (default: the campaign's ``[runner] compression``); ``observer`` watches the run and
    ``remote`` answers prompts beside the terminal (the live console, labctl.console). A simulated lab is built with
    :func:`labctl.run.lab.simulated_lab`, which keeps the model for the run file. ``frame_sink``: the run file
    keeps no frames, each committed step's go to it instead (``RunWriter.hand_frames_to``). InputError when
    ``run_file`` exists; DiskSpaceLow (before anything is written) when its disk cannot hold the run."""
    run_file = Path(run_file)
    refuse_existing_output(run_file)
    if lab.simulated and lab.sim_record is None:
        raise ValueError("a simulated lab without its model text: build it with labctl.run.lab.simulated_lab")
    reporter = reporter or Reporter()
    reporter.observer = observer
    operator = operator or default_operator(lab, reporter, interactive, remote, observer)
    compression = compression or campaign.runner.compression
    steps = campaign.steps()
    connect_lab(lab, reporter.message, operator)
    try:
        if frame_sink is None:
            _ensure_room(run_file, campaign, compression, steps, lab.camera.info())
        writer = RunWriter.create(
            run_file,
            campaign_toml=campaign_toml,
            simulated=lab.simulated,
            devices={role: (dev.identity(), dev.settings()) for role, dev in lab.devices().items()},
            camera=lab.camera.info(),
            steps=len(steps),
            sim=lab.sim_record,
            compression=compression,
        )
        if frame_sink is not None:
            writer.hand_frames_to(frame_sink)
    except BaseException:
        bring_to_safe_state(lab, reporter.message)
        close_all(lab, reporter.message)
        raise
    try:
        result = _execute(campaign, lab, writer, reporter, operator, observer=observer)
    finally:
        writer.close()
    if frame_sink is None:
        _keep_digest(result, reporter)
    return result


def resume_run(
    run_file: str | Path, *, overrides: Sequence[Override] = (), into: str | Path | None = None,
    operator: Operator | None = None, interactive: bool = False, reporter: Reporter | None = None,
    observer: RunObserver | None = None, remote: RemoteAnswers | None = None,
) -> RunResult:
    """Continue ``run_file`` at the first step that is not complete, as ``labctl resume`` does: on the lab it
    was run on (the simulated one rebuilt from the stored model and seed, or the real devices of the stored
    campaign with the connections recorded by earlier resumes and the new ``overrides``, which are recorded too).

    ``into``: continue a damaged ``run_file`` in this new file, carrying its readable complete steps over
    (``run_file`` is only read). ``operator``, ``interactive``, ``reporter``, ``observer`` and ``remote`` as for
    :func:`run_campaign`.
    InputError when ``run_file`` is not a run file or is damaged (the message says how to continue)."""
    run_file = Path(run_file)
    if not run_file.is_file():
        raise InputError(f"run file {run_file} does not exist")
    reporter = reporter or Reporter()
    reporter.observer = observer
    try:
        if into is not None:
            refuse_what_is_not_hdf5(run_file)  # named for what it is, before anything is carried over
            into = Path(into)
            salvage = carry_over(run_file, into, reporter.message)
            reporter.message(f"{salvage.summary()}; the run continues in {into}")
            run_file = into
        writer = RunWriter(run_file)
        dropped = writer.discard_incomplete()
    except DamagedRunFile as exc:
        raise _damaged(run_file, str(exc)) from None
    try:
        simulated = bool(writer.attrs.get("simulated", False))
        if writer.attrs.get("status") == "complete":
            reporter.message(f"{run_file} is already complete; nothing to resume")
            done = len(writer.completed())
            result = RunResult(run_file, "complete", done, done, 0, simulated, tuple(dropped))
        else:
            result = _continue(writer, simulated, list(overrides), dropped, reporter, operator, interactive, remote,
                               observer)
    finally:
        writer.close()
    _keep_digest(result, reporter)  # a complete file opened for writing is newer than its kept hash
    return result


def _continue(writer: RunWriter, simulated: bool, new: list[Override], dropped: list[str], reporter: Reporter,
              operator: Operator | None, interactive: bool, remote: RemoteAnswers | None,
              observer: RunObserver | None) -> RunResult:
    """The steps of ``writer``'s run that are not complete, on its lab (see :func:`resume_run`)."""
    run_file = writer.path
    if new and simulated:
        raise InputError(f"{run_file} is a simulated run: --port and --host apply to runs on real hardware")
    config = parse_campaign(_stored_text(writer, "/", "campaign_toml"), f"{run_file} (stored campaign)")
    done_ids = writer.completed()
    _ensure_room(run_file, config, writer.compression, [s for s in config.steps() if s.step_id not in done_ids],
                 writer.camera_info())
    history = recorded_overrides(writer.attrs, str(run_file))
    config = apply_overrides(config, [(e["role"], e["field"], e["value"]) for e in history], str(run_file))
    stored, config = config, apply_overrides(config, new, str(run_file))
    history += history_entries(stored, new, now_iso())
    if simulated:
        model_text, seed = _stored_text(writer, "sim", "model_toml"), int(_stored_text(writer, "sim", "seed"))
        lab = simulated_lab(config, model_text, seed=seed, source=f"{run_file} (stored model)")
    else:
        lab = build_real_lab(config)
    operator = operator or default_operator(lab, reporter, interactive, remote, observer)
    connect_lab(lab, reporter.message, operator)
    if new:
        writer.attrs[OVERRIDES_ATTRIBUTE] = encode_history(history)
    for role, field, value in new:
        reporter.message(f"{role} {field}: {value} (recorded in {run_file})")
    if dropped:
        reporter.message(f"discarded unfinished step(s): {', '.join(dropped)}")
    writer.set_status("running")
    return _execute(config, lab, writer, reporter, operator, resumed=True, discarded=tuple(dropped),
                    observer=observer)


def _keep_digest(result: RunResult, reporter: Reporter) -> None:
    """A complete run's file hashed once, the hash kept beside it for its evaluations (labctl/run/digest.py)."""
    if result.status == "complete":
        hexdigest = write_digest(result.run_file)
        reporter.message(f"SHA-256 {hexdigest} (kept in {digest_path(result.run_file)})")


def default_operator(lab: Lab, reporter: Reporter, interactive: bool = False, remote: RemoteAnswers | None = None,
                     observer: RunObserver | None = None) -> Operator:
    """The run's one operator, answering the connect-time questions and the campaign's prompts: a simulated
    lab's confirms at once (unless ``interactive``), any other asks on the terminal and takes ``remote``
    answers as well."""
    return Operator(automatic=lab.simulated and not interactive, report=reporter.message, remote=remote,
                    observer=observer)


def _ensure_room(run_file: Path, campaign: Campaign, compression: str, steps: list[Step], camera: CameraInfo) -> None:
    """Refuse to start (DiskSpaceLow, exit 1) when the disk cannot hold the expected size of the steps to run."""
    raw, expected = expected_run_bytes(campaign, compression, steps, camera)
    ensure_free(run_file, expected, f"the run's {len(steps)} remaining step(s) (about {format_bytes(expected)} "
                                    f"with compression {compression}; {format_bytes(raw)} uncompressed)")


def _execute(
    campaign: Campaign, lab: Lab, writer: RunWriter, reporter: Reporter, operator: Operator, *,
    resumed: bool = False, discarded: tuple[str, ...] = (), observer: RunObserver | None = None,
) -> RunResult:
    """Every step not complete yet; what the run file holds afterwards."""
    before = len(writer.completed())
    Runner(campaign, lab, writer, reporter, operator, resumed=resumed, observer=observer).execute()
    reporter.message(f"run complete: {writer.path}")
    done = len(writer.completed())
    return RunResult(writer.path, str(writer.attrs["status"]), len(campaign.steps()), done, done - before,
                     lab.simulated, discarded)


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
