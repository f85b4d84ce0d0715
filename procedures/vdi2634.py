"""VDI/VDE 2634 Part 2 acceptance test on the stage: a ball bar and a flat plate in front of the wall.

* ``sphere_bar``: a ball bar with two spheres of calibrated ``sphere_diameter_mm``
  whose centres are a calibrated ``sphere_spacing_mm`` apart, placed by the
  operator (one prompt per placement) ``gap_mm`` in front of the wall at each of
  ``distances_mm`` (camera to bar) and each of ``orientations_deg`` (the bar's
  direction in the image plane: 0 horizontal, 90 vertical, 45 / 135 the
  diagonals), each with ``tilt_deg`` out of the image plane, so that the
  positions span the measuring volume's width, height and depth as the
  guideline asks; each sphere is fitted with the rim rule of
  ``metrics.vdi2634`` (``max_incidence_deg``, ``rim_margin_px``);
* ``flatness``: a flat plate of ``plate_mm`` placed ``gap_mm`` in front of the
  wall at each distance, tilted about the vertical axis by each of ``tilts_deg``.

A measurement is the mean of ``frames_per_measurement`` frames (default: all
of the step's ``frames``, one measurement per placement), so each placement
gives ``frames // frames_per_measurement`` measurements. The maximum
permissible errors (``mpe_*_mm``, optional) and the ball bar's calibration
uncertainties (``sphere_*_uncertainty_mm``, optional, stated with
``calibration_coverage_factor`` as the certificate states them) travel with
the steps' target parameters; the evaluation gives pass / fail / marginal per
quantity.
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import ClassVar, Literal

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
    calibration_coverage_factor: float = Field(
        2.0, ge=1.0, le=10.0, description="k the certificate states its uncertainties with (1: standard)")
    mpe_form_mm: float | None = Field(None, gt=0, description="maximum permissible probing error form")
    mpe_size_mm: float | None = Field(None, gt=0, description="maximum permissible |probing error size|")
    mpe_spacing_mm: float | None = Field(None, gt=0, description="maximum permissible |sphere-spacing error|")

    def steps(self, first_index: int) -> Iterator[Step]:
        poses = [(d, o) for d in self.distances_mm for o in self.orientations_deg]
        for n, (distance, orientation) in enumerate(poses):
            yield self._step(
                first_index + n, distance, "ball_bar",
                {"diameter_mm": self.sphere_diameter_mm, "spacing_mm": self.sphere_spacing_mm,
                 "orientation_deg": orientation, "tilt_deg": self.tilt_deg, "max_incidence_deg": self.max_incidence_deg,
                 "rim_margin_px": self.rim_margin_px, "diameter_uncertainty_mm": self.sphere_diameter_uncertainty_mm,
                 "spacing_uncertainty_mm": self.sphere_spacing_uncertainty_mm,
                 "calibration_coverage_factor": self.calibration_coverage_factor, "mpe_form_mm": self.mpe_form_mm,
                 "mpe_size_mm": self.mpe_size_mm, "mpe_spacing_mm": self.mpe_spacing_mm},
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

    def steps(self, first_index: int) -> Iterator[Step]:
        poses = [(d, t) for d in self.distances_mm for t in self.tilts_deg]
        for n, (distance, tilt) in enumerate(poses):
            yield self._step(
                first_index + n, distance, "flat_plate",
                {"plate_mm": list(self.plate_mm), "tilt_deg": tilt, "mpe_flatness_mm": self.mpe_flatness_mm},
                f"place the {self.plate_mm[0]:g} x {self.plate_mm[1]:g} mm flat plate {self.gap_mm:g} mm in front "
                f"of the wall, centred on the camera axis, turned {tilt:g} deg about the vertical",
            )
