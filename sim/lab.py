"""The simulated lab's ground truth: mounting offsets and the laser's errors.

These are what a real lab never knows exactly and calibrates away: the camera
sits ``camera_mount_error_mm`` farther from the wall than the stage's nominal
distance; the laser's zero lies ``laser_offset_mm`` behind the camera's optical
centre; the laser has a constant bias within its +-1 mm accuracy and a
repeatability of 0.3 mm (Dimetix DAN-10-150, taken as 2 sigma). They can be
changed in a model file's ``[lab]`` table and are recorded only under ``/sim``.
"""

from __future__ import annotations

from pydantic import Field

from drivers.laser.dimetix import ACCURACY_MM, REPEATABILITY_2SIGMA_MM
from procedures.steps import StrictModel


class LabGeometry(StrictModel):
    """Each value within what a lab can have without noticing (a camera a metre off its mount, or a laser
    reading with metres of noise, is no hidden error but another lab)."""

    camera_mount_error_mm: float = Field(6.0, ge=-200.0, le=200.0)
    laser_offset_mm: float = Field(42.0, ge=-1000.0, le=1000.0)
    laser_bias_mm: float = Field(0.4, ge=-ACCURACY_MM, le=ACCURACY_MM)
    laser_noise_mm: float = Field(REPEATABILITY_2SIGMA_MM / 2, ge=0.0, le=10.0)
    laser_resolution_mm: float = Field(0.1, gt=0.0, le=10.0)
    tilt_x_deg: float = Field(0.0, ge=-10, le=10)
    tilt_y_deg: float = Field(0.0, ge=-10, le=10)
