"""index.json's keys as documented (docs/scale.md, Outputs): ``labctl_version``, ``created``, ``counts`` (``runs``,
``ok``, ``failed``), ``kind`` with its settings, then every run's summary under ``runs`` (its camera as keyfigures.json
gives it); and index.csv's rows."""

from __future__ import annotations

import csv
import json

from labctl.batch.index import BatchIndex, SweepSettings, write_index
from labctl.batch.tasks import CameraSummary
from labctl.evaluation.keyfigures import CameraDescription
from labctl.jsondoc import to_json


def _runs() -> list[dict]:
    ok = {"run": "a.h5", "output": "o/a", "status": "ok", "error": None, "seconds": 1.0, "name": "a",
          "evaluate": {"output": "o/a/evaluation", "report": "r", "camera": {"model": "cam", "serial": "7"},
                       "figures": {"z_precision_q90_mm": 0.5, "z_trueness_q90_mm": None}},
          "reconcile": {"verdict": "effect_found", "named": ["wiggling", "multipath"], "gap_before": 2.0}}
    failed = {"run": "b.h5", "output": "o/b", "status": "failed", "error": "evaluate: broken", "seconds": 0.5,
              "name": "b", "evaluate": {"error": "broken"}}
    return [ok, failed]


def test_a_batch_of_runs_lists_its_counts_kind_and_runs(tmp_path):
    json_path, csv_path = write_index(BatchIndex(kind="runs", evaluate=True, reconcile=False, model="model",
                                                 runs=_runs()), tmp_path)
    doc = json.loads(json_path.read_text())
    assert list(doc) == ["labctl_version", "created", "counts", "kind", "evaluate", "reconcile", "model", "runs"]
    assert doc["counts"] == {"runs": 2, "ok": 1, "failed": 1} and doc["kind"] == "runs"
    assert doc["reconcile"] is False and doc["runs"] == _runs()
    rows = list(csv.DictReader(csv_path.open()))
    assert [r["name"] for r in rows] == ["a", "b"]
    assert rows[0]["z_precision_q90_mm"] == "0.5" and rows[0]["named"] == "wiggling;multipath"
    assert rows[0]["camera_serial"] == "7" and rows[1]["error"] == "evaluate: broken"
    assert "z_trueness_q90_mm" not in rows[0]  # no run has a value for it


def test_a_sweep_records_its_settings_and_leaves_out_what_does_not_apply(tmp_path):
    settings = SweepSettings(name="s", axes=["seed"], evaluate=True, reconcile=False, keep_runs=False,
                             figures=["z_precision_q90_mm"])
    json_path, _ = write_index(BatchIndex(kind="sweep", sweep=settings, runs=[]), tmp_path, ["seed"])
    doc = json.loads(json_path.read_text())
    assert list(doc) == ["labctl_version", "created", "counts", "kind", "sweep", "runs"]  # no null_calibration
    assert doc["sweep"] == {"name": "s", "axes": ["seed"], "evaluate": True, "reconcile": False, "keep_runs": False,
                            "figures": ["z_precision_q90_mm"]}
    assert doc["counts"] == {"runs": 0, "ok": 0, "failed": 0}


def test_a_runs_camera_has_the_keys_of_keyfigures_json_camera():
    """The summary's camera (a mapping, as it travels from the workers) has the keys, in order, that ``camera`` of
    keyfigures.json has."""
    assert list(CameraSummary.__annotations__) == list(to_json(CameraDescription()))
