"""What one stack of an arbitrary scene shows without a reference: validity, temporal noise, planarity.

* validity per pixel: the fraction of frames with a finite, non-zero depth;
  the capture's valid fraction is the share of pixels valid in at least
  half of the frames and in two (the rule of metrics/stack.py);
* temporal noise per pixel: the standard deviation of z over the stack (ISO
  5725-1 repeatability conditions: same scene, camera and settings, short
  time), summarized by its median and 90 % quantile over the valid pixels;
* plane fit: least squares z = a x + b y + c through the stack-mean points
  (metrics/depth_quality.fit_plane, after the 0.5 % depth trimming of the
  Intel Depth Quality Tool). The scene counts as planar when at least 95 % of
  the points lie within the tolerance of the plane: 3 x the Q90 temporal noise,
  but at least 0.5 % of the median depth (a judgement: the flatness a wall
  keeps under multipath and a camera's own non-linearity); the plane is then
  refitted to those points and its distance on the optical axis, its tilts and
  the RMS of the residuals are reported.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from metrics.depth import median_q90_abs
from metrics.depth_quality import fit_plane, trim_by_z
from metrics.stack import stack_stats

PLANAR_INLIER_FRACTION = 0.95
PLANAR_NOISE_FACTOR = 3.0
PLANAR_MIN_TOLERANCE = 0.005  # of the median depth


@dataclass(frozen=True)
class PlaneFit:
    planar: bool
    inlier_fraction: float
    tolerance_mm: float
    distance_on_axis_mm: float
    tilt_about_x_deg: float  # the plane's normal turned towards +y
    tilt_about_y_deg: float  # the plane's normal turned towards +x
    rms_mm: float
    residual: np.ndarray = field(repr=False)  # (H, W) signed distance from the plane, NaN where invalid


@dataclass(frozen=True)
class CaptureSummary:
    frames: int
    valid_fraction: float
    depth_median_mm: float
    depth_q05_mm: float
    depth_q95_mm: float
    temporal_noise_median_mm: float
    temporal_noise_q90_mm: float
    plane: PlaneFit | None
    depth: np.ndarray = field(repr=False)  # (H, W) stack mean of z
    noise: np.ndarray = field(repr=False)  # (H, W) per-pixel std of z
    validity: np.ndarray = field(repr=False)  # (H, W) fraction of frames valid
    intensity: np.ndarray | None = field(repr=False, default=None)  # (H, W) stack mean


def plane_fit(x: np.ndarray, y: np.ndarray, z: np.ndarray, noise_q90_mm: float) -> PlaneFit | None:
    """Fit a plane to the organized mean cloud (H, W) and judge whether the scene is planar (module docstring).

    None when fewer than 3 points are valid.

    Examples
    --------
    z = 1000 + 0.1 x + 0.2 y: planar, 1000 mm on the axis, normal turned by -atan(0.2) = -11.310 deg
    towards +y and -atan(0.1) = -5.711 deg towards +x, no residual.

    >>> y, x = np.mgrid[-10:10, -10:10].astype(float)
    >>> fit = plane_fit(x, y, 1000.0 + 0.1 * x + 0.2 * y, noise_q90_mm=1.0)
    >>> fit.planar, round(fit.distance_on_axis_mm, 6), round(fit.tilt_about_x_deg, 3), round(fit.tilt_about_y_deg, 3)
    (True, 1000.0, -11.31, -5.711)
    >>> round(fit.rms_mm, 6)
    0.0
    """
    ok = np.isfinite(x) & np.isfinite(y) & np.isfinite(z) & (z != 0)
    points = np.stack([x[ok], y[ok], z[ok]], axis=-1).astype(np.float64)
    if len(points) < 3:
        return None
    plane = fit_plane(trim_by_z(points))
    noise = noise_q90_mm if math.isfinite(noise_q90_mm) else 0.0
    tolerance = max(PLANAR_NOISE_FACTOR * noise, PLANAR_MIN_TOLERANCE * float(np.median(points[:, 2])))
    inliers = np.abs(plane.signed_distance(points)) <= tolerance
    fraction = float(inliers.mean())
    planar = fraction >= PLANAR_INLIER_FRACTION
    if planar and inliers.sum() >= 3:
        plane = fit_plane(points[inliers])
    residual = np.full(z.shape, np.nan)
    residual[ok] = plane.signed_distance(points)
    rms = float(np.sqrt(np.mean(np.square(residual[ok][inliers])))) if inliers.any() else math.nan
    nx, ny, nz = plane.normal
    return PlaneFit(planar, fraction, tolerance, plane.z_on_axis(), math.degrees(math.atan2(ny, nz)),
                    math.degrees(math.atan2(nx, nz)), rms, residual)


def summarize_capture(x: np.ndarray, y: np.ndarray, z: np.ndarray, intensity: np.ndarray | None = None
                      ) -> CaptureSummary:
    """Maps and summary of (N, H, W) stacks of x, y, z (mm, NaN or 0 invalid) and optionally intensity.

    Examples
    --------
    Three frames of a wall at 1000 mm seen 1 mm nearer, at and 1 mm farther: all pixels valid,
    median depth 1000 mm, temporal noise (sample std) 1 mm.

    >>> y, x = np.mgrid[-2:2, -2:2].astype(float)
    >>> z = np.stack([np.full(x.shape, 1000.0 + k) for k in (-1.0, 0.0, 1.0)])
    >>> s = summarize_capture(np.broadcast_to(x, z.shape), np.broadcast_to(y, z.shape), z)
    >>> s.frames, s.valid_fraction, s.depth_median_mm, s.temporal_noise_median_mm, s.plane.planar
    (3, 1.0, 1000.0, 1.0, True)
    """
    z = np.where(np.asarray(z) == 0, np.nan, np.asarray(z, dtype=np.float32))
    frames = z.shape[0]
    sz = stack_stats(z)
    sx, sy = stack_stats(np.asarray(x, dtype=np.float32)), stack_stats(np.asarray(y, dtype=np.float32))
    validity = np.isfinite(z).mean(axis=0)
    depth, noise = sz.mean, sz.std  # a single frame has no std (NaN)
    valid = np.isfinite(depth)
    finite_depth = depth[np.isfinite(depth)]
    if finite_depth.size:
        q05, median, q95 = (float(v) for v in np.quantile(finite_depth, [0.05, 0.5, 0.95]))
    else:
        q05 = median = q95 = math.nan
    noise_median, noise_q90 = median_q90_abs(noise)
    plane = plane_fit(sx.mean, sy.mean, depth, noise_q90)
    mean_intensity = stack_stats(np.asarray(intensity, dtype=np.float32)).mean if intensity is not None else None
    if mean_intensity is not None and not np.isfinite(mean_intensity).any():
        mean_intensity = None  # a camera (or recording) without an intensity stream
    return CaptureSummary(frames, float(valid.mean()), median, q05, q95, noise_median, noise_q90, plane,
                          depth, noise, validity, mean_intensity)
