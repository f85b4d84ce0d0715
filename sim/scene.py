"""Scenes rendered analytically by ray-plane intersection, in the camera frame.

A scene returns, per pixel, the range along the pixel's ray to the first
surface, the cosine of the incidence angle and the surface's NIR reflectance.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

#: NIR reflectance of the lab's white wall (thesis 4.1.1: 90 % at 850/940 nm)
WALL_REFLECTANCE = 0.90


@dataclass(frozen=True)
class Pose:
    """Where the camera is relative to the target.

    ``distance_mm`` is the perpendicular distance from the camera's optical
    centre to the target plane; ``tilt_x_deg``/``tilt_y_deg`` rotate the camera
    about its own x (pitch) and y (yaw) axes.
    """

    distance_mm: float
    tilt_x_deg: float = 0.0
    tilt_y_deg: float = 0.0

    def target_normal(self) -> np.ndarray:
        """Unit normal of the target plane (pointing away from the camera), camera frame."""
        ax, ay = math.radians(self.tilt_x_deg), math.radians(self.tilt_y_deg)
        rx = np.array([[1, 0, 0], [0, math.cos(ax), -math.sin(ax)], [0, math.sin(ax), math.cos(ax)]])
        ry = np.array([[math.cos(ay), 0, math.sin(ay)], [0, 1, 0], [-math.sin(ay), 0, math.cos(ay)]])
        return (ry @ rx).T @ np.array([0.0, 0.0, 1.0])


@dataclass(frozen=True)
class SceneHit:
    range_mm: np.ndarray
    cos_incidence: np.ndarray
    reflectance: np.ndarray


def render_wall(rays: np.ndarray, pose: Pose, reflectance: float = WALL_REFLECTANCE) -> SceneHit:
    """Flat wall filling the view: range = D / (n . d) for unit ray d and wall normal n."""
    n = pose.target_normal()
    cos_inc = np.tensordot(n, rays, axes=1)
    if np.any(cos_inc <= 0):
        raise ValueError("the wall is not in front of every pixel (tilt too large)")
    return SceneHit(
        range_mm=pose.distance_mm / cos_inc,
        cos_incidence=cos_inc,
        reflectance=np.full(cos_inc.shape, reflectance),
    )


SCENES = {"wall": render_wall}


def render(target: str, rays: np.ndarray, pose: Pose) -> SceneHit:
    """Render the named target; KeyError lists the targets this simulator knows."""
    try:
        scene = SCENES[target]
    except KeyError:
        raise KeyError(f"no simulated scene for target {target!r}; known: {', '.join(SCENES)}") from None
    return scene(rays, pose)
