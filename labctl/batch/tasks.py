"""What a worker does for one run: the functions ``labctl evaluate`` and ``labctl reconcile`` call, on a path.

A task gets the run file's path (the run is read where it lies, stacks
streamed step by step as ``labctl evaluate`` does) and an output directory,
writes the same files the serial command writes there, and returns a small
summary (plain JSON values) for the index: never arrays or the run itself.
A failure of one run becomes the summary's ``error`` (the message the serial
command would print; the traceback in ``evaluate-error.txt`` or
``reconcile-error.txt`` beside the outputs), so
the other runs go on.
"""

from __future__ import annotations

import math
import os
import socket
import time
import traceback
from collections.abc import Callable
from pathlib import Path
from typing import TypedDict, TypeVar, cast

from labctl.errors import LabctlError
from labctl.jsondoc import JSONValue, to_json


class CameraSummary(TypedDict):
    """The camera of a run as ``camera`` of its keyfigures.json gives it (the fields of ``CameraDescription``,
    labctl/evaluation/keyfigures.py, as a mapping)."""

    model: str
    serial: str
    firmware: str
    backend: str
    width: int | None
    height: int | None
    fov_deg: list[float] | None
    frame_rate_hz: float | None
    wavelength_nm: float | None
    simulated: bool


class EvaluateSummary(TypedDict, total=False):
    """What ``labctl evaluate`` gave for one run (``evaluate`` of a run in index.json); only ``error`` when it
    failed."""

    output: str
    report: str
    camera: CameraSummary
    figures: dict[str, float | None]  # every key figure's value, in keyfigures.json's order
    error: str


class ReconcileSummary(TypedDict, total=False):
    """What ``labctl reconcile`` gave for one run (``reconcile`` of a run in index.json); only ``error`` when it
    failed."""

    output: str
    report: str
    model: str
    verdict: str
    named: list[str]
    empirical: list[str]
    gap_before: float | None
    gap_after: float | None
    gap_floor: float | None
    consistent_with_noise: bool | None
    best_candidate: str | None
    best_candidate_dbic: float | None
    worst_step_ratio: float | None
    error: str


class Summary(TypedDict, total=False):
    """One run of a batch in index.json: where it was processed, each stage's summary, its status (``ok`` or
    ``failed``, ``error`` saying why) and time; a sweep point adds its grid parameters and whether it is a null
    run, the batch the run's name. A mapping: it travels from the workers as is and is written in the order
    its keys were set."""

    run: str
    output: str
    worker: str
    evaluate: EvaluateSummary
    reconcile: ReconcileSummary
    status: str
    error: str | None
    seconds: float
    run_deleted: bool
    parameters: dict[str, JSONValue]  # grid axis -> its value at this point, as the sweep file gives it
    null: bool
    name: str


#: what a stage of one run returns: its summary, or only ``error`` when it failed (``guarded``)
StageSummary = TypeVar("StageSummary", EvaluateSummary, ReconcileSummary, dict[str, str])


def error_message(exc: BaseException) -> str:
    """The one-line message the command line would print for ``exc`` (labctl.cli.main's mapping)."""
    if isinstance(exc, LabctlError):
        return str(exc)
    if isinstance(exc, OSError) and exc.strerror:
        return f"{exc.filename}: {exc.strerror}" if exc.filename else exc.strerror
    return f"{type(exc).__name__}: {exc}"


def guarded(stage: Callable[[], StageSummary], error_file: Path) -> StageSummary:
    """``stage()``, or ``{"error": message}`` when it fails (the traceback written to ``error_file``)."""
    try:
        return stage()
    except Exception as exc:  # one run's failure must not stop the batch: it is reported in the index
        error_file.parent.mkdir(parents=True, exist_ok=True)
        error_file.write_text("".join(traceback.format_exception(exc)))
        return {"error": error_message(exc)}


def evaluate_run(run: Path, outdir: Path) -> EvaluateSummary:
    """``labctl evaluate RUN -o OUTDIR``: keyfigures.json, report.html and plots; the figures' values."""
    from labctl.evaluation.evaluate import evaluate_runs
    from labctl.evaluation.keyfigures import read_keyfigures
    from labctl.report.html import write_outputs

    json_path, report = write_outputs(evaluate_runs([run]), outdir)
    doc = read_keyfigures(json_path)
    return {"output": str(outdir), "report": str(report), "camera": cast(CameraSummary, to_json(doc.camera)),
            "figures": {name: figure.value for name, figure in doc.figures.items()}}


def reconcile_run(run: Path, outdir: Path, model_text: str | None = None,
                  model_source: str = "model") -> ReconcileSummary:
    """``labctl reconcile RUN [--model MODEL] --null-runs 0 -o OUTDIR`` (the fixed thresholds: null replicas of
    every run would multiply the batch's cost by K + 1): reconcile.json, reconcile.html, model.toml; the
    verdict, named effects, gaps, the best candidate's dBIC and the largest step gap in units of its floor
    before any effect was added (the two numbers the thresholds are calibrated on)."""
    from labctl.reconcile.report import write_reconcile
    from labctl.reconcile.workflow import reconcile
    from sim.model import parse_model

    model = parse_model(model_text, model_source) if model_text is not None else None
    result = reconcile(run, model, null_runs=0)
    report, model_file, doc = write_reconcile(result, run, outdir)
    before = result.goodness_before
    worst = before.worst_step if before is not None else None
    best = max((c.score for c in result.candidates), default=None)
    return {"output": str(outdir), "report": str(report), "model": str(model_file), "verdict": doc.verdict,
            "named": [e.name for e in result.named],
            "empirical": [e.name for e in result.empirical],
            "gap_before": doc.gap_before, "gap_after": doc.gap_after, "gap_floor": doc.gap_floor,
            "consistent_with_noise": doc.consistent_with_noise,
            "best_candidate": result.candidates[0].name if result.candidates else None,
            "best_candidate_dbic": best if best is None or math.isfinite(best) else None,
            "worst_step_ratio": round(worst.ratio, 4) if worst is not None and math.isfinite(worst.ratio) else None}


def process_run(run: Path, outdir: Path, evaluate: bool, reconcile: bool, model_text: str | None = None,
                model_source: str = "model") -> Summary:
    """One run of a batch: evaluated into ``outdir/evaluation`` and/or reconciled into ``outdir/reconcile``;
    ``status`` is ``failed`` when a stage failed (its ``error`` says why), the other stage still runs."""
    start = time.monotonic()
    summary: Summary = {"run": str(run), "output": str(outdir), "worker": f"{socket.gethostname()}:{os.getpid()}"}
    if evaluate:
        summary["evaluate"] = guarded(lambda: evaluate_run(run, outdir / "evaluation"),
                                      outdir / "evaluate-error.txt")
    if reconcile:
        summary["reconcile"] = guarded(lambda: reconcile_run(run, outdir / "reconcile", model_text, model_source),
                                       outdir / "reconcile-error.txt")
    errors = [f"{stage}: {summary[stage]['error']}" for stage in ("evaluate", "reconcile")
              if "error" in summary.get(stage, {})]
    summary["status"] = "failed" if errors else "ok"
    summary["error"] = "; ".join(errors) or None
    summary["seconds"] = round(time.monotonic() - start, 3)
    return summary
