"""The evaluation's curves over distance as NeXus NXdata, ``OUTDIR/curves.h5``, beside keyfigures.json.

NeXus viewers (silx view, h5web) plot an NXdata group by itself: its ``signal`` over its ``axes``, with the
``auxiliary_signals`` beside it and ``<name>_errors`` as error bars, each dataset carrying ``units`` and
``long_name`` (NeXus NXdata base class, NIAC 2014 attribute convention). The file's ``@default`` leads to the
depth errors over distance.

* ``evaluation/depth_error``: trueness Q90 over the reference distance, with trueness median, accuracy Q90
  and median and precision Q90 and median as auxiliary signals (Thesis 2024, 4.2.1);
* ``evaluation/repeatability_center``: the centre pixel's repeatability over distance with its Type A standard
  uncertainty as errors (docs/keyfigures.md, Uncertainty);
* ``evaluation/z_accuracy``: the Depth Quality Tool's Z accuracy (%) over distance, where the steps have an
  absolute reference.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import h5py
import numpy as np

from labctl.evaluation.evaluate import Evaluation
from labctl.provenance import labctl_version

#: depth-error columns of the ``depth_error`` group: (DepthErrors attribute, long name)
DEPTH_COLUMNS = (
    ("trueness_q90_mm", "trueness Q90 |stack mean - reference| (mm)"),
    ("trueness_median_mm", "trueness median |stack mean - reference| (mm)"),
    ("accuracy_q90_mm", "accuracy Q90 |first frame - reference| (mm)"),
    ("accuracy_median_mm", "accuracy median |first frame - reference| (mm)"),
    ("precision_q90_mm", "precision Q90 of the per-pixel std (mm)"),
    ("precision_median_mm", "precision median of the per-pixel std (mm)"),
)


def _dataset(group: h5py.Group, name: str, values: Sequence[float], units: str, long_name: str) -> None:
    data = group.create_dataset(name, data=np.asarray(values, dtype="float64"))
    data.attrs.update(units=units, long_name=long_name)


def _nxdata(entry: h5py.Group, name: str, axis: Sequence[float], signal: str, auxiliary: Sequence[str],
            title: str) -> h5py.Group:
    group = entry.create_group(name)
    group.attrs.update(NX_class="NXdata", signal=signal, axes=["reference_mm"], title=title)
    if auxiliary:
        group.attrs["auxiliary_signals"] = list(auxiliary)
    _dataset(group, "reference_mm", axis, "mm", "reference distance (mm)")
    return group


def write_curves(evaluation: Evaluation, path: Path) -> Path | None:
    """Write the curves the evaluation has (none without wall steps: nothing is written, None returned)."""
    if not evaluation.depth:
        return None
    order = np.argsort([p.errors.reference_mm for p in evaluation.depth], kind="stable")
    depth = [evaluation.depth[i] for i in order]
    reference = [p.errors.reference_mm for p in depth]
    with h5py.File(path, "w") as f:
        f.attrs.update(NX_class="NXroot", default="evaluation", creator=f"labctl {labctl_version()}",
                       file_name=path.name)
        entry = f.create_group("evaluation")
        entry.attrs.update(NX_class="NXentry", default="depth_error")
        errors = _nxdata(entry, "depth_error", reference, DEPTH_COLUMNS[0][0], [c for c, _ in DEPTH_COLUMNS[1:]],
                         "depth errors over distance (Thesis 2024, 4.2.1)")
        for column, long_name in DEPTH_COLUMNS:
            _dataset(errors, column, [getattr(p.errors, column) for p in depth], "mm", long_name)
        centre = _nxdata(entry, "repeatability_center", reference, "repeatability_center_mm", [],
                         "centre pixel's repeatability over distance, error bars: its standard uncertainty")
        _dataset(centre, "repeatability_center_mm", [p.errors.repeatability_center_mm for p in depth], "mm",
                 "repeatability of the centre pixel (sample std over the stack, mm)")
        _dataset(centre, "repeatability_center_mm_errors", [p.repeatability_center_u_mm for p in depth], "mm",
                 "standard uncertainty of the repeatability (mm)")
        vendor = sorted(evaluation.vendor, key=lambda v: v.figures.reference_mm)
        if vendor:
            accuracy = _nxdata(entry, "z_accuracy", [v.figures.reference_mm for v in vendor], "z_accuracy_pct", [],
                               "Depth Quality Tool's Z accuracy over distance (against the absolute reference)")
            _dataset(accuracy, "z_accuracy_pct", [v.figures.z_accuracy_pct for v in vendor], "%",
                     "Z accuracy (% of the distance from the depth origin)")
    return path
