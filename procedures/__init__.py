"""Procedures: one module per measurement procedure, each a generator of steps.

``PROCEDURES`` maps the campaign's ``kind`` to its configuration model; the
campaign validates ``[[procedure]]`` entries against the union of these.
"""

from __future__ import annotations

from procedures.alignment import Alignment, FaceMask
from procedures.depth_sweep import DepthSweep, XYSweep
from procedures.offset_calibration import OffsetCalibration
from procedures.remission_angle import RemissionAngle
from procedures.slanted_edge import SlantedEdge
from procedures.steps import Step
from procedures.targets_at_focus import BoehlerStar, Checkerboard
from procedures.vdi2634 import Flatness, SphereBar

PROCEDURES = {
    "alignment": Alignment,
    "offset_calibration": OffsetCalibration,
    "depth_sweep": DepthSweep,
    "xy_sweep": XYSweep,
    "slanted_edge": SlantedEdge,
    "checkerboard": Checkerboard,
    "boehler_star": BoehlerStar,
    "remission_angle": RemissionAngle,
    "face_mask": FaceMask,
    "sphere_bar": SphereBar,
    "flatness": Flatness,
}

ProcedureConfig = (
    Alignment | OffsetCalibration | DepthSweep | XYSweep | SlantedEdge | Checkerboard | BoehlerStar
    | RemissionAngle | FaceMask | SphereBar | Flatness
)

__all__ = ["PROCEDURES", "ProcedureConfig", "Step"]
