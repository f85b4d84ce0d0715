"""Sharpness over distance and imagery resolution (Thesis 2024, 5.1, 6.2-6.3, 6.6, 5.1.2, §9).

* hyperfocal distance: the nearest distance from which the SFR area stays at
  or above 90 % of its plateau, the plateau being the median over the far half
  of the sweep (Thesis 2024, 5.1.2);
* best focus: the distance of the highest SFR area after a 3-point moving
  median (Thesis 2024, 5.1.2 "argmax of a smoothed SFRarea"), ties going to the higher
  unsmoothed value;
* imagery resolution (Thesis 2024, 6.3.1): angular = sensor angular resolution /
  SFR10 (eq. 5-1), lateral = the size that angle covers at the distance (eq. 5-2);
* inter-eye distance coverage (Thesis 2024, eq. 6-2): px = IED / (tan(res) d).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

PLATEAU_FRACTION = 0.9
IED_MM = 62.5  # average adult inter-eye distance (Yildirim et al. 2015, Thesis 2024, 6.6)


def _sorted_valid(distances: Sequence[float], values: Sequence[float], valid: Sequence[bool]) -> tuple[np.ndarray, np.ndarray]:
    d, v, ok = np.asarray(distances, float), np.asarray(values, float), np.asarray(valid, bool)
    keep = ok & np.isfinite(v) & np.isfinite(d)
    order = np.argsort(d[keep])
    return d[keep][order], v[keep][order]


def plateau(distances: Sequence[float], sfr_area: Sequence[float], valid: Sequence[bool]) -> float:
    """Median SFR area over the far half of the valid positions (Thesis 2024, 5.1.2)."""
    d, v = _sorted_valid(distances, sfr_area, valid)
    if not d.size:
        return math.nan
    return float(np.median(v[d.size // 2 :]))


def hyperfocal_distance(distances: Sequence[float], sfr_area: Sequence[float], valid: Sequence[bool],
                        fraction: float = PLATEAU_FRACTION) -> float:
    """Nearest distance from which every valid SFR area stays >= ``fraction`` x plateau (Thesis 2024, 5.1.2)."""
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


def best_focus_distance(distances: Sequence[float], sfr_area: Sequence[float], valid: Sequence[bool]) -> float:
    """Distance of the highest 3-point-median-smoothed SFR area among valid positions."""
    d, v = _sorted_valid(distances, sfr_area, valid)
    if not d.size:
        return math.nan
    padded = np.concatenate([v[:1], v, v[-1:]])
    smoothed = np.median(np.stack([padded[:-2], padded[1:-1], padded[2:]]), axis=0)
    tied = np.flatnonzero(smoothed == smoothed.max())
    return float(d[tied[np.argmax(v[tied])]])  # ties (common with medians) go to the higher raw value


def nearest_sharp_distance(distances: Sequence[float], sfr_area: Sequence[float], valid: Sequence[bool],
                           tolerance: float = 0.05) -> float:
    """Nearest distance whose 3-point-median SFR area is within ``tolerance`` of the best.

    Where to put a target that must be sharp and large in the image: "if there
    are multiple distances with high focus, the smallest distance is chosen"
    (Thesis 2024, 5.2.1).
    """
    d, v = _sorted_valid(distances, sfr_area, valid)
    if not d.size:
        return math.nan
    padded = np.concatenate([v[:1], v, v[-1:]])
    smoothed = np.median(np.stack([padded[:-2], padded[1:-1], padded[2:]]), axis=0)
    return float(d[np.argmax(smoothed >= (1.0 - tolerance) * smoothed.max())])


def imagery_resolution_deg(sensor_resolution_deg: float, sfr10_cy_px: float) -> float:
    """Angular imagery resolution: sensor angular resolution divided by SFR10 (Thesis 2024, 6.3.1)."""
    if not sfr10_cy_px > 0:
        return math.nan
    return sensor_resolution_deg / sfr10_cy_px


def lateral_mm(angular_deg: float, distance_mm: float) -> float:
    """Size covered by ``angular_deg`` at ``distance_mm`` (Thesis 2024, eq. 5-2)."""
    return 2.0 * distance_mm * math.tan(math.radians(angular_deg) / 2.0)


def ied_pixels(resolution_deg: float, distance_mm: float, ied_mm: float = IED_MM) -> float:
    """Pixels across the inter-eye distance at ``distance_mm`` (Thesis 2024, eq. 6-2)."""
    return ied_mm / (math.tan(math.radians(resolution_deg)) * distance_mm)
