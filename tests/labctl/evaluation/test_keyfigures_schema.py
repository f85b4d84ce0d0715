"""keyfigures.json against its JSON Schema (docs/keyfigures.schema.json), checked with the ``jsonschema`` library.

The committed schema is the one the dataclasses that write keyfigures.json give (so it cannot drift from them); a
simulated campaign's evaluation validates against it; a document that breaks it does not. The complete campaigns
of every camera (every procedure section) are validated in test_complete_campaigns.py.
"""

from __future__ import annotations

import copy
import hashlib
import json
import threading

import h5py
import jsonschema
import pytest

from labctl.evaluation.keyfigures import SCHEMA_VERSION, read_keyfigures
from labctl.evaluation.schema import SCHEMA_FILE, schema_text
from labctl.run.digest import sha256_of


def validator() -> jsonschema.Draft202012Validator:
    schema = json.loads(SCHEMA_FILE.read_text())
    jsonschema.Draft202012Validator.check_schema(schema)
    return jsonschema.Draft202012Validator(schema)


def test_the_committed_schema_is_the_one_the_document_classes_give():
    assert SCHEMA_FILE.read_text() == schema_text(), "regenerate it: python -m labctl.evaluation.schema"


@pytest.fixture(scope="module")
def evaluated(evaluated_small_campaign):
    return evaluated_small_campaign / "keyfigures.json"


def test_an_evaluation_validates_and_states_its_schema_version(evaluated):
    document = json.loads(evaluated.read_text())
    validator().validate(document)
    assert document["schema_version"] == SCHEMA_VERSION
    assert list(document)[:4] == ["camera", "figures", "suitability", "schema_version"]
    assert read_keyfigures(evaluated).schema_version == SCHEMA_VERSION


@pytest.mark.parametrize("break_it", [
    lambda d: d.pop("camera"),
    lambda d: d["figures"]["z_trueness_q90_mm"].update(value="0.7 mm"),
    lambda d: d["figures"]["z_trueness_q90_mm"].update(colour="red"),
    lambda d: d.update(schema_version="0.9"),
    lambda d: d["suitability"]["stories"]["pad_light"]["checks"][0].update(status=1),
])
def test_a_document_that_breaks_the_layout_does_not_validate(evaluated, break_it):
    document = copy.deepcopy(json.loads(evaluated.read_text()))
    break_it(document)
    assert not validator().is_valid(document)


def test_a_file_from_before_the_version_reads_as_version_0(evaluated, tmp_path):
    document = json.loads(evaluated.read_text())
    del document["schema_version"]
    (tmp_path / "keyfigures.json").write_text(json.dumps(document))
    assert read_keyfigures(tmp_path / "keyfigures.json").schema_version == "0"


def test_the_conditions_name_the_file_by_its_hash_and_its_devices(evaluated):
    """The run file's SHA-256 as hashlib computes it over the file's bytes, the labctl that recorded it and the
    devices the run file records (camera, stage, laser meter), with the report's Conditions section showing it."""
    document = json.loads(evaluated.read_text())
    (conditions,) = document["conditions"]
    run = evaluated.parents[1] / "r.h5"
    assert conditions["path"] == str(run)
    assert conditions["sha256"] == hashlib.sha256(run.read_bytes()).hexdigest()
    with h5py.File(run, "r") as f:
        assert conditions["recorded_by"] == f.attrs["labctl_version"]
        recorded = {role: g.attrs["serial"] for role, g in f["devices"].items()}
    assert {d["role"]: d["serial"] for d in conditions["devices"]} == recorded and {"camera", "laser"} <= set(recorded)
    assert conditions["status"] == "complete" and conditions["simulated"] is True
    # the simulated camera's sensor warms from the room (23 degC) towards 20 K above it while the run lasts
    (low, high), = conditions["camera_temperatures_c"].values()
    assert 23.0 <= low < high < 43.0
    page = (evaluated.parent / "report.html").read_text()
    assert "<h2>Conditions</h2>" in page and conditions["sha256"] in page
    assert "camera temperature sensor" in page and f"{high:.1f}" in page


def test_a_hash_stops_when_asked():
    stop = threading.Event()
    stop.set()
    assert sha256_of(SCHEMA_FILE, stop) == ""
    assert sha256_of(SCHEMA_FILE) == hashlib.sha256(SCHEMA_FILE.read_bytes()).hexdigest()
