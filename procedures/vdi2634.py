"""VDI/VDE 2634 Part 2 acceptance test on the stage: a ball bar and a flat plate in front of the wall.

* ``sphere_bar``: a ball bar with two spheres of calibrated ``sphere_diameter_mm``
  whose centres are a calibrated ``sphere_spacing_mm`` apart, placed by the
  operator (one prompt per placement) ``gap_mm`` in front of the wall at each of
  ``distances_mm`` (camera to bar) and each of ``orientations_deg`` (the bar's
  direction in the image plane: 0 horizontal, 90 vertical, 45 / 135 the
  diagonals), each with ``tilt_deg`` out of the image plane; or, with
  ``placements``, each placement at its own ``distance_mm``, ``offset_mm``
  (right, up of the camera axis), ``orientation_deg`` and ``tilt_deg``
  (towards the wall), so that the positions spread through the measuring
  volume, its space diagonals included, as VDI/VDE 2634-2 asks for the
  sphere-spacing error (the bar is placed by hand: no procedure has the robot
  hold an artefact); each sphere is fitted with the rim rule of
  ``metrics.vdi2634`` (``max_incidence_deg``, ``rim_margin_px``);
* ``flatness``: a flat plate of ``plate_mm`` placed ``gap_mm`` in front of the
  wall at each distance, tilted about the vertical axis by each of ``tilts_deg``.

A measurement is the mean of ``frames_per_measurement`` frames (default: all
of the step's ``frames``, one measurement per placement), so each placement
gives ``frames // frames_per_measurement`` measurements. The maximum
permissible errors (``mpe_*_mm``, optional) and the artefacts' calibration
uncertainties (``sphere_*_uncertainty_mm``, ``flatness_uncertainty_mm``, optional,
stated with ``calibration_coverage_factor`` as the certificate states them) travel with
the steps' target parameters; the evaluation gives pass / fail / marginal per
quantity.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from typing import ClassVar, Literal

import numpy as np
from pydantic import Field, model_validator

from procedures.steps import Step, StrictModel


class _Artefact(StrictModel):
    """What both artefact procedures share: placements in front of the wall at several distances."""

    needs_reference: ClassVar[bool] = False

    kind: str
    gap_mm: float = Field(500.0, gt=0.0, le=3000.0, description="artefact to wall")
    frames: int = Field(10, ge=1, le=10000)
    exposure_us: float | None = Field(None, gt=0)
    camera_settings: dict[str, object] = Field(default_factory=dict)
    distances_mm: list[float]
    frames_per_measurement: int | None = Field(None, ge=1, le=10000,
                                               description="frames averaged into one measurement (default: all)")
    calibration_coverage_factor: float = Field(
        2.0, ge=1.0, le=10.0, description="k the certificate states its uncertainties with (1: standard)")

    @model_validator(mode="after")
    def _measurements_divide_frames(self) -> _Artefact:
        if self.frames_per_measurement is not None and self.frames % self.frames_per_measurement:
            raise ValueError(f"frames_per_measurement = {self.frames_per_measurement} must divide frames = "
                             f"{self.frames} (each measurement averages that many frames)")
        return self

    def averaged_frames(self) -> int:
        """Frames averaged into one measurement: ``frames_per_measurement``, else all of a step's frames."""
        return self.frames if self.frames_per_measurement is None else self.frames_per_measurement

    def stage_distances_mm(self) -> list[float]:
        """The stage sets the camera-wall distance: artefact distance plus gap."""
        return [d + self.gap_mm for d in self.distances_mm]

    def _step(self, index: int, distance: float, target: str, params: dict[str, object], prompt: str) -> Step:
        return Step(index=index, procedure=self.kind, target=target, target_params={"gap_mm": self.gap_mm,
                    "frames_per_measurement": self.averaged_frames(), **params},
                    frames=self.frames, distance_mm=distance + self.gap_mm, exposure_us=self.exposure_us,
                    camera_settings=self.camera_settings, prompt=prompt)


