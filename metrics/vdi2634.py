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

    @property
    def used_share(self) -> float:
        """Share of the points the fit used: neither outside the rim rule nor left out as outliers (VDI/VDE
        2634-2 allows leaving out 0.3 %; the rim rule leaves out more, module docstring).

        Examples
        --------
        >>> SphereFit(np.zeros(3), 25.0, np.zeros(70), n_points=100, n_excluded=0, n_rim=30).used_share
        0.7
        """
        return (self.n_points - self.n_rim - self.n_excluded) / self.n_points


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
    """Robust least-squares sphere through (n, 3) points (VDI/VDE 2634-2 outlier rule, module docstring).

    Examples
    --------
    Seven points of a sphere of radius 25 mm about (1, 2, 500) mm.

    >>> directions = np.vstack([np.eye(3), -np.eye(3), np.ones((1, 3)) / np.sqrt(3.0)])
    >>> fit = fit_sphere(np.array([1.0, 2.0, 500.0]) + 25.0 * directions)
    >>> np.round(fit.centre, 6).tolist(), round(fit.radius, 6), fit.n_excluded
    ([1.0, 2.0, 500.0], 25.0, 0)
    """
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

    Examples
    --------
    A sphere of radius 25 mm, 500 mm away: the point facing the camera (incidence 0) and one 30 deg
    round the sphere (incidence 31.5 deg) are kept, the point on the silhouette (grazing) is not.

    >>> points = np.array([[0.0, 0.0, 475.0], [12.5, 0.0, 500.0 - 25.0 * np.cos(np.radians(30.0))], [25.0, 0.0, 500.0]])
    >>> cap_mask(points, np.array([0.0, 0.0, 500.0]), 25.0, max_incidence_deg=60.0, margin_rad=0.0).tolist()
    [True, True, False]
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
    the same.

    Examples
    --------
    The half of a sphere (radius 25 mm, 500 mm away) that faces the camera, in rings 10, 30, 50 and
    70 deg round from the line of sight: the first three meet their lines of sight at incidences up to
    52 deg, the ring at 70 deg at 73 deg and is left out (12 of 48 points).

    >>> t, p = np.radians(np.mgrid[10:90:20, 0:360:30])
    >>> rays = np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), -np.cos(t)], axis=-1).reshape(-1, 3)
    >>> fit = fit_sphere_cap(np.array([0.0, 0.0, 500.0]) + 25.0 * rays, calibrated_radius=25.0)
    >>> round(fit.radius, 6), fit.n_points, fit.n_rim
    (25.0, 48, 12)
    """
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
    """P_F: range of the radial deviations from the fitted sphere (mm).

    Examples
    --------
    >>> fit = SphereFit(np.zeros(3), 12.5, np.array([-0.02, 0.01, 0.03]), n_points=3, n_excluded=0)
    >>> round(probing_error_form(fit), 6)
    0.05
    """
    return float(fit.deviations.max() - fit.deviations.min())


def probing_error_size(fit: SphereFit, calibrated_diameter_mm: float) -> float:
    """P_S: fitted minus calibrated diameter (mm).

    Examples
    --------
    >>> fit = SphereFit(np.zeros(3), 12.51, np.zeros(3), n_points=3, n_excluded=0)
    >>> round(probing_error_size(fit, 25.0), 6)
    0.02
    """
    return fit.diameter - calibrated_diameter_mm


def sphere_spacing_error(first: SphereFit, second: SphereFit, calibrated_distance_mm: float) -> float:
    """SD: measured minus calibrated distance between the two sphere centres (mm).

    Examples
    --------
    Centres 500 mm apart (a 3-4-5 triangle), calibrated 499.9 mm.

    >>> first = SphereFit(np.array([0.0, 0.0, 1000.0]), 25.0, np.zeros(3), n_points=3, n_excluded=0)
    >>> second = SphereFit(np.array([300.0, 400.0, 1000.0]), 25.0, np.zeros(3), n_points=3, n_excluded=0)
    >>> round(sphere_spacing_error(first, second, 499.9), 6)
    0.1
    """
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
    """Orthogonal least-squares plane through (n, 3) points, with the 0.3 % outlier rule.

    Examples
    --------
    A +-0.05 mm checker on the plane z = 1000 mm: the plane is z = 1000 mm, the deviations +-0.05 mm.

    >>> y, x = np.mgrid[0:4, 0:4].astype(float)
    >>> z = 1000.0 + 0.05 * (-1.0) ** (x + y)
    >>> fit = fit_flat(np.column_stack([x.ravel(), y.ravel(), z.ravel()]))
    >>> round(float(fit.normal[2]), 6), round(float(fit.centroid[2]), 6), fit.n_points
    (1.0, 1000.0, 16)
    """
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
    """F: range of the signed deviations from the least-squares plane (mm).

    Examples
    --------
    >>> y, x = np.mgrid[0:4, 0:4].astype(float)
    >>> z = 1000.0 + 0.05 * (-1.0) ** (x + y)
    >>> round(flatness_error(fit_flat(np.column_stack([x.ravel(), y.ravel(), z.ravel()]))), 6)
    0.1
    """
    return float(fit.deviations.max() - fit.deviations.min())
