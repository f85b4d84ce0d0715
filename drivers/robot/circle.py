"""The measurement circle: camera poses on a circle around a target, looking at it.

The circle is defined in the robot's base frame by its centre (the target point),
its rotation axis, and the camera's pose at 0° (the TCP pose taught on the teach
pendant: x, y, z in mm and the orientation as a rotation vector in rad, UR's
``p[x, y, z, rx, ry, rz]`` convention of the UR Script Manual, "Pose"). The pose at
angle θ and radius R is the 0° pose rotated by θ about the axis through the centre
(right-hand rule), moved along the line to the centre until it is R away. The TCP's
z axis is the camera's optical axis, so the camera keeps looking at the centre.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation


def _unit(vector: np.ndarray, what: str) -> np.ndarray:
    norm = float(np.linalg.norm(vector))
    if not math.isfinite(norm) or norm < 1e-9:
        raise ValueError(f"{what} must be a non-zero vector, got {vector.tolist()}")
    return vector / norm


@dataclass(frozen=True)
class CirclePosition:
    """Where a TCP pose lies relative to the circle."""

    angle_deg: float
    radius_mm: float
    off_plane_mm: float
    """distance of the TCP from the circle's plane"""
    aim_error_deg: float
    """angle between the TCP orientation and the circle pose's orientation there"""


class MeasurementCircle:
    """Camera poses on the measurement circle (see the module docstring).

    ``tolerance_mm`` / ``aim_tolerance_deg`` bound how far the 0° pose may lie off the
    circle's plane and how far its optical axis may miss the centre.
    """

    def __init__(
        self,
        center_mm: Sequence[float],
        axis: Sequence[float],
        zero_pose: Sequence[float],
        *,
        tolerance_mm: float = 1.0,
        aim_tolerance_deg: float = 1.0,
    ) -> None:
        if len(center_mm) != 3 or len(axis) != 3 or len(zero_pose) != 6:
            raise ValueError("the circle needs a centre [x, y, z], an axis [x, y, z] and a 0° pose [x, y, z, rx, ry, rz]")
        self.center = np.asarray(center_mm, float)
        self.axis = _unit(np.asarray(axis, float), "the rotation axis")
        self.zero_position = np.asarray(zero_pose[:3], float)
        self.zero_rotation = Rotation.from_rotvec(np.asarray(zero_pose[3:], float))
        offset = self.zero_position - self.center
        off_plane = float(offset @ self.axis)
        if abs(off_plane) > tolerance_mm:
            raise ValueError(
                f"the 0° pose lies {off_plane:.1f} mm off the circle's plane (tolerance {tolerance_mm:g} mm): "
                "the camera must be at the height of the centre along the rotation axis"
            )
        radial = offset - off_plane * self.axis
        self.zero_radius_mm = float(np.linalg.norm(radial))
        if self.zero_radius_mm < tolerance_mm:
            raise ValueError("the 0° pose coincides with the circle's centre; the camera must be on the circle")
        self.u0 = radial / self.zero_radius_mm
        optical_axis = self.zero_rotation.apply([0.0, 0.0, 1.0])
        miss = math.degrees(math.acos(float(np.clip(optical_axis @ -self.u0, -1.0, 1.0))))
        if miss > aim_tolerance_deg:
            raise ValueError(
                f"at the 0° pose the camera's optical axis (TCP z) misses the centre by {miss:.1f}° "
                f"(tolerance {aim_tolerance_deg:g}°): teach a pose that looks at the target"
            )

    def _turn(self, angle_deg: float) -> Rotation:
        return Rotation.from_rotvec(math.radians(angle_deg) * self.axis)

    def pose(self, angle_deg: float, radius_mm: float) -> np.ndarray:
        """TCP pose ``[x, y, z (mm), rx, ry, rz (rad)]`` at ``angle_deg`` on the circle of ``radius_mm``."""
        turn = self._turn(angle_deg)
        position = self.center + radius_mm * turn.apply(self.u0)
        rotation = turn * self.zero_rotation
        return np.concatenate([position, rotation.as_rotvec()])

    def locate(self, pose: Sequence[float]) -> CirclePosition:
        """Angle and radius of a TCP pose (mm, rad), its distance from the circle's plane and
        how far its orientation is from the circle pose's there."""
        position = np.asarray(pose[:3], float)
        offset = position - self.center
        off_plane = float(offset @ self.axis)
        radial = offset - off_plane * self.axis
        radius = float(np.linalg.norm(radial))
        angle = math.degrees(math.atan2(float(self.axis @ np.cross(self.u0, radial)), float(self.u0 @ radial)))
        ideal = Rotation.from_rotvec(self.pose(angle, radius)[3:])
        difference = Rotation.from_rotvec(np.asarray(pose[3:], float)) * ideal.inv()
        return CirclePosition(angle, radius, abs(off_plane), math.degrees(difference.magnitude()))

    def arc(self, from_deg: float, to_deg: float, radius_mm: float, step_deg: float) -> list[np.ndarray]:
        """Poses from (excluding) ``from_deg`` to (including) ``to_deg``, at most ``step_deg`` apart."""
        if step_deg <= 0:
            raise ValueError(f"step_deg must be positive, got {step_deg}")
        count = max(1, math.ceil(abs(to_deg - from_deg) / step_deg - 1e-9))
        return [self.pose(from_deg + (to_deg - from_deg) * k / count, radius_mm) for k in range(1, count + 1)]
