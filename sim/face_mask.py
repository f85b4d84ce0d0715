"""Analytic height field of an adult silicone face mask (Thesis 2024, 6.7, Fig. 5-13).

Coordinates in mm on the mask's base plane, seen frontally by the camera:
x to the right, y downwards (image convention), origin at the centre of the
outline. The height h(x, y) is how far the surface comes towards the camera
from the base plane; in the camera frame (x right, y down, z away from the
camera) a surface point lies at z = z_base - h.

    h = T(rho) * F(x, y),    rho = sqrt((x / 75)^2 + (y / 105)^2)

* Outline: rho < 1, an ellipse 150 mm wide and 210 mm high.
* Rim taper: T = S((1 - rho) / 0.2) with the smootherstep
  S(t) = 6 t^5 - 15 t^4 + 10 t^3 for t in [0, 1] (0 below, 1 above): h and
  its first two derivatives vanish on the outline, and the mask falls
  steeply but smoothly to its base over the outer fifth of the outline.
* Relief F, a sum of smooth analytic parts; G is a Gaussian bump
  exp(-((x - x0)^2 / 2 sx^2 + (y - y0)^2 / 2 sy^2)), L(t) = 1 / (1 + e^-t):
  - face base: dome 21 * sqrt(1 - rho^3) (flat front, curving back at the sides);
  - brow ridge: +5 G at (0, -33), sigma (32, 5);
  - eye sockets: -13 G at (+-31.25, -14), sigma (11, 8): centres 62.5 mm
    apart, the mean adult inter-eye distance Thesis 2024 uses (6.6, after
    Yildirim et al. 2015);
  - nose: (3 + 11 (y + 26) / 54) * L((y + 26) / 3) * L((32 - y) / 2.5)
    * exp(-(x / w)^4), a dorsum rising from the nasion (y = -26) towards
    y = +28, ending under the tip, with steep sides; the half-width
    w = 6 + 6 L((y - 18) / 4) widens from the bridge to the alae. The tip,
    the highest point of the mask, lies at (0, +24) and is 33.6 mm high;
  - cheeks: +9 G at (+-44, +10), sigma (12, 17);
  - lips: +5 G at (0, +47), sigma (15, 4.5) and +5 G at (0, +60), sigma (13, 4.5);
  - chin: +8 G at (0, +84), sigma (17, 9).

Every part is infinitely differentiable inside the outline and the taper is
C2, so normals are well defined everywhere. The unit normal pointing out of
the mask (towards the camera) is n = (-dh/dx, -dh/dy, -1) / sqrt(1 + |grad h|^2);
its angle to the viewing axis is arccos(1 / sqrt(1 + |grad h|^2)).

Fig. 5-13 of Thesis 2024 shows, for the real mask, a broad distribution of
these angles with many near 40 and 70 deg (nose, cheeks). This model, limited
to 33.6 mm of relief, has about 37 % of its projected area (47 % of its
surface area) between 30 and 75 deg, and no angle beyond 68 deg; most
of the rest lies at 10-25 deg on forehead, cheeks and chin.
"""

from __future__ import annotations

import numpy as np

HALF_WIDTH_MM = 75.0
HALF_HEIGHT_MM = 105.0
RIM_BAND = 0.2
INTER_EYE_DISTANCE_MM = 62.5
EYE_CENTRES_MM = ((-INTER_EYE_DISTANCE_MM / 2, -14.0), (INTER_EYE_DISTANCE_MM / 2, -14.0))
NOSE_TIP_MM = (0.0, 24.0)
_NASION_Y_MM = -26.0
_DORSUM_END_Y_MM = 28.0


def _gauss(x: np.ndarray, y: np.ndarray, x0: float, y0: float, sx: float, sy: float) -> np.ndarray:
    return np.exp(-0.5 * (((x - x0) / sx) ** 2 + ((y - y0) / sy) ** 2))


def _logistic(t: np.ndarray) -> np.ndarray:
    return 0.5 * (1.0 + np.tanh(0.5 * t))


