"""Acceptance-test quantities of VDI/VDE 2634 Part 2 (optical 3D measuring systems imaging an area).

* sphere fit: least-squares (geometric: the sum of squared radial deviations
  is minimized, started from the algebraic fit), radius free;
* outlier rule: the guideline allows up to 0.3 % of the points of a
  measurement to be left out. labctl leaves out at most ``floor(0.003 n)``
  points, and only points whose |deviation| from the first fit exceeds three
  times the RMS deviation (largest first), then refits; nothing is left out of
  a clean measurement;
* rim rule (``fit_sphere_cap``): an area sensor's pixels on a sphere's rim see
  the sphere and what lies behind it at once (the pixel footprint, the lens
  blur, a stereo matcher's window) and the sphere itself at grazing incidence;
  their points lie off the sphere and bias its size (outwards where the
  background is mixed in). The guideline itself knows only the 0.3 % rule
  above; labctl additionally keeps only the points whose line of sight (from
  the camera at the origin) meets the sphere (fitted centre, calibrated
  radius) at an incidence of at most
  ``max_incidence_deg`` (60 deg: half the 120 deg cone opening angle about
  the line of sight within which the ASTM E3125-17 sphere-centre algorithm
  keeps a sphere's points, Rachakonda et al. 2018; a pixel's footprint on the
  sphere stretches as 1 / cos(incidence), twice its frontal size there) and passes at least
  ``margin_rad`` inside its silhouette (one pixel: a pixel
  whose centre lies one pixel inside has its whole footprint, half-diagonal
  0.71 px, on the sphere). The selection depends only on the points'
  directions, not on their measured ranges, so it does not select noise; it
  is iterated with the refit until the kept points no longer change;
* probing error form P_F: range (max - min) of the radial deviations from the
  fitted sphere;
* probing error size P_S: fitted diameter minus calibrated diameter;
* sphere-spacing error SD: distance between the two fitted sphere centres (each
  fitted with its radius free) minus the calibrated distance;
* flatness measurement error F: range of the signed deviations from the
  least-squares (orthogonal) plane of the flat artefact, with the same
  outlier rule.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import optimize

#: share of the points the guideline allows to leave out
MAX_EXCLUDED_SHARE = 0.003
#: a point is an outlier candidate beyond this many RMS deviations of the first fit
OUTLIER_RMS_FACTOR = 3.0


@dataclass(frozen=True)
class SphereFit:
    centre: np.ndarray
    radius: float
    deviations: np.ndarray  # radial deviations of the points kept (mm, positive outside)
    n_points: int
    n_excluded: int
    n_rim: int = 0  # points left out by the rim rule (``fit_sphere_cap``)

    @property
    def diameter(self) -> float:
        return 2.0 * self.radius


def _excluded(deviations: np.ndarray) -> np.ndarray:
    """Boolean mask of the points the outlier rule leaves out (see the module docstring)."""
    limit = int(math.floor(MAX_EXCLUDED_SHARE * deviations.size))
    out = np.zeros(deviations.size, bool)
    if limit == 0:
        return out
    rms = float(np.sqrt(np.mean(deviations**2)))
    candidates = np.flatnonzero(np.abs(deviations) > OUTLIER_RMS_FACTOR * rms)
    worst = candidates[np.argsort(-np.abs(deviations[candidates]), kind="stable")][:limit]
    out[worst] = True
    return out


def _sphere_least_squares(points: np.ndarray) -> tuple[np.ndarray, float]:
    """Geometric least-squares sphere, started from the algebraic (linear) fit."""
    a = np.column_stack([2 * points, np.ones(len(points))])
    b = np.sum(points**2, axis=1)
    sol, *_ = np.linalg.lstsq(a, b, rcond=None)
    centre0 = sol[:3]
    radius0 = math.sqrt(max(sol[3] + centre0 @ centre0, 1e-12))

    def residuals(p: np.ndarray) -> np.ndarray:
        return np.linalg.norm(points - p[:3], axis=1) - p[3]

    result = optimize.least_squares(residuals, np.append(centre0, radius0), method="lm", xtol=1e-12, ftol=1e-12)
    return result.x[:3], float(result.x[3])


def fit_sphere(points: np.ndarray) -> SphereFit:
    """Robust least-squares sphere through (n, 3) points (VDI/VDE 2634-2 outlier rule, module docstring)."""
    points = np.asarray(points, float)
    points = points[np.all(np.isfinite(points), axis=1)]
    if len(points) < 4:
        raise ValueError(f"a sphere needs 4 points, got {len(points)}")
    centre, radius = _sphere_least_squares(points)
    excluded = _excluded(np.linalg.norm(points - centre, axis=1) - radius)
    if excluded.any():
        centre, radius = _sphere_least_squares(points[~excluded])
    kept = points[~excluded]
    return SphereFit(centre, radius, np.linalg.norm(kept - centre, axis=1) - radius, len(points), int(excluded.sum()))


def cap_mask(points: np.ndarray, centre: np.ndarray, radius: float, max_incidence_deg: float,
             margin_rad: float) -> np.ndarray:
    """Points whose line of sight from the origin meets the sphere (``centre``, ``radius``) at an incidence of at
    most ``max_incidence_deg`` and passes at least ``margin_rad`` inside its silhouette (rim rule, module docstring).

    A ray at angle gamma from the direction of the centre (distance D) passes the centre at b = D sin gamma
    and meets the sphere at the incidence asin(b / r); the silhouette lies at gamma_s = asin(r / D).
    """
    points = np.asarray(points, float)
    distance = float(np.linalg.norm(centre))
    if distance <= radius:
        raise ValueError("the camera lies inside the fitted sphere")
    cos_gamma = points @ (centre / distance) / np.linalg.norm(points, axis=1)
    gamma = np.arccos(np.clip(cos_gamma, -1.0, 1.0))
    inside = gamma <= math.asin(radius / distance) - margin_rad
    steep = distance * np.sin(gamma) <= radius * math.sin(math.radians(max_incidence_deg))
    return inside & steep & (cos_gamma > 0)


def fit_sphere_cap(points: np.ndarray, calibrated_radius: float, max_incidence_deg: float = 60.0,
                   margin_rad: float = 0.0, iterations: int = 10) -> SphereFit:
    """Robust sphere through the points an area sensor saw (camera at the origin), with the rim rule of the
    module docstring: fit, keep the points ``cap_mask`` selects about the fitted centre (the cap drawn with the
    artefact's ``calibrated_radius``, so a noisy radius cannot shrink it), refit, until the kept points stay
    the same."""
    points = np.asarray(points, float)
    points = points[np.all(np.isfinite(points), axis=1)]
    fit = fit_sphere(points)
    keep = np.ones(len(points), bool)
    for _ in range(iterations):
        selected = cap_mask(points, fit.centre, calibrated_radius, max_incidence_deg, margin_rad)
        if np.array_equal(selected, keep):
            break
        keep = selected
        fit = fit_sphere(points[keep])
    return SphereFit(fit.centre, fit.radius, fit.deviations, len(points), fit.n_excluded, int((~keep).sum()))


def probing_error_form(fit: SphereFit) -> float:
    """P_F: range of the radial deviations from the fitted sphere (mm)."""
    return float(fit.deviations.max() - fit.deviations.min())


def probing_error_size(fit: SphereFit, calibrated_diameter_mm: float) -> float:
    """P_S: fitted minus calibrated diameter (mm)."""
    return fit.diameter - calibrated_diameter_mm


def sphere_spacing_error(first: SphereFit, second: SphereFit, calibrated_distance_mm: float) -> float:
    """SD: measured minus calibrated distance between the two sphere centres (mm)."""
    return float(np.linalg.norm(first.centre - second.centre)) - calibrated_distance_mm


@dataclass(frozen=True)
class FlatnessFit:
    normal: np.ndarray
    centroid: np.ndarray
    deviations: np.ndarray  # signed deviations of the points kept (mm)
    n_points: int
    n_excluded: int


def _plane_deviations(points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    centroid = points.mean(axis=0)
    _, _, vt = np.linalg.svd(points - centroid, full_matrices=False)
    normal = vt[2] if vt[2][2] >= 0 else -vt[2]
    return normal, centroid, (points - centroid) @ normal


def fit_flat(points: np.ndarray) -> FlatnessFit:
    """Orthogonal least-squares plane through (n, 3) points, with the 0.3 % outlier rule."""
    points = np.asarray(points, float)
    points = points[np.all(np.isfinite(points), axis=1)]
    if len(points) < 3:
        raise ValueError(f"a plane needs 3 points, got {len(points)}")
    normal, centroid, dev = _plane_deviations(points)
    excluded = _excluded(dev)
    if excluded.any():
        normal, centroid, dev = _plane_deviations(points[~excluded])
    return FlatnessFit(normal, centroid, dev, len(points), int(excluded.sum()))


def flatness_error(fit: FlatnessFit) -> float:
    """F: range of the signed deviations from the least-squares plane (mm)."""
    return float(fit.deviations.max() - fit.deviations.min())
