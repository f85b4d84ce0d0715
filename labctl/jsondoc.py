"""Result documents as JSON: the one conversion from the project's results to JSON text.

The result files labctl writes (``keyfigures.json``, ``reconcile.json``,
``compare.json``, a batch's ``index.json``) and the ``--json`` output of its
commands are built from typed dataclasses (or plain dicts and lists) and
turned into JSON here, so that a document's keys are the fields of its
dataclass, in their declared order:

* a dataclass becomes an object with one key per field, in field order;
* a field declared with :func:`optional` is left out while it is ``None``
  (documents whose later keys appear only when they apply);
* a field declared with :func:`inline` holds a dataclass whose fields are
  written in its place, as keys of the enclosing object (nothing while it is
  ``None``);
* dicts, lists and tuples are converted item by item, numpy arrays and
  numbers as Python lists and numbers.

Numbers are strict JSON. RFC 8259 section 6: "Numeric values that cannot be
represented in the grammar below (such as Infinity and NaN) are not
permitted." Python's ``json`` writes them as ``NaN`` / ``Infinity`` by
default, which other JSON readers reject; every non-finite float is
therefore written as ``null`` (the value is missing), and the text is made
with ``allow_nan=False`` as a guard.
"""

from __future__ import annotations

import dataclasses
import inspect
import json
import math
import types
import typing
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

#: field metadata: leave the key out of the document while the value is None
OMIT_IF_NONE = "omit_if_none"
#: field metadata: write the value's own fields in place of the field
INLINE = "inline"

#: a JSON value as :func:`to_json` gives it
JSONValue = dict[str, "JSONValue"] | list["JSONValue"] | str | int | float | bool | None


def optional() -> Any:
    """A dataclass field that defaults to None and is left out of the JSON document while it is None."""
    return dataclasses.field(default=None, metadata={OMIT_IF_NONE: True})


def inline(default: Any = dataclasses.MISSING) -> Any:
    """A dataclass field holding a dataclass (or None) whose fields are written in its place, as keys of the
    enclosing object; nothing is written while it is None. ``default`` as in ``dataclasses.field``."""
    return dataclasses.field(default=default, metadata={INLINE: True})


def to_json(value: object) -> JSONValue:
    """``value`` as JSON values: dataclasses as objects in field order (``optional`` fields left out while None,
    ``inline`` fields' keys in their place), containers item by item, numpy arrays as lists, numpy numbers as
    Python numbers, non-finite floats as None."""
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        doc: dict[str, JSONValue] = {}
        for f in dataclasses.fields(value):
            item = getattr(value, f.name)
            if f.metadata.get(INLINE):
                if item is not None:
                    doc.update(to_json(item))  # type: ignore[arg-type]  # a dataclass: an object
            elif not (f.metadata.get(OMIT_IF_NONE) and item is None):
                doc[f.name] = to_json(item)
        return doc
    if isinstance(value, dict):
        return {key: to_json(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [to_json(item) for item in value]
    if isinstance(value, np.ndarray):
        return to_json(value.tolist())
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value  # type: ignore[return-value]  # str, int, bool, None: JSON as they are


def dumps(value: object, indent: int | None = 2) -> str:
    """The JSON text of ``value`` (:func:`to_json`), refusing anything that is not valid JSON; ``indent=None``:
    on one line."""
    return json.dumps(to_json(value), allow_nan=False, indent=indent)


def write_json(path: Path, value: object, final_newline: bool = False) -> Path:
    """Write ``value`` as indented JSON (:func:`dumps`) to ``path``; returns ``path``."""
    path.write_text(dumps(value) + ("\n" if final_newline else ""), encoding="utf-8")
    return path


def json_schema(root: type, **annotations: JSONValue) -> dict[str, JSONValue]:
    """The JSON Schema (draft 2020-12) of the documents :func:`to_json` writes from dataclass ``root``, from the
    same type hints, so the two cannot drift apart: a dataclass or ``TypedDict`` is an object of exactly its keys
    (``optional`` fields not required, ``inline`` fields' keys in their place), its docstring the description;
    lists and tuples arrays; dicts objects; ``X | None`` either; a float a number or null (non-finite floats are
    written as null). ``annotations``: more keywords of the schema's root (``$id``, ``title``, ...)."""
    defs: dict[str, JSONValue] = {}
    top = _schema(root, defs)
    return {"$schema": "https://json-schema.org/draft/2020-12/schema", **annotations, **top, "$defs": defs}


def _schema(hint: Any, defs: dict[str, JSONValue]) -> dict[str, JSONValue]:
    origin, args = typing.get_origin(hint), typing.get_args(hint)
    if hint is Any or hint is object:
        return {}
    if origin in (typing.Union, types.UnionType):
        options = [_schema(a, defs) for a in args if a is not type(None)]
        if type(None) in args:
            options.append({"type": "null"})
        return options[0] if len(options) == 1 else {"anyOf": options}  # type: ignore[return-value]
    if origin is typing.Literal:
        return {"enum": list(args)}
    if origin is tuple and args and args[-1] is not Ellipsis:
        return {"type": "array", "prefixItems": [_schema(a, defs) for a in args], "items": False}
    if origin in (list, tuple, Sequence):
        return {"type": "array", "items": _schema(args[0], defs) if args else {}}
    if origin in (dict, Mapping):
        return {"type": "object", "additionalProperties": _schema(args[1], defs) if args else {}}
    if hint is bool:
        return {"type": "boolean"}
    if hint is int:
        return {"type": "integer"}
    if hint is float:
        return {"type": ["number", "null"]}
    if hint is str:
        return {"type": "string"}
    if dataclasses.is_dataclass(hint) or typing.is_typeddict(hint):
        name = hint.__name__
        if name not in defs:
            defs[name] = {}  # a record that contains itself refers to this entry
            defs[name] = _record(hint, defs)
        return {"$ref": f"#/$defs/{name}"}
    raise TypeError(f"no JSON Schema for the type {hint!r}")


def _record(record: type, defs: dict[str, JSONValue]) -> dict[str, JSONValue]:
    """The object schema of a dataclass or ``TypedDict``."""
    hints = typing.get_type_hints(record)
    properties: dict[str, JSONValue] = {}
    required: list[str] = []
    if typing.is_typeddict(record):
        for key, hint in hints.items():
            properties[key] = _schema(hint, defs)
        required = [key for key in hints if key in record.__required_keys__]  # type: ignore[attr-defined]
    else:
        for f in dataclasses.fields(record):
            if f.metadata.get(INLINE):
                inner = next(a for a in typing.get_args(hints[f.name]) or (hints[f.name],) if a is not type(None))
                for g in dataclasses.fields(inner):
                    properties[g.name] = _schema(typing.get_type_hints(inner)[g.name], defs)
                continue
            properties[f.name] = _schema(hints[f.name], defs)
            if not f.metadata.get(OMIT_IF_NONE):
                required.append(f.name)
    doc = inspect.getdoc(record) or ""
    described = {"description": doc} if doc and not doc.startswith(f"{record.__name__}(") else {}
    return {"type": "object", **described, "properties": properties, "required": required,
            "additionalProperties": False}
