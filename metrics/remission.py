"""Remission and angle: a small ROI on the optical axis, trueness and the misalignment fit (Thesis 2024, 5.4).

Thesis 2024, 5.4 evaluates the centre pixel of a plate seen from a camera that the
robot carries around a circle of radius R in 10 deg steps (Fig. 5-14), 6.5
reports repeatability and trueness over the angle per material (Fig. 6-11).
labctl evaluates a small ROI instead and corrects for misalignment:

ROI. :func:`axis_roi` centres the ROI on the principal point, taken as the
image centre ((H - 1) / 2, (W - 1) / 2) in pixel coordinates. On an even-sized
image that point lies between four pixels, so the ROI gets an even size there
(5 x 5 asked -> 6 x 6 on 640 x 480); a 5 x 5 ROI "around the centre pixel"
(H // 2, W // 2) would sit half a pixel off the axis, which on a plate tilted by
theta shifts its mean depth by about d tan(theta) / (2 f_px), with the sign of
theta (at 850 mm, 640 px over 67 deg: 2.4 mm at 70 deg, 5 mm at 80 deg).

Distance. The distance of a step is z of the target plane at the optical axis,
which is also the range along the axis (x = y = 0 there), i.e. the quantity of
Fig. 5-15. It is not the mean z (nor the mean range) of the ROI: across a
plate tilted by theta the depth is not linear in the pixel position, so the
ROI mean is biased by about d tan(theta)^2 <u^2> (u = x / z over the ROI), a
1/cos^2 pattern that would leak into the misalignment fit (6 mm at 80 deg for
a 6 x 6 ROI on a 160 px wide, 67 deg sensor). Instead, with u = x / z and
v = y / z of the stack-mean cloud (the camera's own pixel directions), a plane
n . p = c gives exactly 1 / z = (n_x u + n_y v + n_z) / c, so a linear least-
squares fit of 1 / z in (1, u, v) over the ROI, evaluated at u = v = 0, is the
axis distance whatever the tilt and whichever pixels are off the target.

On target. At steep angles the ROI footprint runs off the plate onto the
background (curtains 2 m behind). A ROI pixel is on the target when it is
valid (stack half-valid rule), lies in the window where the target can be
(:func:`target_window`), lies within ``off_target_fraction`` (20 %) of the
ROI's median depth (the plate itself spans d u_max tan(theta) either side of
it: 12 % at 80 deg for a 6 px ROI on 160 px over 67 deg, 3 % on 640 px; the
background lies more than twice as far), is not next to a ROI pixel that
fails these tests or is invalid, inside the ROI or in the ring of pixels
around it (a pixel straddling the plate's edge sees only part of the plate,
whose depth is not the plane's on the pixel's ray: on a steep plate a few mm
off, too few pixels to be told apart as outliers), and is not an outlier of
the plane fit (more than ``outlier_sigmas`` robust standard deviations,
MAD-based). A step is evaluated only when more than half of
the ROI is on target: a straight plate edge crossing the ROI then leaves the
ROI's centre, the optical axis, on the plate (Thesis 2024 drops positions whose
centre pixel is off the target, 6.5.1); with exactly half, the axis may lie up
to half a pixel beyond the edge.

Repeatability. Per-pixel standard deviation over the stack (Thesis 2024, 5.4.1),
pooled over the on-target ROI pixels as the root of the mean variance: the
estimate of a common pixel's std with n_pixels (N - 1) degrees of freedom,
where a single centre pixel has only N - 1.

Misalignment (Thesis 2024, 5.4.2, Fig. 5-15). A target plane delta behind the circle
centre and a camera whose optical axis passes the robot axis at e along the
camera's +x (image right) give the axis distance

    d(theta) = R + b + delta / cos(theta) - e tan(theta),

theta the robot angle (positive: the camera moves towards world +x, see
sim/geometry.py), b the camera's range offset plus the radius error plus the
material's sub-surface bias. :func:`fit_misalignment` fits b, delta and e
linearly in (1, 1 / cos theta, tan theta) to the curve of a good target (PTFE);
the geometric reference of any material is then R + delta / cos - e tan
(:func:`geometric_reference`). For 20 mm the target term adds 95 mm at 80 deg
relative to 0 deg and the camera term 113 mm at 80 deg (Thesis 2024's text says
"about 20 cm" for both; the geometry gives these values).
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from metrics.stack import stack_stats
from metrics.uncertainty import jackknife_standard_errors

#: default ROI size (Thesis 2024, 5.4), raised by one where the image size has the other parity
ROI_SIZE_PX = 5
#: largest plausible misalignment of target, camera axis and range offset (sets the target window)
MAX_OFFSET_MM = 100.0
#: smallest per-step distance uncertainty the fit uses as weight: the robot's pose repeatability
#: (UR5e +-0.03 mm) and the plate's flatness rule out knowing a step's distance better
MIN_DISTANCE_SE_MM = 0.1
#: robust residual scale below which no plane-fit outliers are rejected (mm)
RESIDUAL_FLOOR_MM = 0.1


def axis_roi(height: int, width: int, size: int = ROI_SIZE_PX) -> tuple[slice, slice]:
    """Row and column slices of a ROI centred on the image centre ((H - 1) / 2, (W - 1) / 2).

    Each side is ``size`` or ``size + 1``, whichever has the parity of the image
    side, so the ROI is symmetric about the principal point (an even ROI on an
    even image); never larger than the image.

    Examples
    --------
    >>> axis_roi(480, 640)  # 5 x 5 asked, 6 x 6 about the centre between four pixels
    (slice(237, 243, None), slice(317, 323, None))
    >>> axis_roi(5, 7)
    (slice(0, 5, None), slice(1, 6, None))
    """
    if size < 1:
        raise ValueError(f"ROI size must be at least 1 px, got {size}")

    def span(n: int) -> slice:
        k = min(n, size + (n - size) % 2)
        start = (n - k) // 2
        return slice(start, start + k)

    return span(height), span(width)


Window = tuple[slice, slice]


def with_ring(roi: Window, height: int, width: int, ring: int = 1) -> tuple[Window, Window]:
    """The ROI grown by ``ring`` pixels on each side (within the image) and where the ROI lies inside it.

    Examples
    --------
    >>> with_ring((slice(237, 243), slice(317, 323)), 480, 640)
    ((slice(236, 244, None), slice(316, 324, None)), (slice(1, 7, None), slice(1, 7, None)))
    >>> with_ring((slice(0, 5), slice(1, 6)), 5, 7)  # no ring beyond the image
    ((slice(0, 5, None), slice(0, 7, None)), (slice(0, 5, None), slice(1, 6, None)))
    """
    grown = tuple(slice(max(0, s.start - ring), min(n, s.stop + ring)) for s, n in zip(roi, (height, width)))
    inner = tuple(slice(s.start - g.start, s.stop - g.start) for s, g in zip(roi, grown))
    return grown, inner  # type: ignore[return-value]


def target_window(angle_deg: float, radius_mm: float, max_offset_mm: float = MAX_OFFSET_MM) -> tuple[float, float]:
    """Axis distances at which the target can be: R +- m (1 + 1/cos theta + |tan theta|).

    With the target plane, the camera axis and the camera's range offset each
    within ``max_offset_mm`` of nominal (the three terms of the misalignment
    model); the background 2 m behind the target lies far outside.

    Examples
    --------
    At 0 deg: 850 mm +- 100 mm x (1 + 1 + 0); at 60 deg: +- 100 mm x (1 + 2 + 1.732).

    >>> target_window(0.0, 850.0)
    (650.0, 1050.0)
    >>> tuple(round(d, 1) for d in target_window(60.0, 850.0))
    (376.8, 1323.2)
    """
    t = math.radians(angle_deg)
    half = max_offset_mm * (1.0 + 1.0 / math.cos(t) + abs(math.tan(t)))
    return radius_mm - half, radius_mm + half


@dataclass(frozen=True)
class RoiMeasurement:
    """One step's ROI: axis distance, repeatability and where its pixels went.

    ``invalid_fraction + off_target_fraction`` plus the on-target share is 1.
    ``distance_mm``, ``distance_se_mm`` (standard error of the plane fit at the
    axis), ``plane_rms_mm`` (RMS depth residual about the plane),
    ``repeatability_mm`` and its Type A standard uncertainty ``repeatability_u_mm``
    (:func:`pooled_std_jackknife`) are NaN unless ``on_target``.
    """

    distance_mm: float
    distance_se_mm: float
    repeatability_mm: float
    repeatability_u_mm: float
    plane_rms_mm: float
    invalid_fraction: float
    off_target_fraction: float
    on_target: bool
    pixels: int


def _fit_inverse_depth(u: np.ndarray, v: np.ndarray, z: np.ndarray) -> tuple[np.ndarray, float] | None:
    """Least squares 1/z = a + b u + c v; coefficients and the standard error of a (None if rank-deficient)."""
    a = np.column_stack([np.ones_like(u), u, v])
    coef, _, rank, _ = np.linalg.lstsq(a, 1.0 / z, rcond=None)
    if rank < 3 or z.size < 4:
        return None
    dof = z.size - 3
    sigma2 = float(np.sum((1.0 / z - a @ coef) ** 2)) / dof
    se_a = math.sqrt(sigma2 * float(np.linalg.inv(a.T @ a)[0, 0]))
    return coef, se_a


def _next_to(mask: np.ndarray) -> np.ndarray:
    """Pixels with a 4-neighbour in ``mask`` (inside the array; its border is no neighbour)."""
    out = np.zeros_like(mask)
    out[1:] |= mask[:-1]
    out[:-1] |= mask[1:]
    out[:, 1:] |= mask[:, :-1]
    out[:, :-1] |= mask[:, 1:]
    return out


def pooled_std_jackknife(stack: np.ndarray) -> float:
    """Type A standard uncertainty (GUM 4.2) of the pooled standard deviation sqrt(mean over pixels of the
    per-pixel sample variance) of an (N, P) stack of P pixels over N frames (NaN: not measured): the jackknife
    over the frames (Efron & Tibshirani 1993, eq. 11.5), each frame left out in turn. Over the frames, not the
    pixels, because neighbouring pixels' noise is correlated (a stereo camera's matching window) and the
    frames are the independent repetitions. NaN with fewer than three frames.

    Examples
    --------
    Independent Gaussian noise of sigma 1 on 400 pixels over 50 frames: the pooled std has a standard
    uncertainty of about sigma / sqrt(2 nu) with nu = 400 x 49 degrees of freedom (GUM E.4.3), 0.00505.

    >>> rng = np.random.default_rng(1)
    >>> round(pooled_std_jackknife(rng.normal(size=(50, 400))), 4)
    0.005
    """
    stack = np.asarray(stack, dtype=float)
    n = stack.shape[0]
    if n < 3:
        return math.nan
    seen = np.isfinite(stack)
    with np.errstate(invalid="ignore", divide="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        centred = np.where(seen, stack - np.nanmean(stack, axis=0), 0.0)
    count, total, squares = seen.sum(axis=0), centred.sum(axis=0), (centred**2).sum(axis=0)

    def pooled(kept: np.ndarray) -> tuple[float]:
        i = int(np.flatnonzero(~kept)[0])
        c = count - seen[i]
        s, ss = total - centred[i], squares - centred[i] ** 2
        ok = c >= 2
        variance = (ss[ok] - s[ok] ** 2 / c[ok]) / (c[ok] - 1)
        return (float(np.sqrt(np.mean(variance))) if ok.any() else math.nan,)

    return jackknife_standard_errors(pooled, n)[0]


def measure_roi(x: np.ndarray, y: np.ndarray, z: np.ndarray,
                window_mm: tuple[float, float] = (0.0, math.inf), *,
                inner: tuple[slice, slice] | None = None,
                off_target_fraction: float = 0.2, min_on_target: float = 0.5,
                outlier_sigmas: float = 4.0) -> RoiMeasurement:
    """Axis distance, pooled repeatability and invalid/off-target fractions of (N, h, w) ROI stacks.

    See the module docstring for the rules; ``window_mm`` is where the target
    can be (:func:`target_window`). ``inner``: where the ROI lies in the given
    stacks when they hold a ring of pixels around it (:func:`with_ring`), whose
    only use is to tell which ROI pixels lie next to one that does not see the
    target; by default the stacks are the ROI. The step is on target when more
    than ``min_on_target`` of the ROI is, and at least 4 pixels are (the plane
    fit needs a degree of freedom for its standard error).

    Examples
    --------
    A plate turned about the y axis, 1 / z = (1 - 0.5 u) / 850 with u = x / z: 850 mm on the axis;
    three frames 1 mm nearer, on and 1 mm beyond it: repeatability 1 mm.

    >>> v, u = (np.mgrid[0:6, 0:6] - 2.5) * 0.01
    >>> z = 850.0 / (1.0 - 0.5 * u) + np.array([-1.0, 0.0, 1.0])[:, None, None]
    >>> m = measure_roi(u * z, v * z, z)
    >>> m.on_target, round(m.distance_mm, 3), round(m.repeatability_mm, 3), m.invalid_fraction, m.pixels
    (True, 850.0, 1.0, 0.0, 36)
    """
    zs = stack_stats(z)
    xm, ym = stack_stats(x).mean, stack_stats(y).mean
    with np.errstate(invalid="ignore", divide="ignore"):
        valid = zs.valid & np.isfinite(xm) & np.isfinite(ym) & (zs.mean > 0)
        zm = np.where(valid, zs.mean, np.nan)
        u, v = xm / zm, ym / zm
    inner = inner or (slice(None), slice(None))
    lo, hi = window_mm
    keep = valid & (zm >= lo) & (zm <= hi)
    if keep[inner].any():
        median = float(np.median(zm[inner][keep[inner]]))
        keep &= np.abs(zm - median) <= off_target_fraction * median
    keep &= ~_next_to(~keep)
    std, zm, u, v, valid, keep = (a[inner] for a in (zs.std, zm, u, v, valid, keep))
    n_pixels = zm.size
    fit = None
    while keep.sum() > min_on_target * n_pixels:
        fit = _fit_inverse_depth(u[keep], v[keep], zm[keep])
        if fit is None:
            break
        coef = fit[0]
        with np.errstate(invalid="ignore", divide="ignore"):
            residual = zm - 1.0 / (coef[0] + coef[1] * u + coef[2] * v)
        r = residual[keep]
        scale = max(1.4826 * float(np.median(np.abs(r - np.median(r)))), RESIDUAL_FLOOR_MM)
        inliers = keep & (np.abs(residual) <= outlier_sigmas * scale)
        if inliers.sum() == keep.sum():
            break
        keep, fit = inliers, None
    invalid = float(1.0 - valid.mean())
    off = float((valid & ~keep).sum() / n_pixels)
    if fit is None:  # a fit survives only with more than min_on_target of the ROI kept
        return RoiMeasurement(math.nan, math.nan, math.nan, math.nan, math.nan, invalid, off, False, int(keep.sum()))
    coef, se_a = fit
    distance = 1.0 / float(coef[0])
    return RoiMeasurement(
        distance_mm=distance,
        distance_se_mm=se_a * distance**2,
        repeatability_mm=float(np.sqrt(np.mean(std[keep] ** 2))),
        repeatability_u_mm=pooled_std_jackknife(z[(slice(None), *inner)][:, keep]),
        plane_rms_mm=float(np.sqrt(np.mean(residual[keep] ** 2))),
        invalid_fraction=invalid,
        off_target_fraction=off,
        on_target=True,
        pixels=int(keep.sum()),
    )


def geometric_reference(angle_deg: float | np.ndarray, radius_mm: float | np.ndarray,
                        delta_mm: float = 0.0, e_mm: float = 0.0) -> np.ndarray:
    """Axis distance from the pose: R + delta / cos(theta) - e tan(theta) (Thesis 2024, Fig. 5-15).

    Examples
    --------
    850 mm + 20 mm / cos(60 deg) - 10 mm x tan(60 deg) = 850 + 40 - 17.321 mm.

    >>> round(float(geometric_reference(60.0, 850.0, delta_mm=20.0, e_mm=10.0)), 3)
    872.679
    """
    t = np.radians(np.asarray(angle_deg, float))
    return np.asarray(radius_mm, float) + delta_mm / np.cos(t) - e_mm * np.tan(t)


def trueness_vs_zero(angles_deg: Sequence[float], distances_mm: Sequence[float],
                     tolerance_deg: float = 0.5) -> np.ndarray:
    """Distance minus the mean distance at 0 deg of the same curve (Thesis 2024, 5.4.1); NaN without 0 deg.

    Examples
    --------
    >>> trueness_vs_zero([-10.0, 0.0, 10.0], [851.0, 850.0, 852.0]).tolist()
    [1.0, 0.0, 2.0]
    """
    a, d = np.asarray(angles_deg, float), np.asarray(distances_mm, float)
    zero = (np.abs(a) <= tolerance_deg) & np.isfinite(d)
    if not zero.any():
        return np.full(d.shape, np.nan)
    return d - float(np.mean(d[zero]))


@dataclass(frozen=True)
class MisalignmentFit:
    """d(theta) - R = b + delta / cos(theta) - e tan(theta), fitted by weighted least squares.

    ``delta_mm``: target plane behind the circle centre; ``e_mm``: optical axis
    beside the robot axis along the camera's +x; ``bias_mm``: b. Standard errors
    are scaled by the reduced chi-square; ``residuals_mm`` belong to
    ``angles_deg`` (the points used).
    """

    delta_mm: float
    e_mm: float
    bias_mm: float
    delta_se_mm: float
    e_se_mm: float
    bias_se_mm: float
    residual_rms_mm: float
    angles_deg: np.ndarray
    residuals_mm: np.ndarray

    def reference(self, angle_deg: float | np.ndarray, radius_mm: float | np.ndarray) -> np.ndarray:
        """The geometric reference R + delta / cos - e tan of this fit (b not included).

        Examples
        --------
        A fit to b = 2 mm, delta = 20 mm, e = 10 mm: at 60 deg, 850 + 20 / 0.5 - 10 x 1.732 mm.

        >>> t = np.radians([-60.0, -30.0, 0.0, 30.0, 60.0])
        >>> fit = fit_misalignment(np.degrees(t), 852.0 + 20.0 / np.cos(t) - 10.0 * np.tan(t), 850.0)
        >>> round(float(fit.reference(60.0, 850.0)), 3)
        872.679
        """
        return geometric_reference(angle_deg, radius_mm, self.delta_mm, self.e_mm)


def fit_misalignment(angles_deg: Sequence[float], distances_mm: Sequence[float],
                     radius_mm: float | Sequence[float], distance_se_mm: Sequence[float] | None = None,
                     min_se_mm: float = MIN_DISTANCE_SE_MM) -> MisalignmentFit:
    """Fit b, delta and e to a distance-vs-angle curve (Thesis 2024, 5.4.2, 5.4).

    Non-finite distances are skipped. Weights are 1 / se^2 with each step's
    standard error raised to at least ``min_se_mm`` (unit weights without
    ``distance_se_mm``). Applied to a trueness curve with ``radius_mm = 0`` the
    same fit measures how much 1/cos and tan pattern the curve still holds.
    Raises ValueError with fewer than 4 usable points.

    Examples
    --------
    A curve made of b = 2 mm, delta = 20 mm, e = 10 mm gives them back.

    >>> angles = np.array([-60.0, -30.0, 0.0, 30.0, 60.0])
    >>> t = np.radians(angles)
    >>> fit = fit_misalignment(angles, 850.0 + 2.0 + 20.0 / np.cos(t) - 10.0 * np.tan(t), 850.0)
    >>> round(fit.bias_mm, 6), round(fit.delta_mm, 6), round(fit.e_mm, 6)
    (2.0, 20.0, 10.0)
    """
    a = np.asarray(angles_deg, float)
    d = np.asarray(distances_mm, float)
    r = np.broadcast_to(np.asarray(radius_mm, float), a.shape)
    se = np.ones_like(d) if distance_se_mm is None else np.maximum(np.asarray(distance_se_mm, float), min_se_mm)
    ok = np.isfinite(a) & np.isfinite(d) & np.isfinite(r) & np.isfinite(se)
    if ok.sum() < 4:
        raise ValueError(f"misalignment fit needs at least 4 angles with a distance, got {int(ok.sum())}")
    t = np.radians(a[ok])
    design = np.column_stack([np.ones_like(t), 1.0 / np.cos(t), -np.tan(t)])
    w = 1.0 / se[ok]
    y = d[ok] - r[ok]
    coef, _, rank, _ = np.linalg.lstsq(design * w[:, None], y * w, rcond=None)
    if rank < 3:
        raise ValueError("misalignment fit is degenerate: the angles do not separate 1, 1/cos and tan")
    residual = y - design @ coef
    dof = max(int(ok.sum()) - 3, 1)
    chi2_red = float(np.sum((residual * w) ** 2)) / dof
    cov = np.linalg.inv((design * w[:, None]).T @ (design * w[:, None])) * chi2_red
    se_coef = np.sqrt(np.diag(cov))
    return MisalignmentFit(
        delta_mm=float(coef[1]), e_mm=float(coef[2]), bias_mm=float(coef[0]),
        delta_se_mm=float(se_coef[1]), e_se_mm=float(se_coef[2]), bias_se_mm=float(se_coef[0]),
        residual_rms_mm=float(np.sqrt(np.mean(residual**2))),
        angles_deg=a[ok], residuals_mm=residual,
    )
