"""Result documents as JSON: the one conversion from the project's result dataclasses to JSON text.

The result files labctl writes (``keyfigures.json``, ``reconcile.json``,
``compare.json``, a batch's ``index.json``) are built from typed dataclasses
and turned into JSON here, so that a document's keys are the fields of its
dataclass, in their declared order:

* a dataclass becomes an object with one key per field, in field order;
* a field declared with :func:`optional` is left out while it is ``None``
  (documents whose later keys appear only when they apply);
* dicts, lists and tuples are converted item by item, everything else as
  :func:`metrics.jsonsafe.json_safe` does (numpy numbers as Python numbers,
  non-finite floats as ``null``: RFC 8259 section 6).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

from metrics.jsonsafe import dumps_strict, json_safe

#: field metadata: leave the key out of the document while the value is None
OMIT_IF_NONE = "omit_if_none"


def optional() -> Any:
    """A dataclass field that defaults to None and is left out of the JSON document while it is None."""
    return dataclasses.field(default=None, metadata={OMIT_IF_NONE: True})


def to_json(value: object) -> Any:
    """``value`` as JSON values: dataclasses as objects in field order (``optional`` fields left out while None),
    containers item by item, numbers JSON-safe."""
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {f.name: to_json(getattr(value, f.name)) for f in dataclasses.fields(value)
                if not (f.metadata.get(OMIT_IF_NONE) and getattr(value, f.name) is None)}
    if isinstance(value, dict):
        return {key: to_json(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [to_json(item) for item in value]
    return json_safe(value)


def dumps(value: object, indent: int | None = 2) -> str:
    """The JSON text of ``value`` (:func:`to_json`), refusing anything that is not valid JSON."""
    return dumps_strict(to_json(value), indent=indent)


def write_json(path: Path, value: object, final_newline: bool = False) -> Path:
    """Write ``value`` as indented JSON (:func:`dumps`) to ``path``; returns ``path``."""
    path.write_text(dumps(value) + ("\n" if final_newline else ""), encoding="utf-8")
    return path
