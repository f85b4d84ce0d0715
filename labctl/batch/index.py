"""The batch's index: every run's summary in ``index.json`` and one row per run in ``index.csv``."""

from __future__ import annotations

import csv
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

from labctl.batch.tasks import Summary
from labctl.jsondoc import JSONValue, inline, optional, write_json
from labctl.provenance import labctl_version, now_iso

RECONCILE_COLUMNS = ["verdict", "named", "empirical", "gap_before", "gap_after", "gap_floor", "consistent_with_noise",
                     "best_candidate", "best_candidate_dbic", "worst_step_ratio"]


def figure_names(summaries: Sequence[Summary]) -> list[str]:
    """The key figures any run of the batch has a value for, in keyfigures.json's order."""
    names: dict[str, None] = {}
    for s in summaries:
        for name, value in s.get("evaluate", {}).get("figures", {}).items():
            if value is not None:
                names.setdefault(name, None)
    return list(names)


@dataclass(kw_only=True)
class Counts:
    """How many runs the batch has, how many completed every stage and how many failed."""

    runs: int
    ok: int
    failed: int


def counts(summaries: Sequence[Summary]) -> Counts:
    """The batch's run counts."""
    ok = sum(s.get("status") == "ok" for s in summaries)
    return Counts(runs=len(summaries), ok=ok, failed=len(summaries) - ok)


@dataclass(kw_only=True)
class SweepSettings:
    """A sweep's settings as ``index.json`` records them: its name, axes, stages and the figures it tables."""

    name: str
    axes: list[str]
    evaluate: bool
    reconcile: bool
    keep_runs: bool
    figures: list[str]


@dataclass(kw_only=True)
class ErrorRates:
    """The reconcile verdicts over null runs: their counts, the false positives (runs with a named effect) and
    false alarms (``unexplained``) with their rates and 95 % upper bounds, the effects named, and the largest
    best-candidate dBIC and step gap over floor (None without any)."""

    runs: int
    verdicts: dict[str, int]
    false_positive: int
    false_positive_rate: float
    false_positive_upper_95: float
    false_unexplained: int
    false_unexplained_rate: float
    false_unexplained_upper_95: float
    named: dict[str, int]
    largest_candidate_dbic: float | None
    largest_step_ratio: float | None


@dataclass(kw_only=True)
class NullCalibration:
    """``null_calibration`` of a sweep's index.json: the thresholds, the error rates over all reconciled null runs
    (their keys in place) and per camera."""

    dbic_threshold: float
    step_factor: float
    overall: ErrorRates = inline()
    by_camera: dict[str, ErrorRates]


@dataclass(kw_only=True)
class BatchIndex:
    """``index.json``: the labctl version and time of writing and the run counts (set when it is made), the kind
    of batch (``runs``: with its stages and the reconcile model's source; ``sweep``: with its settings and, for
    reconciled null runs, the thresholds' error rates) and every run's summary."""

    labctl_version: str = field(init=False)
    created: str = field(init=False)
    counts: Counts = field(init=False)
    kind: str
    evaluate: bool | None = optional()
    reconcile: bool | None = optional()
    model: str | None = optional()
    sweep: SweepSettings | None = optional()
    null_calibration: NullCalibration | None = optional()
    runs: list[Summary]

    def __post_init__(self) -> None:
        self.labctl_version, self.created, self.counts = labctl_version(), now_iso(), counts(self.runs)


def _cell(value: JSONValue) -> JSONValue:
    """A value as index.csv writes it: a list joined with ``;``, None as empty."""
    if isinstance(value, list):
        return ";".join(str(v) for v in value)
    return "" if value is None else value


def csv_rows(summaries: Sequence[Summary], axes: Sequence[str] = ()) -> tuple[list[str], list[dict[str, JSONValue]]]:
    """index.csv's header and rows: name, status, error, seconds, the grid's parameters, the camera, every
    key figure any run has, the reconcile verdict and gaps, the output directory."""
    figures = figure_names(summaries)
    header = (["name", "run", "status", "error", "seconds"] + list(axes) + (["null"] if axes else [])
              + ["camera_model", "camera_serial"] + figures + RECONCILE_COLUMNS + ["output"])
    rows = []
    for s in summaries:
        evaluation, reconciled = s.get("evaluate", {}), s.get("reconcile", {})
        camera = evaluation.get("camera", {})
        row = {"name": s["name"], "run": s.get("run"), "status": s.get("status"), "error": s.get("error"),
               "seconds": s.get("seconds"), "camera_model": camera.get("model"), "camera_serial": camera.get("serial"),
               "output": s.get("output"), **{a: s.get("parameters", {}).get(a) for a in axes}}
        if axes:
            row["null"] = s.get("null")
        row.update({f: evaluation.get("figures", {}).get(f) for f in figures})
        row.update({c: reconciled.get(c) for c in RECONCILE_COLUMNS})
        rows.append({k: _cell(v) for k, v in row.items()})
    return header, rows


def write_index(index: BatchIndex, outdir: Path, axes: Sequence[str] = ()) -> tuple[Path, Path]:
    """OUTDIR/index.json (``index``) and OUTDIR/index.csv (a row per run, columns for the sweep's ``axes``)."""
    json_path = write_json(outdir / "index.json", index, final_newline=True)
    header, rows = csv_rows(index.runs, axes)
    csv_path = outdir / "index.csv"
    with csv_path.open("w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=header)
        writer.writeheader()
        writer.writerows(rows)
    return json_path, csv_path
