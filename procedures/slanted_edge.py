"""Sharpness over distance with the ISO 12233 slanted-edge chart (Thesis 2024, 5.1.2, 6.2).

The operator mounts the chart (one prompt), the camera sweeps it from
``start_mm`` to ``stop_mm``; then the operator covers the chart with the
white sheet once, and the camera sweeps back over the same distances for the white reference (one prompt instead of
one per position). Exposure may follow the distance, as in Thesis 2024, Table C-1:
``exposure_table = [[from_mm, exposure_us], ...]`` uses the exposure of the
last row whose ``from_mm`` is not above the distance.
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import ClassVar, Literal

from pydantic import Field, field_validator, model_validator

from procedures.depth_sweep import check_sweep, sweep_positions
from procedures.steps import Step, StrictModel

COVER_PROMPT = "cover the slanted-edge chart with the white sheet (white reference)"


def mount_prompt(angle_deg: float) -> str:
    """The operator's set-up of the chart before the first chart step."""
    return (f"mount the slanted-edge chart on the wall, its edges slanted {angle_deg:g} deg from the image axes, "
            "centred on the camera axis")


class SlantedEdge(StrictModel):
    """Campaign entry ``kind = "slanted_edge"``."""

    needs_reference: ClassVar[bool] = False

    kind: Literal["slanted_edge"]
    start_mm: float = Field(100.0, gt=0, description="nearest distance (the chart cannot be touched)")
    stop_mm: float = Field(3000.0, gt=0)
    step_mm: float = Field(100.0, gt=0)
    frames: int = Field(100, ge=1, le=10000)
    angle_deg: float = Field(8.0, ge=2.0, le=40.0, description="slant of the chart's edges")
    exposure_us: float | None = Field(None, gt=0, description="one exposure for every distance")
    exposure_table: list[tuple[float, float]] = Field(
        default_factory=list, description="[[from_mm, exposure_us], ...], ascending from_mm"
    )
    camera_settings: dict[str, object] = Field(default_factory=dict)

    @field_validator("exposure_table")
    @classmethod
    def _ascending(cls, table: list[tuple[float, float]]) -> list[tuple[float, float]]:
        starts = [row[0] for row in table]
        if starts != sorted(starts) or len(set(starts)) != len(starts):
            raise ValueError("exposure_table rows must have strictly ascending from_mm")
        if any(e <= 0 for _, e in table):
            raise ValueError("exposure_table exposures must be > 0 us")
        return table

    @model_validator(mode="after")
    def _consistent(self) -> SlantedEdge:
        check_sweep(self.start_mm, self.stop_mm, self.step_mm)
        if self.exposure_us is not None and self.exposure_table:
            raise ValueError("give either exposure_us or exposure_table, not both")
        return self

    def exposure_at(self, distance_mm: float) -> float | None:
        """Exposure for ``distance_mm``: the table's row, the fixed value, or None (camera default)."""
        chosen = self.exposure_us
        for start, exposure in self.exposure_table:
            if distance_mm >= start:
                chosen = exposure
        return chosen

    def stage_distances_mm(self) -> list[float]:
        return sweep_positions(self.start_mm, self.stop_mm, self.step_mm)

    def steps(self, first_index: int) -> Iterator[Step]:
        """Chart at every distance (near to far), then the white sheet (far to near)."""
        distances = self.stage_distances_mm()
        index = first_index
        for target, order in (("slanted_edge", distances), ("white_sheet", distances[::-1])):
            for n, distance in enumerate(order):
                yield Step(
                    index=index,
                    procedure=self.kind,
                    target=target,
                    target_params={"angle_deg": self.angle_deg},
                    frames=self.frames,
                    distance_mm=distance,
                    exposure_us=self.exposure_at(distance),
                    camera_settings=self.camera_settings,
                    prompt=None if n else (COVER_PROMPT if target == "white_sheet" else mount_prompt(self.angle_deg)),
                )
                index += 1
