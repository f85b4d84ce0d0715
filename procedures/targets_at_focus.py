"""Procedures that capture one target at the camera's sharpest distance (Thesis 2024, 5.2.1, 6.3.2, 6.4).

``distance_mm`` is a number (camera-to-target distance) or ``"best_focus"``:
the runner then takes the distance from the campaign's earlier
``slanted_edge`` steps — the nearest distance whose sharpness is within 5 % of
the best, because "if there are multiple distances with high focus, the
smallest distance is chosen" (Thesis 2024, 5.2.1), which keeps the tiles and
segments large.

* ``checkerboard`` (Thesis 2024, 5.2-5.3): a 19 mm board on the wall, filling the image;
* ``boehler_star`` (Thesis 2024, 5.1.3): a Boehler star ``gap_mm`` in front of the wall;
  ``segments`` 72, 24 or both ``[72, 24]`` (the 24-segment star is the
  fallback where the 72 is not resolved, Thesis 2024, 6.3.2) with an operator prompt
  per star swap.
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import ClassVar, Literal

from pydantic import Field, field_validator

from procedures.steps import Step, StrictModel

BEST_FOCUS = "best_focus"


class Checkerboard(StrictModel):
    """Campaign entry ``kind = "checkerboard"``."""

    needs_reference: ClassVar[bool] = False

    kind: Literal["checkerboard"]
    distance_mm: float | Literal["best_focus"] = Field(BEST_FOCUS, description="camera-board distance")
    tile_mm: float = Field(19.0, gt=1.0, le=200.0)
    frames: int = Field(100, ge=1, le=10000)
    exposure_us: float | None = Field(None, gt=0)
    camera_settings: dict[str, object] = Field(default_factory=dict)

    @field_validator("distance_mm")
    @classmethod
    def _positive(cls, value: float | str) -> float | str:
        if isinstance(value, (int, float)) and value <= 0:
            raise ValueError("distance_mm must be > 0 or 'best_focus'")
        return value

    def stage_distances_mm(self) -> list[float]:
        return [] if self.distance_mm == BEST_FOCUS else [float(self.distance_mm)]

    def steps(self, first_index: int) -> Iterator[Step]:
        yield Step(
            index=first_index,
            procedure=self.kind,
            target="checkerboard",
            target_params={"tile_mm": self.tile_mm},
            frames=self.frames,
            distance_mm=None if self.distance_mm == BEST_FOCUS else float(self.distance_mm),
            distance_from=BEST_FOCUS if self.distance_mm == BEST_FOCUS else None,
            exposure_us=self.exposure_us,
            camera_settings=self.camera_settings,
            prompt=f"mount the checkerboard ({self.tile_mm:g} mm tiles) on the wall, filling the view",
        )


class BoehlerStar(StrictModel):
    """Campaign entry ``kind = "boehler_star"``."""

    needs_reference: ClassVar[bool] = False

    kind: Literal["boehler_star"]
    distance_mm: float | Literal["best_focus"] = Field(BEST_FOCUS, description="camera-star distance")
    segments: int | list[int] = Field(72, description="72, 24, or [72, 24] to capture both stars")
    gap_mm: float = Field(300.0, gt=0.0, le=3000.0, description="star to wall")
    frames: int = Field(100, ge=1, le=10000)
    exposure_us: float | None = Field(None, gt=0)
    camera_settings: dict[str, object] = Field(default_factory=dict)

    @field_validator("segments")
    @classmethod
    def _stars(cls, value: int | list[int]) -> int | list[int]:
        stars = value if isinstance(value, list) else [value]
        if not stars or any(n not in (24, 72) for n in stars) or len(set(stars)) != len(stars):
            raise ValueError(f"segments must be 72, 24 or [72, 24], got {value!r}")
        return value

    @field_validator("distance_mm")
    @classmethod
    def _positive(cls, value: float | str) -> float | str:
        if isinstance(value, (int, float)) and value <= 0:
            raise ValueError("distance_mm must be > 0 or 'best_focus'")
        return value

    @property
    def stars(self) -> list[int]:
        return self.segments if isinstance(self.segments, list) else [self.segments]

    def stage_distances_mm(self) -> list[float]:
        """The stage sets the camera-wall distance: star distance plus gap."""
        return [] if self.distance_mm == BEST_FOCUS else [float(self.distance_mm) + self.gap_mm]

    def steps(self, first_index: int) -> Iterator[Step]:
        for n, segments in enumerate(self.stars):
            yield Step(
                index=first_index + n,
                procedure=self.kind,
                target="boehler_star",
                target_params={"segments": segments, "gap_mm": self.gap_mm},
                frames=self.frames,
                distance_mm=None if self.distance_mm == BEST_FOCUS else float(self.distance_mm) + self.gap_mm,
                distance_from=BEST_FOCUS if self.distance_mm == BEST_FOCUS else None,
                distance_offset_mm=self.gap_mm,
                exposure_us=self.exposure_us,
                camera_settings=self.camera_settings,
                prompt=f"place the {segments}-segment Boehler star {self.gap_mm:g} mm in front of the wall, "
                "centred on the camera axis",
            )
