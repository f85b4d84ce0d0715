"""Depth error on the wall over distance (Thesis 2024, 4.2.1).

The stage moves the camera from ``start_mm`` to ``stop_mm`` (inclusive) in
``step_mm`` increments; at each position a stack of ``frames`` frames of the
white wall is captured.

A sweep in one direction moves the distance, the run's time (a warm-up drift)
and the signal (intensity falls with the distance) together, so that an error
following one cannot be told from an error following another. ``order``
breaks the tie between distance and time: ``"descending"`` runs the sweep far
to near, ``"interleaved"`` takes every other position on the way out and the
rest on the way back, so that near and far positions are each seen early and
late. ``return_mm`` adds one more stack at the end at that distance (the
reference distance of the offset calibration, seen again long after it).
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import ClassVar, Literal

from pydantic import Field, model_validator

from procedures.steps import Step, StrictModel

#: the most positions one sweep may have: a 4 m stage travel in 0.4 mm steps. Beyond it the step is a typing
#: error (a step of 1e-7 mm would plan 10^10 stacks, and planning alone would exhaust the memory)
MAX_POSITIONS = 10_000


def _count(start_mm: float, stop_mm: float, step_mm: float) -> int:
    return int((stop_mm - start_mm) / step_mm + 1e-9) + 1


def sweep_positions(start_mm: float, stop_mm: float, step_mm: float) -> list[float]:
    """Inclusive arithmetic sweep ``start, start+step, ... <= stop`` (tolerant to rounding)."""
    return [round(start_mm + i * step_mm, 6) for i in range(_count(start_mm, stop_mm, step_mm))]


def check_sweep(start_mm: float, stop_mm: float, step_mm: float) -> None:
    """ValueError (a campaign validation message) when the sweep runs backwards or has more than
    ``MAX_POSITIONS`` positions."""
    if stop_mm < start_mm:
        raise ValueError(f"stop_mm ({stop_mm:g}) must not be smaller than start_mm ({start_mm:g})")
    if (count := _count(start_mm, stop_mm, step_mm)) > MAX_POSITIONS:
        raise ValueError(f"step_mm = {step_mm:g} gives {count:.3g} positions from {start_mm:g} to {stop_mm:g} mm, "
                         f"more than the {MAX_POSITIONS} a sweep may have: check the step's unit (mm)")


SweepOrder = Literal["ascending", "descending", "interleaved"]


def ordered(positions: list[float], order: SweepOrder) -> list[float]:
    """The positions in capture order: as given, reversed, or every other one out and the rest back
    (``[1, 2, 3, 4, 5]`` interleaved: ``[1, 3, 5, 4, 2]``)."""
    if order == "descending":
        return positions[::-1]
    if order == "interleaved":
        return positions[::2] + positions[1::2][::-1]
    return list(positions)


class DepthSweep(StrictModel):
    """Campaign entry ``kind = "depth_sweep"``."""

    needs_reference: ClassVar[bool] = True

    kind: Literal["depth_sweep"]
    start_mm: float = Field(400.0, gt=0)
    stop_mm: float = Field(4000.0, gt=0)
    step_mm: float = Field(100.0, gt=0)
    frames: int = Field(100, ge=1, le=10000)
    exposure_us: float | None = Field(None, gt=0)
    camera_settings: dict[str, object] = Field(default_factory=dict)
    order: SweepOrder = "ascending"
    return_mm: float | None = Field(None, gt=0, description="one more stack at this distance after the sweep")

    @model_validator(mode="after")
    def _ordered(self) -> DepthSweep:
        check_sweep(self.start_mm, self.stop_mm, self.step_mm)
        return self

    def stage_distances_mm(self) -> list[float]:
        """Nominal distances the stage must reach, in capture order (the return last)."""
        positions = ordered(sweep_positions(self.start_mm, self.stop_mm, self.step_mm), self.order)
        return positions + ([self.return_mm] if self.return_mm is not None else [])

    def steps(self, first_index: int) -> Iterator[Step]:
        """One wall stack per position in ``order`` (nearest first by default), then the return stack."""
        for i, distance in enumerate(self.stage_distances_mm()):
            yield Step(
                index=first_index + i,
                procedure=self.kind,
                target="wall",
                frames=self.frames,
                distance_mm=distance,
                exposure_us=self.exposure_us,
                camera_settings=self.camera_settings,
            )


class XYSweep(DepthSweep):
    """Campaign entry ``kind = "xy_sweep"``: the same wall sweep, evaluated for x/y noise (Thesis 2024, 5.3)."""

    needs_reference: ClassVar[bool] = False

    kind: Literal["xy_sweep"]  # type: ignore[assignment]