#: steepest tilt of a placement towards the wall (both spheres must stay apart in the image: ``BallBarPlacement``)
MAX_PLACEMENT_TILT_DEG = 80.0
#: the eight directions of the image (right, up: as seen from the camera) a bar's far end is named by in a prompt
_DIRECTIONS = ("right", "upper right", "upper", "upper left", "left", "lower left", "lower", "lower right")


class BallBarPlacement(StrictModel):
    """One position and orientation of the ball bar (VDI/VDE 2634-2, sphere-spacing error: positions spread
    through the measuring volume, along its space diagonals too).

    ``distance_mm``: camera to the bar's middle along the camera axis; ``offset_mm``: the middle's offset
    right of and above the camera axis, as seen from the camera; ``orientation_deg``: the bar's direction in
    the image plane, from horizontal, clockwise as seen from the camera (0 horizontal, 90 vertical, as
    ``orientations_deg``); ``tilt_deg``: the bar turned out of the image plane, the sphere at the
    ``orientation_deg`` end towards the wall.
    """

    distance_mm: float = Field(gt=0.0, le=20000.0, description="camera to the bar's middle")
    offset_mm: tuple[float, float] = Field((0.0, 0.0), description="the middle right of, above the camera axis")
    orientation_deg: float = Field(0.0, ge=-360.0, le=360.0, description="in the image plane, 0 horizontal")
    tilt_deg: float = Field(0.0, ge=-MAX_PLACEMENT_TILT_DEG, le=MAX_PLACEMENT_TILT_DEG,
                            description="out of the image plane, towards the wall")

    def centres_mm(self, spacing_mm: float) -> tuple[np.ndarray, np.ndarray]:
        """The two sphere centres in the camera frame (x right, y down, z along the axis): the first at the
        ``orientation_deg + 180`` end, the second at the ``orientation_deg`` end (the one tilted towards the
        wall for ``tilt_deg`` > 0)."""
        phi, tilt = math.radians(self.orientation_deg), math.radians(self.tilt_deg)
        axis = np.array([math.cos(phi) * math.cos(tilt), math.sin(phi) * math.cos(tilt), math.sin(tilt)])
        middle = np.array([self.offset_mm[0], -self.offset_mm[1], self.distance_mm])
        return middle - axis * spacing_mm / 2, middle + axis * spacing_mm / 2

    def problem(self, spacing_mm: float, diameter_mm: float, gap_mm: float) -> str | None:
        """Why the camera could not see both spheres apart (the near one hiding part of the far one, or one
        behind the camera), or why the far one would not stand clear of the wall's half gap the evaluation
        cuts the artefact at; None when the placement is measurable."""
        radius = diameter_mm / 2
        centres = self.centres_mm(spacing_mm)
        if min(c[2] for c in centres) <= radius:
            return "the near sphere would reach the camera"
        far = max(c[2] for c in centres) - self.distance_mm
        if far + radius >= gap_mm / 2:
            return (f"the far sphere would reach {far + radius:.0f} mm behind the bar's middle, not clear of half "
                    f"the gap to the wall ({gap_mm / 2:g} mm) where the evaluation separates artefact and wall")
        first, second = (c / np.linalg.norm(c) for c in centres)
        apart = math.acos(float(np.clip(first @ second, -1.0, 1.0)))
        sizes = sum(math.asin(radius / float(np.linalg.norm(c))) for c in centres)
        if apart <= sizes:
            return (f"the spheres would overlap in the image ({math.degrees(apart):.1f} deg apart as seen from the "
                    f"camera, {math.degrees(sizes):.1f} deg needed): the near one hides part of the far one")
        return None

    def prompt(self, diameter_mm: float, spacing_mm: float, gap_mm: float) -> str:
        """The operator's instruction, in the words of a person standing at the camera looking at the wall."""
        right, up = self.offset_mm
        sides = [f"{abs(right):g} mm {'right' if right > 0 else 'left'} of"] if right else []
        sides += [f"{abs(up):g} mm {'above' if up > 0 else 'below'}"] if up else []
        where = f"{' and '.join(sides)} the camera axis" if sides else "on the camera axis"
        text = (f"place the ball bar ({diameter_mm:g} mm spheres, {spacing_mm:g} mm apart) with its middle "
                f"{self.distance_mm:g} mm from the camera ({gap_mm:g} mm in front of the wall), {where}, at "
                f"{self.orientation_deg:g} deg from horizontal (clockwise as seen from the camera)")
        if self.tilt_deg == 0:
            return text + ", parallel to the wall"
        # the end tilted towards the wall: the orientation_deg end for a positive tilt, in image words (y up)
        end = self.orientation_deg + (0.0 if self.tilt_deg > 0 else 180.0)
        name = _DIRECTIONS[round((-end % 360.0) / 45.0) % 8]
        return text + f", tilted {abs(self.tilt_deg):g} deg out of the wall's plane with its {name} sphere towards the wall"


