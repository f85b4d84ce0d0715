"""The batch's index: every run's summary in ``index.json`` and one row per run in ``index.csv``."""

from __future__ import annotations

import csv
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from labctl.batch.tasks import Summary
from labctl.run.store import labctl_version, now_iso
from metrics.jsonsafe import dumps_strict

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


def counts(summaries: Sequence[Summary]) -> dict[str, int]:
    ok = sum(s.get("status") == "ok" for s in summaries)
    return {"runs": len(summaries), "ok": ok, "failed": len(summaries) - ok}


def _cell(value: Any) -> Any:
    if isinstance(value, list):
        return ";".join(str(v) for v in value)
    return "" if value is None else value


def csv_rows(summaries: Sequence[Summary], axes: Sequence[str] = ()) -> tuple[list[str], list[dict[str, Any]]]:
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


def write_index(summaries: Sequence[Summary], outdir: Path, extra: dict[str, Any] | None = None,
                axes: Sequence[str] = ()) -> tuple[Path, Path]:
    """OUTDIR/index.json (the summaries, counts and ``extra``) and OUTDIR/index.csv."""
    doc = {"labctl_version": labctl_version(), "created": now_iso(), "counts": counts(summaries), **(extra or {}),
           "runs": list(summaries)}
    json_path = outdir / "index.json"
    json_path.write_text(dumps_strict(doc, indent=2) + "\n")
    header, rows = csv_rows(summaries, axes)
    csv_path = outdir / "index.csv"
    with csv_path.open("w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=header)
        writer.writeheader()
        writer.writerows(rows)
    return json_path, csv_path
