"""Evaluation of the face mask (Thesis 2024, 6.7) and of the alignment record (Thesis 2024, 4.1.2).

The face mask's stack-mean organized cloud is kept for export (PCD) and a
rendering in the report; the alignment step's accepted corner fields and
residual tilt are reported as recorded by the runner.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from labctl.run.store import StepRecord
from metrics.stack import stack_stats


@dataclass(frozen=True)
class FaceMaskResult:
    step_id: str
    distance_mm: float
    cloud: np.ndarray  # (H, W, 3) stack mean, NaN invalid
    intensity: np.ndarray
    invalid_fraction: float


@dataclass(frozen=True)
class AlignmentRecord:
    step_id: str
    fields_mm: dict[str, tuple[float, float, float]]
    tilt_x_deg: float
    tilt_y_deg: float


def face_mask(step: StepRecord) -> FaceMaskResult:
    """The mask's stack-mean cloud (x, y, z stacked on the last axis) and intensity."""
    x, y, z = (stack_stats(step.read(c)).mean for c in ("x", "y", "z"))
    cloud = np.stack([x, y, z], axis=-1).astype(np.float32)
    return FaceMaskResult(step.step_id, float(step.attrs.get("distance_mm", math.nan)), cloud,
                          stack_stats(step.read("intensity")).mean.astype(np.float32),
                          float(np.mean(~np.isfinite(z))))


def alignment(step: StepRecord) -> AlignmentRecord | None:
    """The accepted alignment of an ``alignment`` step (None if the step carries none)."""
    raw: Any = step.attrs.get("alignment_fields_json")
    if raw is None:
        return None
    fields = {name: tuple(values) for name, values in json.loads(raw).items()}
    return AlignmentRecord(step.step_id, fields, float(step.attrs["tilt_x_deg"]), float(step.attrs["tilt_y_deg"]))