def _nose(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    dorsum = 3.0 + 11.0 * (y - _NASION_Y_MM) / (_DORSUM_END_Y_MM - _NASION_Y_MM)
    window = _logistic((y - _NASION_Y_MM) / 3.0) * _logistic((_DORSUM_END_Y_MM + 4.0 - y) / 2.5)
    half_width = 6.0 + 6.0 * _logistic((y - 18.0) / 4.0)
    return dorsum * window * np.exp(-((x / half_width) ** 4))


def _relief(x: np.ndarray, y: np.ndarray, rho: np.ndarray) -> np.ndarray:
    (lx, ey), (rx, _) = EYE_CENTRES_MM
    return (
        21.0 * np.sqrt(np.clip(1.0 - rho**3, 0.0, None))
        + 5.0 * _gauss(x, y, 0.0, -33.0, 32.0, 5.0)
        - 13.0 * (_gauss(x, y, lx, ey, 11.0, 8.0) + _gauss(x, y, rx, ey, 11.0, 8.0))
        + _nose(x, y)
        + 9.0 * (_gauss(x, y, -44.0, 10.0, 12.0, 17.0) + _gauss(x, y, 44.0, 10.0, 12.0, 17.0))
        + 5.0 * _gauss(x, y, 0.0, 47.0, 15.0, 4.5)
        + 5.0 * _gauss(x, y, 0.0, 60.0, 13.0, 4.5)
        + 8.0 * _gauss(x, y, 0.0, 84.0, 17.0, 9.0)
    )


def face_height(x_mm: np.ndarray, y_mm: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Height of the mask above its base plane (mm) and whether (x, y) lies inside the outline.

    ``x_mm`` and ``y_mm`` broadcast against each other; the height is 0 outside
    the outline.
    """
    x, y = np.broadcast_arrays(np.asarray(x_mm, dtype=float), np.asarray(y_mm, dtype=float))
    rho = np.hypot(x / HALF_WIDTH_MM, y / HALF_HEIGHT_MM)
    t = np.clip((1.0 - rho) / RIM_BAND, 0.0, 1.0)
    taper = t**3 * (10.0 - 15.0 * t + 6.0 * t**2)
    return taper * _relief(x, y, rho), rho < 1.0


def face_normals(x_mm: np.ndarray, y_mm: np.ndarray, step_mm: float = 0.01) -> np.ndarray:
    """Unit normals, shape (3, ...), in the camera frame, pointing out of the mask towards the camera.

    n = (-dh/dx, -dh/dy, -1) / sqrt(1 + |grad h|^2) with the gradient by
    central differences of ``step_mm`` (error O(step^2): the field is smooth).
    """
    x, y = np.broadcast_arrays(np.asarray(x_mm, dtype=float), np.asarray(y_mm, dtype=float))
    hx = (face_height(x + step_mm, y)[0] - face_height(x - step_mm, y)[0]) / (2 * step_mm)
    hy = (face_height(x, y + step_mm)[0] - face_height(x, y - step_mm)[0]) / (2 * step_mm)
    n = np.stack([-hx, -hy, -np.ones_like(hx)])
    return n / np.linalg.norm(n, axis=0)


def angle_histogram(
    bin_width_deg: float = 5.0, spacing_mm: float = 0.5, per_surface_area: bool = False
) -> tuple[np.ndarray, np.ndarray]:
    """Distribution of the angle between surface normal and viewing axis over the mask.

    Samples the inside of the outline on a square grid of ``spacing_mm`` and
    returns ``(edges_deg, fraction)``: bin edges from 0 to 90 deg and the
    fraction of the area in each bin (summing to 1). The area is the projected
    one, as a frontal camera's pixels see it; with ``per_surface_area`` each
    sample is weighted by 1 / cos(angle), the true surface area (as a point
    cloud sampled evenly on the surface would count it).
    """
    xs = np.arange(-HALF_WIDTH_MM, HALF_WIDTH_MM + spacing_mm / 2, spacing_mm)
    ys = np.arange(-HALF_HEIGHT_MM, HALF_HEIGHT_MM + spacing_mm / 2, spacing_mm)
    x, y = np.meshgrid(xs, ys)
    inside = face_height(x, y)[1]
    cos = np.abs(face_normals(x[inside], y[inside])[2])
    edges = np.arange(0.0, 90.0 + bin_width_deg / 2, bin_width_deg)
    weights = 1.0 / cos if per_surface_area else None
    counts, _ = np.histogram(np.degrees(np.arccos(cos)), bins=edges, weights=weights)
    return edges, counts / counts.sum()