class SphereBar(_Artefact):
    """Campaign entry ``kind = "sphere_bar"``."""

    kind: Literal["sphere_bar"]
    sphere_diameter_mm: float = Field(50.0, gt=1.0, le=500.0, description="calibrated diameter of both spheres")
    sphere_spacing_mm: float = Field(300.0, gt=1.0, le=3000.0, description="calibrated centre distance")
    distances_mm: list[float] = Field([1000.0, 1500.0, 2000.0], min_length=1, description="camera to bar")
    orientations_deg: list[float] = Field([0.0, 45.0, 90.0, 135.0], min_length=1)
    tilt_deg: float = Field(0.0, ge=-60.0, le=60.0, description="bar out of the image plane")
    max_incidence_deg: float = Field(60.0, gt=0.0, le=90.0, description="rim rule: steepest incidence kept")
    rim_margin_px: float = Field(1.0, ge=0.0, le=20.0, description="rim rule: pixels kept inside the silhouette")
    sphere_diameter_uncertainty_mm: float | None = Field(
        None, ge=0, le=10.0, description="calibration certificate's uncertainty of the diameter")
    sphere_spacing_uncertainty_mm: float | None = Field(
        None, ge=0, le=10.0, description="calibration certificate's uncertainty of the centre distance")
    sphere_form_uncertainty_mm: float | None = Field(
        None, ge=0, le=10.0, description="calibration certificate's uncertainty of the spheres' form deviation")
    mpe_form_mm: float | None = Field(None, gt=0, description="maximum permissible probing error form")
    mpe_size_mm: float | None = Field(None, gt=0, description="maximum permissible |probing error size|")
    mpe_spacing_mm: float | None = Field(None, gt=0, description="maximum permissible |sphere-spacing error|")
    placements: list[BallBarPlacement] | None = Field(
        None, min_length=1, description="each placement's position and orientation (instead of distances_mm x "
                                        "orientations_deg with one tilt_deg)")

    @model_validator(mode="after")
    def _placements_measurable(self) -> SphereBar:
        if self.placements is None:
            return self
        if self.model_fields_set & {"distances_mm", "orientations_deg", "tilt_deg"}:
            given = sorted(self.model_fields_set & {"distances_mm", "orientations_deg", "tilt_deg"})
            raise ValueError(f"placements gives every placement's distance, orientation and tilt: leave out "
                             f"{', '.join(given)}")
        for n, placement in enumerate(self.placements):
            problem = placement.problem(self.sphere_spacing_mm, self.sphere_diameter_mm, self.gap_mm)
            if problem is not None:
                raise ValueError(f"placements[{n}] (distance_mm = {placement.distance_mm:g}, tilt_deg = "
                                 f"{placement.tilt_deg:g}): {problem}")
        return self

    def stage_distances_mm(self) -> list[float]:
        """The stage sets the camera-wall distance: each placement's (or each ``distances_mm``) plus the gap."""
        if self.placements is None:
            return super().stage_distances_mm()
        return [p.distance_mm + self.gap_mm for p in self.placements]

    def _bar(self, orientation_deg: float, tilt_deg: float) -> dict[str, object]:
        """A step's target parameters: the bar, its orientation and tilt, its rim rule, calibration and MPEs."""
        return {"diameter_mm": self.sphere_diameter_mm, "spacing_mm": self.sphere_spacing_mm,
                "orientation_deg": orientation_deg, "tilt_deg": tilt_deg, "max_incidence_deg": self.max_incidence_deg,
                "rim_margin_px": self.rim_margin_px,
                "diameter_uncertainty_mm": self.sphere_diameter_uncertainty_mm,
                "spacing_uncertainty_mm": self.sphere_spacing_uncertainty_mm,
                "form_uncertainty_mm": self.sphere_form_uncertainty_mm,
                "calibration_coverage_factor": self.calibration_coverage_factor, "mpe_form_mm": self.mpe_form_mm,
                "mpe_size_mm": self.mpe_size_mm, "mpe_spacing_mm": self.mpe_spacing_mm}

    def steps(self, first_index: int) -> Iterator[Step]:
        """One step per placement: ``placements`` when given (the middle's ``offset_mm`` recorded in the camera
        frame, x right, y down, as the simulator's scene takes it), else every distance x orientation with the
        one ``tilt_deg``, centred on the camera axis (VDI/VDE 2634-2, sphere-spacing error)."""
        if self.placements is not None:
            for n, p in enumerate(self.placements):
                yield self._step(
                    first_index + n, p.distance_mm, "ball_bar",
                    {**self._bar(p.orientation_deg, p.tilt_deg), "offset_mm": [p.offset_mm[0], 0.0 - p.offset_mm[1]]},
                    p.prompt(self.sphere_diameter_mm, self.sphere_spacing_mm, self.gap_mm))
            return
        poses = [(d, o) for d in self.distances_mm for o in self.orientations_deg]
        for n, (distance, orientation) in enumerate(poses):
            yield self._step(
                first_index + n, distance, "ball_bar",
                self._bar(orientation, self.tilt_deg),
                f"place the ball bar ({self.sphere_diameter_mm:g} mm spheres, {self.sphere_spacing_mm:g} mm apart) "
                f"{self.gap_mm:g} mm in front of the wall, centred on the camera axis, at {orientation:g} deg from "
                f"horizontal, tilted {self.tilt_deg:g} deg towards the wall",
            )


