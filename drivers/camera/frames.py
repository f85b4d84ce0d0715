"""Helpers shared by the camera backends: SDK import, invalid points, pinhole geometry.

Every backend delivers :class:`~drivers.protocols.Frame` arrays in the run file's
convention (docs/runfile.md): x, y, z float32 in mm in the camera frame (z along the
optical axis), NaN where the camera has no valid point, intensity float32.
"""

from __future__ import annotations

import importlib
import math
from types import ModuleType

import numpy as np

from drivers.errors import MissingSDKError


def import_sdk(module: str, device: str, install: str) -> ModuleType:
    """Import an SDK module on first use; MissingSDKError saying exactly what to install."""
    try:
        return importlib.import_module(module)
    except ImportError as exc:
        raise MissingSDKError(device, f"the Python module '{module}' is missing ({exc}); {install}") from exc


def invalidate(x: np.ndarray, y: np.ndarray, z: np.ndarray, invalid: np.ndarray | None = None) -> tuple[np.ndarray, ...]:
    """x, y, z as float32 with NaN where ``invalid`` is set or z is not a positive finite distance
    (a point in front of a camera has z > 0; SDKs mark missing points with 0 or NaN)."""
    x, y, z = (np.asarray(a, dtype=np.float32).copy() for a in (x, y, z))
    with np.errstate(invalid="ignore"):
        bad = ~(z > 0)
    if invalid is not None:
        bad |= invalid
    for array in (x, y, z):
        array[bad] = np.nan
    return x, y, z


def backproject(
    z: np.ndarray, focal_px: tuple[float, float], principal_px: tuple[float, float]
) -> tuple[np.ndarray, np.ndarray]:
    """x, y (mm) of pixels with depth ``z`` (mm) through a pinhole: x = (u - cx) z / fx, y = (v - cy) z / fy,
    with (u, v) the column and row index of the pixel."""
    height, width = z.shape
    u = np.arange(width, dtype=np.float32)[None, :]
    v = np.arange(height, dtype=np.float32)[:, None]
    x = (u - np.float32(principal_px[0])) / np.float32(focal_px[0]) * z
    y = (v - np.float32(principal_px[1])) / np.float32(focal_px[1]) * z
    return x.astype(np.float32), y.astype(np.float32)


def pinhole_fov_deg(width: int, height: int, focal_px: tuple[float, float]) -> tuple[float, float]:
    """Horizontal and vertical field of view (degrees) of a pinhole with focal lengths in pixels."""
    return (
        math.degrees(2.0 * math.atan(width / (2.0 * focal_px[0]))),
        math.degrees(2.0 * math.atan(height / (2.0 * focal_px[1]))),
    )
