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
import json
import math
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
