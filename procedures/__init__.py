"""Procedures: one module per measurement procedure, each a generator of steps.

``PROCEDURES`` maps the campaign's ``kind`` to its configuration model; the
campaign validates ``[[procedure]]`` entries against the union of these.
"""

from __future__ import annotations

from procedures.depth_sweep import DepthSweep
from procedures.offset_calibration import OffsetCalibration
from procedures.slanted_edge import SlantedEdge
from procedures.steps import Step

PROCEDURES = {
    "offset_calibration": OffsetCalibration,
    "depth_sweep": DepthSweep,
    "slanted_edge": SlantedEdge,
}

ProcedureConfig = OffsetCalibration | DepthSweep | SlantedEdge

__all__ = ["PROCEDURES", "ProcedureConfig", "Step"]
