"""Steps: the unit of a plan, of execution, of checkpointing and of resume.

A procedure is a generator of :class:`Step` objects. Because a plan is plain
data, ``labctl plan`` can list and time it without touching hardware, and the
runner can skip steps that are already complete in a run file.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from pydantic import BaseModel, ConfigDict


class StrictModel(BaseModel):
    """Base of every configuration model: unknown keys are an error, and so are NaN and infinity (TOML
    spells them ``nan`` and ``inf``; no configuration number may be either)."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


@dataclass(frozen=True)
class Step:
    """One capture: where the devices go, what the camera sees, how many frames.

    ``distance_mm`` is the nominal camera-to-wall distance set with the stage
    (None when the stage does not move for this step). ``distance_from``
    names a distance the runner resolves at run time (``"best_focus"``: from
    the run's slanted-edge steps), to which ``distance_offset_mm`` is added
    (e.g. a star's gap to the wall). ``robot_angle_deg`` is the
    position on the robot's measurement circle (None without robot).
    ``target_params`` describe the target (e.g. a Boehler star's segments and
    gap to the wall) and are recorded with the step. ``prompt``
    is an operator action that must be confirmed before the step starts (e.g. a
    target swap). ``role`` tells the runner about special steps: ``"offset"``
    steps determine the camera-laser offset used for every later reference
    distance.
    """

    index: int
    procedure: str
    target: str
    frames: int
    target_params: Mapping[str, Any] = field(default_factory=dict)
    distance_mm: float | None = None
    distance_from: str | None = None
    distance_offset_mm: float = 0.0
    robot_angle_deg: float | None = None
    robot_radius_mm: float | None = None
    exposure_us: float | None = None
    camera_settings: Mapping[str, Any] = field(default_factory=dict)
    prompt: str | None = None
    role: str = "capture"

    @property
    def step_id(self) -> str:
        """``<NNNNN>_<procedure kind>`` (docs/runfile.md)."""
        return f"{self.index:05d}_{self.procedure}"
