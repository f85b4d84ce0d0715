"""Textures (reflectance over a plane) and shapes (where a plane exists), as data.

Each is a small frozen dataclass: callable on numpy arrays of in-plane
coordinates (u, v) in mm, and describable as a numeric code plus up to four
parameters so that the compiled ray caster (sim/scenes/cast.py) evaluates
exactly the same function.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Uniform:
    """Constant reflectance."""

    value: float
    code = 0

    def __call__(self, u: np.ndarray, v: np.ndarray) -> np.ndarray:
        return np.full(np.shape(u), self.value)

    def params(self) -> tuple[float, ...]:
        return (self.value, 0.0, 0.0, 0.0)


@dataclass(frozen=True)
class Checker:
    """Checkerboard of ``tile_mm`` tiles, a tile corner at (0, 0), ``white`` in the tile at +u, +v."""

    tile_mm: float
    white: float
    black: float
    code = 1

    def __call__(self, u: np.ndarray, v: np.ndarray) -> np.ndarray:
        parity = (np.floor(u / self.tile_mm) + np.floor(v / self.tile_mm)) % 2
        return np.where(parity == 0, self.white, self.black)

    def params(self) -> tuple[float, ...]:
        return (self.tile_mm, self.white, self.black, 0.0)


@dataclass(frozen=True)
class SlantedQuadrant:
    """Slanted-edge chart: ``black`` where the coordinates turned by ``angle_deg`` are both positive."""

    angle_deg: float
    white: float
    black: float
    code = 2

    def __call__(self, u: np.ndarray, v: np.ndarray) -> np.ndarray:
        a = math.radians(self.angle_deg)
        ur, vr = math.cos(a) * u + math.sin(a) * v, -math.sin(a) * u + math.cos(a) * v
        return np.where((ur > 0) & (vr > 0), self.black, self.white)

    def params(self) -> tuple[float, ...]:
        return (math.radians(self.angle_deg), self.white, self.black, 0.0)


@dataclass(frozen=True)
class Rect:
    """A centred rectangle of ``width`` x ``height`` mm."""

    width: float
    height: float
    code = 1

    def __call__(self, u: np.ndarray, v: np.ndarray) -> np.ndarray:
        return (np.abs(u) <= self.width / 2) & (np.abs(v) <= self.height / 2)

    def params(self) -> tuple[float, ...]:
        return (self.width / 2, self.height / 2, 0.0, 0.0)


@dataclass(frozen=True)
class Star:
    """A Boehler star: N wedges of which the even ones are filled, a central disc, ``diameter`` overall."""

    segments: int
    diameter_mm: float
    disc_mm: float
    rotation_deg: float
    code = 2

    def __call__(self, u: np.ndarray, v: np.ndarray) -> np.ndarray:
        r = np.hypot(u, v)
        phi = np.mod(np.arctan2(v, u) - math.radians(self.rotation_deg), 2 * math.pi)
        filled = np.floor(phi * self.segments / (2 * math.pi)).astype(np.int64) % 2 == 0
        return (r <= self.diameter_mm / 2) & (filled | (r <= self.disc_mm / 2))

    def params(self) -> tuple[float, ...]:
        return (float(self.segments), self.diameter_mm / 2, self.disc_mm / 2, math.radians(self.rotation_deg))


Texture = Uniform | Checker | SlantedQuadrant
Shape = Rect | Star
