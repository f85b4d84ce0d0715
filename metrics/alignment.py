"""Camera alignment to the wall (Thesis 2024, 4.1.2).

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
        """Mean z (mm) of each corner field.

        Examples
        --------
        >>> fields = {name: (0.0, 0.0, 1000.0 + k) for k, name in enumerate(CORNERS)}
        >>> AlignmentFields(fields, tilt_x_deg=0.0, tilt_y_deg=0.0).depths()
        {'top_left': 1000.0, 'top_right': 1001.0, 'bottom_left': 1002.0, 'bottom_right': 1003.0}
        """
        return {name: xyz[2] for name, xyz in self.fields.items()}


def field_slices(height: int, width: int, field_px: int = 10, margin_px: int | None = None) -> dict[str, tuple[slice, slice]]:
    """The four corner fields, ``margin_px`` in from the image border.

    By default the margin is 10 % of the image side (at least one field size):
    clear of the dark corners of a ToF image and of an active-stereo camera's
    invalid band along the left border (the D455's is f B / z, about 20 px at
    2 m on 640 px).

    Examples
    --------
    A 200 x 100 image: margins of 10 % (10 rows, 20 columns), fields of 10 x 10 px.

    >>> fields = field_slices(100, 200)
    >>> fields["top_left"]
    (slice(10, 20, None), slice(20, 30, None))
    >>> fields["bottom_right"]
    (slice(80, 90, None), slice(170, 180, None))
    """
    mr, mc = ((max(field_px, round(0.1 * height)), max(field_px, round(0.1 * width))) if margin_px is None
              else (margin_px, margin_px))
    if 2 * (mr + field_px) > height or 2 * (mc + field_px) > width:
        raise ValueError(f"fields of {field_px} px with {mr} / {mc} px margins do not fit a {width} x {height} image")
    rows = {"top": slice(mr, mr + field_px), "bottom": slice(height - mr - field_px, height - mr)}
    cols = {"left": slice(mc, mc + field_px), "right": slice(width - mc - field_px, width - mc)}
    return {f"{r}_{c}": (rows[r], cols[c]) for r in ("top", "bottom") for c in ("left", "right")}


def alignment_fields(x: np.ndarray, y: np.ndarray, z: np.ndarray, field_px: int = 10,
                     margin_px: int | None = None) -> AlignmentFields:
    """Corner-field means of a (stack-mean) cloud and the tilt they imply.

    Examples
    --------
    A wall whose depth grows by 0.1 mm per mm to the right and 0.2 mm per mm upwards (y grows
    downwards): tilts of atan(0.1) = 5.711 deg (yaw) and atan(0.2) = 11.310 deg (pitch).

    >>> y, x = np.mgrid[-50:50, -100:100].astype(float)
    >>> fields = alignment_fields(x, y, 1000.0 + 0.1 * x - 0.2 * y)
    >>> round(fields.tilt_y_deg, 3), round(fields.tilt_x_deg, 3)
    (5.711, 11.31)
    """
    means: dict[str, tuple[float, float, float]] = {}
    for name, (rows, cols) in field_slices(*z.shape, field_px, margin_px).items():
        part = [a[rows, cols] for a in (x, y, z)]
        ok = np.isfinite(part[0]) & np.isfinite(part[1]) & np.isfinite(part[2])
        if not ok.any():
            raise ValueError(f"the {name.replace('_', ' ')} alignment field (rows {rows.start}-{rows.stop - 1}, "
                             f"columns {cols.start}-{cols.stop - 1}) has no valid pixel")
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
