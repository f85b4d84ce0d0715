"""Camera alignment to the wall (thesis 4.1.2, SPEC "Lab and hardware").

Ten frames are averaged; four fields of 10 x 10 px near the image corners are
averaged; the camera is tilted until opposite fields agree. labctl reports the
four field depths and the tilt they imply: about the y axis (yaw) from the
left/right depth difference over the fields' lateral separation, about the x
axis (pitch) from the top/bottom difference, using the fields' mean x, y, z
from the point cloud (so the FOV does not enter). A positive tilt means the
camera is turned towards that side (up, right): that side of the wall is farther.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

CORNERS = ("top_left", "top_right", "bottom_left", "bottom_right")


@dataclass(frozen=True)
class AlignmentFields:
    """Mean x, y, z (mm) of each corner field and the implied tilt (deg)."""

    fields: dict[str, tuple[float, float, float]]
    tilt_x_deg: float  # pitch: positive when the camera looks up (the top of the wall is farther)
    tilt_y_deg: float  # yaw: positive when the camera looks right (the right side is farther)

    def depths(self) -> dict[str, float]:
        return {name: xyz[2] for name, xyz in self.fields.items()}


def field_slices(height: int, width: int, field_px: int = 10, margin_px: int | None = None) -> dict[str, tuple[slice, slice]]:
    """The four corner fields, ``margin_px`` (default: one field size) in from the image border."""
    m = field_px if margin_px is None else margin_px
    if 2 * (m + field_px) > min(height, width):
        raise ValueError(f"fields of {field_px} px with {m} px margin do not fit a {width} x {height} image")
    rows = {"top": slice(m, m + field_px), "bottom": slice(height - m - field_px, height - m)}
    cols = {"left": slice(m, m + field_px), "right": slice(width - m - field_px, width - m)}
    return {f"{r}_{c}": (rows[r], cols[c]) for r in ("top", "bottom") for c in ("left", "right")}


def alignment_fields(x: np.ndarray, y: np.ndarray, z: np.ndarray, field_px: int = 10,
                     margin_px: int | None = None) -> AlignmentFields:
    """Corner-field means of a (stack-mean) cloud and the tilt they imply."""
    means: dict[str, tuple[float, float, float]] = {}
    for name, (rows, cols) in field_slices(*z.shape, field_px, margin_px).items():
        part = [a[rows, cols] for a in (x, y, z)]
        ok = np.isfinite(part[0]) & np.isfinite(part[1]) & np.isfinite(part[2])
        if not ok.any():
            raise ValueError(f"the {name.replace('_', ' ')} alignment field has no valid pixel")
        means[name] = tuple(float(a[ok].mean()) for a in part)  # type: ignore[assignment]

    def pair(a: str, b: str, axis: int) -> tuple[float, float]:
        return means[b][2] - means[a][2], means[b][axis] - means[a][axis]

    dz_lr, dx_lr = np.mean([pair("top_left", "top_right", 0), pair("bottom_left", "bottom_right", 0)], axis=0)
    dz_tb, dy_tb = np.mean([pair("top_left", "bottom_left", 1), pair("top_right", "bottom_right", 1)], axis=0)
    return AlignmentFields(
        fields=means,
        tilt_x_deg=math.degrees(math.atan2(-dz_tb, dy_tb)),
        tilt_y_deg=math.degrees(math.atan2(dz_lr, dx_lr)),
    )
