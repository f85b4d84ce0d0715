"""The one JSON converter of result documents: dataclass fields become keys in their declared order, optional
fields are left out only while None, numbers are strict JSON (RFC 8259 section 6: no NaN or Infinity)."""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field

import jsonschema
import numpy as np

from labctl.jsondoc import dumps, inline, json_schema, optional, to_json, write_json


@dataclass(kw_only=True)
class Inner:
    b: float
    a: int


@dataclass(kw_only=True)
class Outer:
    zeta: str
    maybe: bool | None = optional()
    alpha: list[Inner] = field(default_factory=list)
    table: dict[str, object] = field(default_factory=dict)
    later: str | None = optional()


def test_fields_are_keys_in_declared_order_not_alphabetical():
    doc = to_json(Outer(zeta="z", alpha=[Inner(b=1.5, a=2)], table={"y": 1, "x": (1, 2)}))
    assert list(doc) == ["zeta", "alpha", "table"]
    assert list(doc["alpha"][0]) == ["b", "a"]
    assert doc["table"] == {"y": 1, "x": [1, 2]} and list(doc["table"]) == ["y", "x"]


def test_optional_fields_are_left_out_only_while_none():
    assert "maybe" not in to_json(Outer(zeta="z")) and "later" not in to_json(Outer(zeta="z"))
    doc = to_json(Outer(zeta="z", maybe=False, later=""))
    assert doc["maybe"] is False and doc["later"] == ""
    assert list(doc) == ["zeta", "maybe", "alpha", "table", "later"]


@dataclass(kw_only=True)
class Flattened:
    first: str
    inner: Inner | None = inline()
    last: int


def test_inline_fields_are_written_in_place_and_nothing_while_none():
    doc = to_json(Flattened(first="f", inner=Inner(b=0.5, a=1), last=2))
    assert list(doc) == ["first", "b", "a", "last"] and doc["b"] == 0.5
    assert to_json(Flattened(first="f", inner=None, last=2)) == {"first": "f", "last": 2}


def test_numbers_are_strict_json():
    doc = to_json(Outer(zeta="z", table={"nan": math.nan, "inf": -math.inf, "np": np.float32(0.5),
                                         "arr": np.array([1.0, np.nan])}))
    assert doc["table"] == {"nan": None, "inf": None, "np": 0.5, "arr": [1.0, None]}
    assert isinstance(doc["table"]["np"], float)
    json.loads(dumps(doc), parse_constant=lambda c: (_ for _ in ()).throw(ValueError(c)))  # no NaN literal


def test_written_text_is_indented_json(tmp_path):
    path = write_json(tmp_path / "d.json", Inner(b=1.0, a=3), final_newline=True)
    assert path.read_text() == '{\n  "b": 1.0,\n  "a": 3\n}\n'
    assert write_json(tmp_path / "e.json", Inner(b=1.0, a=3)).read_text().endswith("}")


def test_the_schema_accepts_what_to_json_writes_and_nothing_else():
    """json_schema and to_json read the same type hints: optional fields may be absent, inline fields' keys sit in
    place, non-finite floats are null; a wrong type, a missing required key or an unknown key fails."""
    outer = jsonschema.Draft202012Validator(json_schema(Outer))
    assert outer.is_valid(to_json(Outer(zeta="z")))
    assert outer.is_valid(to_json(Outer(zeta="z", maybe=True, alpha=[Inner(b=math.nan, a=1)], later="l")))
    assert not outer.is_valid({"alpha": [], "table": {}})  # zeta is required
    assert not outer.is_valid({**to_json(Outer(zeta="z")), "extra": 1})
    assert not outer.is_valid(to_json(Outer(zeta="z", alpha=[Inner(b=1.0, a=1.5)])))  # an int field
    flat = jsonschema.Draft202012Validator(json_schema(Flattened))
    assert flat.is_valid(to_json(Flattened(first="f", inner=Inner(b=0.5, a=1), last=2)))
    assert flat.is_valid(to_json(Flattened(first="f", inner=None, last=2)))
