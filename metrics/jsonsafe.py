"""Strict JSON for result documents.

RFC 8259 section 6: "Numeric values that cannot be represented in the grammar
below (such as Infinity and NaN) are not permitted." Python's ``json`` writes
them as ``NaN`` / ``Infinity`` by default, which other JSON readers reject;
every result document is therefore written with non-finite numbers as
``null`` (the value is missing) and ``allow_nan=False`` as a guard.
"""

from __future__ import annotations

import json
import math
from typing import Any

import numpy as np


def json_safe(value: Any) -> Any:
    """``value`` with every non-finite float (NaN, +-inf) replaced by None, numpy scalars and
    arrays as Python numbers and lists, tuples as lists; dict keys are kept.

    Examples
    --------
    >>> json_safe({"a": np.float64(1.5), "b": float("nan"), "c": (1, np.int64(2))})
    {'a': 1.5, 'b': None, 'c': [1, 2]}
    """
    if isinstance(value, dict):
        return {key: json_safe(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [json_safe(item) for item in value]
    if isinstance(value, np.ndarray):
        return json_safe(value.tolist())
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def dumps_strict(value: Any, **options: Any) -> str:
    """``json.dumps`` of :func:`json_safe` (``value``), refusing anything that is not valid JSON.

    Examples
    --------
    >>> dumps_strict({"x": float("inf"), "y": np.array([1.0, 2.0])})
    '{"x": null, "y": [1.0, 2.0]}'
    """
    return json.dumps(json_safe(value), allow_nan=False, **options)
