"""Camera alignment to the wall (Thesis 2024, 4.1.2) and the face mask capture (Thesis 2024, 6.7).

``alignment``: the camera looks at the wall at ``distance_mm``; the runner
shows the four corner-field depths and the tilt they imply after every stack
of ``frames`` (default 10, as in Thesis 2024) and asks the operator to adjust
the tilt stage and measure again, or accept; the accepted fields and residual
tilt are recorded with the step.

``face_mask``: the silicone mask ``gap_mm`` in front of the wall, the camera
at ``distance_mm`` from the mask (or ``"best_focus"``), 100 frames; the
evaluation exports its organized point cloud and renders it in the report.
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import ClassVar, Literal

from pydantic import Field

from procedures.steps import Step, StrictModel
from procedures.targets_at_focus import BEST_FOCUS


class Alignment(StrictModel):
    """Campaign entry ``kind = "alignment"``."""

    needs_reference: ClassVar[bool] = False

    kind: Literal["alignment"]
    distance_mm: float = Field(2000.0, gt=0)
    frames: int = Field(10, ge=1, le=1000)
    field_px: int = Field(10, ge=1, le=100)
    margin_px: int | None = Field(None, ge=0, description="fields' distance from the image border (10 % of it)")
    camera_settings: dict[str, object] = Field(default_factory=dict)

    def stage_distances_mm(self) -> list[float]:
        return [self.distance_mm]

    def steps(self, first_index: int) -> Iterator[Step]:
        yield Step(
            index=first_index,
            procedure=self.kind,
            target="wall",
            target_params={"field_px": self.field_px, "margin_px": self.margin_px},
            frames=self.frames,
            distance_mm=self.distance_mm,
            camera_settings=self.camera_settings,
            role="alignment",
        )


class FaceMask(StrictModel):
    """Campaign entry ``kind = "face_mask"``."""

    needs_reference: ClassVar[bool] = False

    kind: Literal["face_mask"]
    distance_mm: float | Literal["best_focus"] = Field(BEST_FOCUS, description="camera-mask distance")
    gap_mm: float = Field(300.0, gt=0.0, le=3000.0, description="mask base to wall")
    frames: int = Field(100, ge=1, le=10000)
    exposure_us: float | None = Field(None, gt=0)
    camera_settings: dict[str, object] = Field(default_factory=dict)

    def stage_distances_mm(self) -> list[float]:
        return [] if self.distance_mm == BEST_FOCUS else [float(self.distance_mm) + self.gap_mm]

    def steps(self, first_index: int) -> Iterator[Step]:
        best = self.distance_mm == BEST_FOCUS
        yield Step(
            index=first_index,
            procedure=self.kind,
            target="face_mask",
            target_params={"gap_mm": self.gap_mm},
            frames=self.frames,
            distance_mm=None if best else float(self.distance_mm) + self.gap_mm,
            distance_from=BEST_FOCUS if best else None,
            distance_offset_mm=self.gap_mm,
            exposure_us=self.exposure_us,
            camera_settings=self.camera_settings,
            prompt=f"mount the silicone face mask {self.gap_mm:g} mm in front of the wall, facing the camera",
        )
