"""The JSON Schema of keyfigures.json, docs/keyfigures.schema.json, from the dataclasses that write it.

``python -m labctl.evaluation.schema [PATH]`` writes it (default: docs/keyfigures.schema.json of the source
tree); tests/labctl/evaluation/test_keyfigures_schema.py checks that the committed file is what this gives and
that evaluations validate against it.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

from labctl.evaluation.keyfigures import SCHEMA_VERSION, KeyFiguresDocument
from labctl.jsondoc import JSONValue, json_schema

SCHEMA_FILE = Path(__file__).resolve().parents[2] / "docs" / "keyfigures.schema.json"


def keyfigures_schema() -> dict[str, JSONValue]:
    """The JSON Schema (draft 2020-12) of keyfigures.json of layout ``SCHEMA_VERSION``."""
    schema = json_schema(KeyFiguresDocument, title="labctl keyfigures.json",
                         description="Key figures, suitability verdicts and procedure sections of a camera's "
                                     "evaluation (labctl evaluate); docs/keyfigures.md describes every key.")
    definition = schema["$defs"]["KeyFiguresDocument"]  # type: ignore[index]
    definition["properties"]["schema_version"] = {"const": SCHEMA_VERSION}  # type: ignore[index]
    return schema


def schema_text() -> str:
    """The schema as the committed file holds it."""
    return json.dumps(keyfigures_schema(), indent=1) + "\n"


if __name__ == "__main__":
    target = Path(sys.argv[1]) if len(sys.argv) > 1 else SCHEMA_FILE
    target.write_text(schema_text())
    print(f"wrote {target}")
