"""Camera-laser offset calibration (Thesis 2024, 4.1.2).

One stack on the wall at 2000 mm. The runner computes
``offset = mean camera depth (central 10 % x 10 % region) - laser reading``
from it; every later step's reference distance is the distance the laser
reading stands for in the camera's frame, ``laser reading + offset``. ("laser - offset" holds with the
opposite sign convention offset = laser - camera; Thesis 2024's definition,
camera - laser, 4.1.2, is used here.)
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import ClassVar, Literal

from pydantic import Field

from procedures.steps import Step, StrictModel


class OffsetCalibration(StrictModel):
    """Campaign entry ``kind = "offset_calibration"``."""

    needs_reference: ClassVar[bool] = False

    kind: Literal["offset_calibration"]
    distance_mm: float = Field(2000.0, gt=0, description="nominal camera-wall distance")
    frames: int = Field(100, ge=1, le=10000)
    exposure_us: float | None = Field(None, gt=0)
    camera_settings: dict[str, object] = Field(default_factory=dict)

    def stage_distances_mm(self) -> list[float]:
        """Nominal distances the stage must reach."""
        return [self.distance_mm]

    def steps(self, first_index: int) -> Iterator[Step]:
        """The single offset step."""
        yield Step(
            index=first_index,
            procedure=self.kind,
            target="wall",
            frames=self.frames,
            distance_mm=self.distance_mm,
            exposure_us=self.exposure_us,
            camera_settings=self.camera_settings,
            role="offset",
        )
