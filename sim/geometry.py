"""Rigid geometry of the simulated lab: camera poses and rays.

Frames. The camera frame has x to the right, y down, z along the optical axis
(image convention). A :class:`Pose` maps camera coordinates to the world:
X_world = R X_cam + position.

* Stage lab: the camera sits at the world origin looking along +z; the wall
  is the plane z = D (the camera-wall distance).
* Robot lab (Thesis 2024, 5.4, Fig. 5-15): the circle centre is the world origin,
  the robot turns the camera about the vertical (y) axis; at angle theta the
  camera sits at (R sin theta, 0, -R cos theta) looking at the centre. A
  camera whose optical axis misses the robot axis by e sits e further along
  its own x axis. The target plane faces the 0 deg camera.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np


def rotation_x(deg: float) -> np.ndarray:
    a = math.radians(deg)
    return np.array([[1.0, 0.0, 0.0], [0.0, math.cos(a), -math.sin(a)], [0.0, math.sin(a), math.cos(a)]])


def rotation_y(deg: float) -> np.ndarray:
    a = math.radians(deg)
    return np.array([[math.cos(a), 0.0, math.sin(a)], [0.0, 1.0, 0.0], [-math.sin(a), 0.0, math.cos(a)]])


def rotation_z(deg: float) -> np.ndarray:
    a = math.radians(deg)
    return np.array([[math.cos(a), -math.sin(a), 0.0], [math.sin(a), math.cos(a), 0.0], [0.0, 0.0, 1.0]])


@dataclass(frozen=True)
class Pose:
    """Camera-to-world transform."""

    rotation: np.ndarray
    position: np.ndarray

    @staticmethod
    def at_origin(tilt_x_deg: float = 0.0, tilt_y_deg: float = 0.0) -> Pose:
        """Stage-lab camera at the origin, pitched by ``tilt_x`` and yawed by ``tilt_y``."""
        return Pose(rotation_y(tilt_y_deg) @ rotation_x(tilt_x_deg), np.zeros(3))

    @staticmethod
    def on_circle(angle_deg: float, radius_mm: float, axis_offset_mm: float = 0.0) -> Pose:
        """Robot-lab camera at ``angle_deg`` on the circle, looking at the centre (Fig. 5-15)."""
        rotation = rotation_y(-angle_deg)
        position = rotation @ np.array([axis_offset_mm, 0.0, -radius_mm])
        return Pose(rotation, position)

    def key(self) -> tuple[float, ...]:
        """Hashable identity (for caches)."""
        return tuple(np.round(np.concatenate([self.rotation.ravel(), self.position]), 9))

    @cached_property
    def _upright(self) -> bool:
        """The camera frame is the world's (to numpy's closeness): its rays need no rotation."""
        return bool(np.allclose(self.rotation, np.eye(3)))

    def rays(self, directions_cam: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The camera centre (world) and the world directions of unit camera-frame directions."""
        if self._upright:
            return self.position, directions_cam
        r = self.rotation
        d = directions_cam
        return self.position, np.stack([r[i, 0] * d[0] + r[i, 1] * d[1] + r[i, 2] * d[2] for i in range(3)])

    def to_camera(self, points_world: np.ndarray) -> np.ndarray:
        """World points (3, ...) in camera coordinates."""
        p = points_world - self.position.reshape((3,) + (1,) * (points_world.ndim - 1))
        return np.tensordot(self.rotation.T, p, axes=1)
