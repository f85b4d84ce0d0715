"""Influence of target remission and angle on the robot (Thesis 2024, 5.4, 6.5).

For every material the operator mounts the plate on the hoist (one prompt per
swap, with the hoist height), then the robot carries the camera around the
circle of ``radius_mm`` from ``angles_deg[0]`` to ``angles_deg[1]`` in
``angles_deg[2]`` steps (alternating direction between materials to save
motion), a stack at every angle.
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import ClassVar, Literal

from pydantic import Field, field_validator, model_validator

from procedures.depth_sweep import MAX_POSITIONS
from procedures.steps import Step, StrictModel

MATERIALS = ("ptfe", "molleton", "silicone", "gelatine", "collagen")
SKIN_LIKE = ("silicone", "gelatine", "collagen")


def _count(start: float, stop: float, step: float) -> int:
    return int(round((stop - start) / step)) + 1


def angle_positions(start: float, stop: float, step: float) -> list[float]:
    """Inclusive angles start, start + step, ... <= stop."""
    return [round(start + i * step, 6) for i in range(_count(start, stop, step))]


class RemissionAngle(StrictModel):
    """Campaign entry ``kind = "remission_angle"``."""

    needs_reference: ClassVar[bool] = False

    kind: Literal["remission_angle"]
    materials: list[Literal["ptfe", "molleton", "silicone", "gelatine", "collagen"]] = Field(
        default_factory=lambda: list(MATERIALS), min_length=1
    )
    angles_deg: tuple[float, float, float] = (-80.0, 80.0, 10.0)
    radius_mm: float = Field(850.0, gt=50.0, le=2000.0)
    hoist_height_mm: float = Field(0.0, description="hoist setting the operator is asked for (recorded)")
    plate_mm: float = Field(200.0, gt=10.0, le=1000.0)
    frames: int = Field(100, ge=1, le=10000)
    exposure_us: float | None = Field(None, gt=0)
    camera_settings: dict[str, object] = Field(default_factory=dict)

    @field_validator("materials")
    @classmethod
    def _unique(cls, materials: list[str]) -> list[str]:
        if len(set(materials)) != len(materials):
            raise ValueError(f"materials must not repeat: {materials}")
        return materials

    @model_validator(mode="after")
    def _angles(self) -> RemissionAngle:
        start, stop, step = self.angles_deg
        if step <= 0 or stop < start:
            raise ValueError(f"angles_deg must be [start, stop, step] with step > 0 and stop >= start, got "
                             f"{list(self.angles_deg)}")
        if not (-90.0 < start and stop < 90.0):
            raise ValueError(f"angles_deg must stay inside (-90, 90) deg, got {list(self.angles_deg)}")
        if (count := _count(start, stop, step)) > MAX_POSITIONS:
            raise ValueError(f"angles_deg step {step:g} gives {count:.3g} robot poses from {start:g} to {stop:g} deg, "
                             f"more than the {MAX_POSITIONS} a sweep may have: check the step's unit (deg)")
        return self

    def angles(self) -> list[float]:
        return angle_positions(*self.angles_deg)

    def stage_distances_mm(self) -> list[float]:
        return []

    def robot_positions(self) -> list[tuple[float, float]]:
        """(angle, radius) of every planned robot pose."""
        return [(a, self.radius_mm) for a in self.angles()]

    def steps(self, first_index: int) -> Iterator[Step]:
        index = first_index
        for n, material in enumerate(self.materials):
            angles = self.angles() if n % 2 == 0 else self.angles()[::-1]
            for k, angle in enumerate(angles):
                yield Step(
                    index=index,
                    procedure=self.kind,
                    target=material,
                    target_params={"plate_mm": self.plate_mm, "hoist_height_mm": self.hoist_height_mm},
                    frames=self.frames,
                    robot_angle_deg=angle,
                    robot_radius_mm=self.radius_mm,
                    exposure_us=self.exposure_us,
                    camera_settings=self.camera_settings,
                    prompt=(f"mount the {material} plate on the hoist at {self.hoist_height_mm:g} mm, its face "
                            "through the circle centre, facing the 0 deg camera") if k == 0 else None,
                )
                index += 1
