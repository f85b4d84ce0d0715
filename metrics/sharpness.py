"""Sharpness over distance and imagery resolution (Thesis 2024, 5.1, 6.2-6.3, 6.6, 5.1.2, §9).

* hyperfocal distance: the nearest distance from which the SFR area stays at
  or above 90 % of its plateau, the plateau being the median over the far half
  of the sweep (Thesis 2024, 5.1.2);
* best focus: the nearest distance whose SFR area, after a 3-point moving
  median, is within 5 % of the highest (Thesis 2024, 5.2.1: of several distances of
  high focus the smallest is chosen); the same distance is the key figure and
  where sharp targets are placed;
* imagery resolution (Thesis 2024, 6.3.1): angular = sensor angular resolution /
  SFR10 (eq. 5-1), lateral = the size that angle covers at the distance (eq. 5-2);
* inter-eye distance coverage at the image centre (pinhole): px = IED f / d
  with f = (W / 2) / tan(FOV / 2); Thesis 2024, eq. 6-2's px = IED / (tan(res) d)
  with the mean angular pixel size res = FOV / W over-counts there.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

PLATEAU_FRACTION = 0.9
#: SFR areas within this fraction of the highest count as equally sharp (best focus)
BEST_FOCUS_TOLERANCE = 0.05
IED_MM = 62.5  # average adult inter-eye distance (Yildirim et al. 2015, Thesis 2024, 6.6)


def _sorted_valid(distances: Sequence[float], values: Sequence[float], valid: Sequence[bool]) -> tuple[np.ndarray, np.ndarray]:
    d, v, ok = np.asarray(distances, float), np.asarray(values, float), np.asarray(valid, bool)
    keep = ok & np.isfinite(v) & np.isfinite(d)
    order = np.argsort(d[keep])
    return d[keep][order], v[keep][order]


def plateau(distances: Sequence[float], sfr_area: Sequence[float], valid: Sequence[bool]) -> float:
    """Median SFR area over the far half of the valid positions (Thesis 2024, 5.1.2).

    Examples
    --------
    The far half of six positions (1000, 1200, 1400 mm) has the median of 0.9, 1.0, 0.95.

    >>> plateau([400, 600, 800, 1000, 1200, 1400], [0.2, 0.5, 0.8, 0.9, 1.0, 0.95], [True] * 6)
    0.95
    """
    d, v = _sorted_valid(distances, sfr_area, valid)
    if not d.size:
        return math.nan
    return float(np.median(v[d.size // 2 :]))


def hyperfocal_distance(distances: Sequence[float], sfr_area: Sequence[float], valid: Sequence[bool],
                        fraction: float = PLATEAU_FRACTION) -> float:
    """Nearest distance from which every valid SFR area stays >= ``fraction`` x plateau (Thesis 2024, 5.1.2).

    Examples
    --------
    Plateau 0.95, level 0.9 x 0.95 = 0.855: every area from 1000 mm on is at or above it, 0.8 at 800 mm is not.

    >>> hyperfocal_distance([400, 600, 800, 1000, 1200, 1400], [0.2, 0.5, 0.8, 0.9, 1.0, 0.95], [True] * 6)
    1000.0
    """
    d, v = _sorted_valid(distances, sfr_area, valid)
    if not d.size:
        return math.nan
    level = fraction * float(np.median(v[d.size // 2 :]))
    nearest = math.nan
    for distance, value in zip(d[::-1], v[::-1]):
        if value < level:
            break
        nearest = float(distance)
    return nearest


def position_spacing(distances: Sequence[float], sfr_area: Sequence[float], valid: Sequence[bool],
                     position_mm: float) -> float:
    """The sweep's resolution at a position it reports (the hyperfocal distance, best focus): the spacing
    between that position and the next nearer valid one; NaN where it is the nearest valid position (the
    condition may start to hold anywhere nearer: the figure is a bound) or there is no position. Both figures
    are the nearest position at which a condition holds, so where it starts to hold lies somewhere within one
    spacing of the reported position: the spacing is the figure's resolution, as the step of an indicating
    device (GUM F.2.2.1).

    Examples
    --------
    >>> d, area = [400, 600, 800, 1000, 1200, 1400], [0.2, 0.5, 0.8, 0.9, 1.0, 0.95]
    >>> position_spacing(d, area, [True] * 6, 1000.0), position_spacing(d, area, [True] * 6, 400.0)
    (200.0, nan)
    >>> position_spacing(d, area, [True, True, False, True, True, True], 1000.0)
    400.0
    """
    d, _ = _sorted_valid(distances, sfr_area, valid)
    if not math.isfinite(position_mm):
        return math.nan
    k = int(np.argmin(np.abs(d - position_mm)))
    return float(d[k] - d[k - 1]) if k > 0 else math.nan


def _smoothed(distances: Sequence[float], sfr_area: Sequence[float], valid: Sequence[bool]) -> tuple[np.ndarray, np.ndarray]:
    """Valid positions by distance and their SFR area after a 3-point moving median (ends repeated)."""
    d, v = _sorted_valid(distances, sfr_area, valid)
    padded = np.concatenate([v[:1], v, v[-1:]])
    return d, np.median(np.stack([padded[:-2], padded[1:-1], padded[2:]]), axis=0) if d.size else v


def best_focus_distance(distances: Sequence[float], sfr_area: Sequence[float], valid: Sequence[bool],
                        tolerance: float = BEST_FOCUS_TOLERANCE) -> float:
    """Best focus: the nearest distance whose 3-point-median SFR area is within ``tolerance`` of the highest.

    One definition for the key figure and for where sharp targets go: "if there
    are multiple distances with high focus, the smallest distance is chosen"
    (Thesis 2024, 5.2.1), which keeps checkerboard tiles and star segments large.

    Examples
    --------
    The 3-point medians are 0.2, 0.5, 0.8, 0.9, 0.95, 0.95; within 5 % of 0.95 (>= 0.9025) first at 1200 mm.

    >>> best_focus_distance([400, 600, 800, 1000, 1200, 1400], [0.2, 0.5, 0.8, 0.9, 1.0, 0.95], [True] * 6)
    1200.0
    """
    d, smoothed = _smoothed(distances, sfr_area, valid)
    if not d.size:
        return math.nan
    return float(d[np.argmax(smoothed >= (1.0 - tolerance) * smoothed.max())])


def sharpness_peak_at_sweep_end(distances: Sequence[float], sfr_area: Sequence[float],
                                valid: Sequence[bool]) -> str | None:
    """``"far"`` or ``"near"`` when the smoothed SFR area peaks at that end of the valid positions, else None.

    A peak at an end of the sweep means the true maximum may lie beyond it: the
    best focus is then a bound, not a measurement.

    Examples
    --------
    >>> sharpness_peak_at_sweep_end([400, 600, 800, 1000], [0.2, 0.5, 0.8, 0.9], [True] * 4)
    'far'
    >>> print(sharpness_peak_at_sweep_end([400, 600, 800, 1000, 1200], [0.2, 0.6, 1.0, 0.6, 0.2], [True] * 5))
    None
    """
    d, smoothed = _smoothed(distances, sfr_area, valid)
    if d.size < 2:
        return None
    peak = np.flatnonzero(smoothed == smoothed.max())
    if peak[-1] == d.size - 1:
        return "far"
    return "near" if peak[0] == 0 else None


def imagery_resolution_deg(sensor_resolution_deg: float, sfr10_cy_px: float) -> float:
    """Angular imagery resolution: sensor angular resolution divided by SFR10 (Thesis 2024, 6.3.1).

    Examples
    --------
    >>> round(imagery_resolution_deg(0.1, 0.25), 6)  # 0.1 deg / 0.25
    0.4
    """
    if not sfr10_cy_px > 0:
        return math.nan
    return sensor_resolution_deg / sfr10_cy_px


def lateral_mm(angular_deg: float, distance_mm: float) -> float:
    """Size covered by ``angular_deg`` at ``distance_mm`` (Thesis 2024, eq. 5-2).

    Examples
    --------
    >>> round(lateral_mm(90.0, 500.0), 6)  # 2 x 500 mm x tan(45 deg)
    1000.0
    """
    return 2.0 * distance_mm * math.tan(math.radians(angular_deg) / 2.0)


def ied_pixels(resolution_deg: float, distance_mm: float, ied_mm: float = IED_MM) -> float:
    """Pixels across the inter-eye distance at ``distance_mm`` with the mean angular pixel size FOV / pixels
    (Thesis 2024, eq. 6-2). It over-counts at the image centre, where a pixel subtends more than the mean angle.

    Examples
    --------
    62.5 mm / (tan(0.1 deg) x 1000 mm) = 62.5 / 1.74533 = 35.81 px.

    >>> round(ied_pixels(0.1, 1000.0), 2)
    35.81
    """
    return ied_mm / (math.tan(math.radians(resolution_deg)) * distance_mm)


def ied_pixels_at_centre(fov_deg: float, pixels: int, distance_mm: float, ied_mm: float = IED_MM) -> float:
    """Pixels across the inter-eye distance of a face at the image centre, ``distance_mm`` away (pinhole model).

    A rectilinear (pinhole) lens maps x = f tan(theta) with the focal length in
    pixels f = (pixels / 2) / tan(FOV / 2); a length L at distance d on the axis
    spans L f / d pixels. Near the axis a pixel subtends 1 / f rad, more than
    the mean FOV / pixels, so the centre is where the face gets the fewest
    pixels (Hartley & Zisserman, Multiple View Geometry, 2nd ed., 6.1).

    Examples
    --------
    90 deg over 640 px: f = 320 px / tan(45 deg) = 320 px; 62.5 mm x 320 / 1000 mm = 20 px.

    >>> round(ied_pixels_at_centre(90.0, 640, 1000.0), 6)
    20.0
    """
    focal_px = (pixels / 2.0) / math.tan(math.radians(fov_deg) / 2.0)
    return ied_mm * focal_px / distance_mm