class Flatness(_Artefact):
    """Campaign entry ``kind = "flatness"``."""

    kind: Literal["flatness"]
    plate_mm: tuple[float, float] = Field((500.0, 400.0), description="width, height of the flat plate")
    distances_mm: list[float] = Field([1000.0, 2000.0], min_length=1, description="camera to plate")
    tilts_deg: list[float] = Field([0.0, 30.0], min_length=1, description="about the vertical axis")
    mpe_flatness_mm: float | None = Field(None, gt=0, description="maximum permissible flatness error")
    flatness_uncertainty_mm: float | None = Field(
        None, ge=0, le=10.0, description="calibration certificate's uncertainty of the plate's flatness deviation")

    def steps(self, first_index: int) -> Iterator[Step]:
        poses = [(d, t) for d in self.distances_mm for t in self.tilts_deg]
        for n, (distance, tilt) in enumerate(poses):
            yield self._step(
                first_index + n, distance, "flat_plate",
                {"plate_mm": list(self.plate_mm), "tilt_deg": tilt, "mpe_flatness_mm": self.mpe_flatness_mm,
                 "flatness_uncertainty_mm": self.flatness_uncertainty_mm,
                 "calibration_coverage_factor": self.calibration_coverage_factor},
                f"place the {self.plate_mm[0]:g} x {self.plate_mm[1]:g} mm flat plate {self.gap_mm:g} mm in front "
                f"of the wall, centred on the camera axis, turned {tilt:g} deg about the vertical",
            )
