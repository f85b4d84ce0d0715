"""The depth-quality figures camera vendors quote, defined as their own tools define them.

Intel RealSense Depth Quality Tool (librealsense ``tools/depth-quality``,
``depth-metrics.h`` and the metric definitions of ``rs-depth-quality.cpp``),
evaluated on one frame of a flat target:

* ROI: the centred 40 % of the image width and height (the tool's default
  ``roi_percentage`` 0.4; columns ``int(0.3 W) .. int(0.7 W)``, rows likewise);
* **fill rate**: valid pixels in the ROI / ROI pixels, in %;
* plane: least-squares fit to all valid ROI points, as ``plane_from_points``
  does for a target facing the camera (the regression of z on x and y, whose
  normal (-a, -b, 1) is normalized, pointing away from the camera);
* trimming: the points are sorted by z and ``n // 200`` are dropped at each
  end (the lowest and highest 0.5 %) before the error statistics; the plane is
  not refitted;
* **Z accuracy**: per point, (z where the optical axis meets the plane - ground
  truth) + the signed point-to-plane distance; the element ``n // 2`` of the
  sorted errors, in % of the ground truth (positive: the plane lies beyond the
  ground truth);
* **plane-fit RMS**: RMS of the signed point-to-plane distances, in mm (the
  tool also shows it in % of the plane distance);
* **subpixel RMS** (stereo): RMS over the points of BL FL / |p| - BL FL / |p'|,
  p' the orthogonal projection of p onto the plane, BL the baseline (mm), FL
  the focal length in pixels. The tool's help text writes Z for "the depth
  range of the i-th pixel"; its code divides by the Euclidean length of the
  point (the range), and so does this function.

Basler blaze depth-quality metrics (docs.baslerweb.com "Depth Quality
Metrics": accuracy as a median deviation, spatial precision as the RMS error of
the depth data, temporal precision as the uniformity over time; "Accuracy and
Precision": 40 x 40 pixels in the centre of the sensor, 25 images). The page
states the quantities in words only; labctl's choices:

* ROI: the centred 40 x 40 pixels (the blaze's test condition);
* **spatial precision**: per frame, the RMS of the depth (z) residuals from the
  least-squares plane z = a x + b y + c over the valid ROI pixels, no
  trimming; the mean over the frames of the stack;
* **temporal precision**: per ROI pixel the sample standard deviation (n - 1)
  over the stack (the half-valid rule of ``metrics.stack``), then the quadratic
  mean over the pixels (so that it estimates the noise sigma without the bias
  of a median of sample standard deviations).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from metrics.stack import stack_stats
from metrics.uncertainty import jackknife_standard_errors, standard_error_of_mean

#: the Depth Quality Tool's default ROI: this fraction of width and height, centred
DQT_ROI_FRACTION = 0.4
#: the blaze test condition: this many pixels square in the centre of the sensor
BASLER_ROI_PX = 40


def dqt_roi(height: int, width: int, fraction: float = DQT_ROI_FRACTION) -> tuple[slice, slice]:
    """Rows and columns of the Depth Quality Tool's ROI (``int(dim * (0.5 -+ fraction / 2))``).

    Examples
    --------
    >>> dqt_roi(480, 640)  # int(0.3 H) .. int(0.7 H), int(0.3 W) .. int(0.7 W)
    (slice(144, 336, None), slice(192, 448, None))
    """
    return (slice(int(height * (0.5 - fraction / 2)), int(height * (0.5 + fraction / 2))),
            slice(int(width * (0.5 - fraction / 2)), int(width * (0.5 + fraction / 2))))


def centre_window(height: int, width: int, size: int = BASLER_ROI_PX) -> tuple[slice, slice]:
    """The centred ``size`` x ``size`` pixels (clipped to the image).

    Examples
    --------
    >>> centre_window(480, 640)
    (slice(220, 260, None), slice(300, 340, None))
    >>> centre_window(30, 640)[0]  # clipped to the image
    slice(0, 30, None)
    """
    rh, rw = min(size, height), min(size, width)
    top, left = (height - rh) // 2, (width - rw) // 2
    return slice(top, top + rh), slice(left, left + rw)


def fill_rate_pct(z: np.ndarray) -> float:
    """librealsense "Fill-Rate": % of the ROI's pixels with a valid (finite, non-zero) depth.

    Examples
    --------
    >>> fill_rate_pct(np.array([[1000.0, 0.0], [np.nan, 1002.0]]))
    50.0
    """
    return float(100.0 * np.count_nonzero(np.isfinite(z) & (z != 0)) / z.size)


@dataclass(frozen=True)
class Plane:
    """Unit normal n (n_z > 0) and offset d of the plane n . p + d = 0 (mm)."""

    normal: np.ndarray
    d: float

    def signed_distance(self, points: np.ndarray) -> np.ndarray:
        """Distance of (n, 3) points from the plane, positive beyond it (away from the camera).

        Examples
        --------
        >>> wall = Plane(np.array([0.0, 0.0, 1.0]), -1000.0)  # z = 1000 mm
        >>> wall.signed_distance(np.array([[0.0, 0.0, 1002.0], [5.0, 5.0, 999.0]])).tolist()
        [2.0, -1.0]
        """
        return points @ self.normal + self.d

    def z_on_axis(self) -> float:
        """z where the optical axis (x = y = 0) meets the plane.

        Examples
        --------
        0.6 x + 0.8 z = 800 meets x = 0 at z = 800 / 0.8.

        >>> round(Plane(np.array([0.6, 0.0, 0.8]), -800.0).z_on_axis(), 6)
        1000.0
        """
        return -self.d / float(self.normal[2])


def fit_plane(points: np.ndarray) -> Plane:
    """Least-squares plane z = a x + b y + c through (n, 3) points (librealsense ``plane_from_points``, z case).

    The normal equations of the centred points, as the tool solves them.

    Examples
    --------
    z = 1000 + 0.1 x + 0.2 y: normal (-0.1, -0.2, 1) / sqrt(1.05), 1000 mm on the axis.

    >>> y, x = np.mgrid[-3:4, -3:4].astype(float)
    >>> plane = fit_plane(np.column_stack([x.ravel(), y.ravel(), 1000.0 + 0.1 * x.ravel() + 0.2 * y.ravel()]))
    >>> np.round(plane.normal, 4).tolist(), round(plane.z_on_axis(), 6)
    ([-0.0976, -0.1952, 0.9759], 1000.0)
    """
    if len(points) < 3:
        raise ValueError(f"a plane needs 3 points, got {len(points)}")
    centroid = points.mean(axis=0)
    q = points - centroid
    xx, xy, yy = q[:, 0] @ q[:, 0], q[:, 0] @ q[:, 1], q[:, 1] @ q[:, 1]
    xz, yz = q[:, 0] @ q[:, 2], q[:, 1] @ q[:, 2]
    a, b = np.linalg.solve(np.array([[xx, xy], [xy, yy]]), np.array([xz, yz]))
    normal = np.array([-a, -b, 1.0])
    normal /= np.linalg.norm(normal)
    return Plane(normal, -float(normal @ centroid))


def _lengths(points: np.ndarray) -> np.ndarray:
    """Euclidean length of each row of (n, 3) points."""
    return np.sqrt(np.einsum("ij,ij->i", points, points))


def valid_points(x: np.ndarray, y: np.ndarray, z: np.ndarray) -> np.ndarray:
    """(n, 3) array of the finite, non-zero-depth points of organized x, y, z.

    Examples
    --------
    >>> x, y = np.array([[0.0, 1.0], [2.0, 3.0]]), np.zeros((2, 2))
    >>> valid_points(x, y, np.array([[1000.0, 0.0], [np.nan, 1001.0]])).tolist()
    [[0.0, 0.0, 1000.0], [3.0, 0.0, 1001.0]]
    """
    ok = np.isfinite(x) & np.isfinite(y) & np.isfinite(z) & (z != 0)
    return np.stack([x[ok], y[ok], z[ok]], axis=-1).astype(np.float64)


def trim_by_z(points: np.ndarray) -> np.ndarray:
    """Drop the ``n // 200`` points of lowest and of highest z (librealsense's 0.5 % outlier trimming).

    A partition instead of the tool's full sort: the same points are kept (up to ties), in another order.

    Examples
    --------
    400 points: 400 // 200 = 2 dropped at each end.

    >>> z = np.arange(400.0)
    >>> kept = trim_by_z(np.column_stack([z, z, z]))
    >>> len(kept), float(kept[:, 2].min()), float(kept[:, 2].max())
    (396, 2.0, 397.0)
    """
    n = len(points)
    cut = n // 200
    if cut == 0:
        return points
    order = np.argpartition(points[:, 2], (cut, n - cut - 1))
    return points[order[cut:n - cut]]


@dataclass(frozen=True)
class DqtFrame:
    """The Depth Quality Tool's figures of one frame (NaN where not computable)."""

    fill_rate_pct: float
    z_accuracy_pct: float
    plane_fit_rms_mm: float
    plane_fit_rms_pct: float
    subpixel_rms_px: float
    distance_mm: float


def dqt_frame(x: np.ndarray, y: np.ndarray, z: np.ndarray, ground_truth_mm: float,
              focal_px: float | None = None, baseline_mm: float | None = None) -> DqtFrame:
    """librealsense depth-quality figures of one frame's ROI (x, y, z in mm, NaN or 0 invalid).

    ``ground_truth_mm``: distance of the target plane along the optical axis
    (Z accuracy is NaN when it is not positive); ``focal_px`` and
    ``baseline_mm``: the stereo geometry (subpixel RMS is NaN without them).

    Examples
    --------
    A wall at 1000 mm said to be at 990 mm, one column without depth: fill rate 75 %, Z accuracy
    100 x 10 / 990 = 1.010 %, no plane-fit error.

    >>> y, x = np.mgrid[-2:2, -2:2].astype(float)
    >>> z = np.full(x.shape, 1000.0)
    >>> z[:, 0] = 0.0
    >>> f = dqt_frame(x, y, z, ground_truth_mm=990.0)
    >>> f.fill_rate_pct, round(f.z_accuracy_pct, 3), round(f.plane_fit_rms_mm, 6), round(f.distance_mm, 6)
    (75.0, 1.01, 0.0, 1000.0)
    """
    fill = fill_rate_pct(z)
    points = valid_points(x, y, z)
    if len(points) < 3:
        return DqtFrame(fill, math.nan, math.nan, math.nan, math.nan, math.nan)
    plane = fit_plane(points)
    kept = trim_by_z(points)
    dist = plane.signed_distance(kept)
    rms = float(np.sqrt(np.mean(dist**2)))
    distance = -plane.d  # the camera's distance from the plane
    accuracy = math.nan
    if ground_truth_mm > 0:
        middle = len(dist) // 2
        errors = np.partition(plane.z_on_axis() - ground_truth_mm + dist, middle)
        accuracy = float(100.0 * errors[middle] / ground_truth_mm)
    subpixel = math.nan
    if focal_px and baseline_mm:
        bf = focal_px * baseline_mm
        projected = kept - dist[:, None] * plane.normal
        disparity = bf / _lengths(kept) - bf / _lengths(projected)
        subpixel = float(np.sqrt(np.mean(disparity**2)))
    return DqtFrame(fill, accuracy, rms, 100.0 * rms / distance, subpixel, distance)


def spatial_precision_mm(x: np.ndarray, y: np.ndarray, z: np.ndarray) -> float:
    """Basler spatial precision of one frame: RMS of the z residuals from the least-squares plane (NaN < 3 points).

    Examples
    --------
    A tilted plane with a +-0.5 mm checker on it: the plane absorbs the tilt, the residuals are +-0.5 mm.

    >>> y, x = np.mgrid[0:4, 0:4].astype(float)
    >>> round(spatial_precision_mm(x, y, 1000.0 + 0.1 * x + 0.5 * (-1.0) ** (x + y)), 6)
    0.5
    """
    points = valid_points(x, y, z)
    if len(points) < 3:
        return math.nan
    design = np.column_stack([points[:, 0], points[:, 1], np.ones(len(points))])
    coef, *_ = np.linalg.lstsq(design, points[:, 2], rcond=None)
    return float(np.sqrt(np.mean((points[:, 2] - design @ coef) ** 2)))


def temporal_precision_mm(z_stack: np.ndarray) -> float:
    """Basler temporal precision of an (N, h, w) ROI stack: quadratic mean of the per-pixel sample std.

    Examples
    --------
    Every pixel seen as d - 1, d, d + 1: sample std 1 mm.

    >>> z = np.array([[[999.0, 1000.0]], [[1000.0, 1001.0]], [[1001.0, 1002.0]]])
    >>> temporal_precision_mm(z)
    1.0
    """
    std = stack_stats(z_stack).std
    std = std[np.isfinite(std)]
    return float(np.sqrt(np.mean(std**2))) if std.size else math.nan


@dataclass(frozen=True)
class VendorFigures:
    """Vendor figures of one wall position (DQT figures: mean over the frames given)."""

    reference_mm: float
    n_frames: int
    fill_rate_pct: float
    z_accuracy_pct: float
    plane_fit_rms_mm: float
    plane_fit_rms_pct: float
    subpixel_rms_px: float
    spatial_precision_mm: float
    temporal_precision_mm: float


def _mean(values: list[float]) -> float:
    finite = [v for v in values if math.isfinite(v)]
    return float(np.mean(finite)) if finite else math.nan


#: the Depth Quality Tool's figures are taken from (the mean over) this many frames of a stack: the first
DQT_FRAMES = 1
Cloud = tuple[np.ndarray, np.ndarray, np.ndarray]


def vendor_figures(dqt: Cloud, window: Cloud, reference_mm: float, focal_px: float | None = None,
                   baseline_mm: float | None = None) -> VendorFigures:
    """All vendor figures of one wall stack.

    ``dqt``: x, y, z (k, h, w) of the Depth Quality Tool's ROI in the frames
    to average (the tool shows one frame at a time; labctl gives it the first
    ``DQT_FRAMES``); ``window``: x, y, z (N, 40, 40) of Basler's
    centre window in every frame of the stack.

    Examples
    --------
    A flat wall at the reference distance 1000 mm, seen 1 mm nearer, at, and 1 mm farther in three frames.

    >>> y, x = np.mgrid[-2:2, -2:2].astype(float)
    >>> z = np.stack([np.full(x.shape, 1000.0 + k) for k in (0.0, -1.0, 1.0)])
    >>> xs, ys = np.broadcast_to(x, z.shape), np.broadcast_to(y, z.shape)
    >>> v = vendor_figures((xs[:1], ys[:1], z[:1]), (xs, ys, z), 1000.0)
    >>> v.fill_rate_pct, round(v.z_accuracy_pct, 6), round(v.spatial_precision_mm, 6), round(v.temporal_precision_mm, 6)
    (100.0, 0.0, 0.0, 1.0)
    """
    x, y, z = dqt
    frames = [dqt_frame(x[k], y[k], z[k], reference_mm, focal_px, baseline_mm) for k in range(len(z))]
    wx, wy, wz = window
    spatial = [spatial_precision_mm(wx[k], wy[k], wz[k]) for k in range(len(wz))]
    return VendorFigures(
        reference_mm=float(reference_mm),
        n_frames=len(wz),
        fill_rate_pct=_mean([f.fill_rate_pct for f in frames]),
        z_accuracy_pct=_mean([f.z_accuracy_pct for f in frames]),
        plane_fit_rms_mm=_mean([f.plane_fit_rms_mm for f in frames]),
        plane_fit_rms_pct=_mean([f.plane_fit_rms_pct for f in frames]),
        subpixel_rms_px=_mean([f.subpixel_rms_px for f in frames]),
        spatial_precision_mm=_mean(spatial),
        temporal_precision_mm=temporal_precision_mm(wz),
    )


@dataclass(frozen=True)
class VendorUncertainties:
    """Type A standard uncertainties (GUM 4.2) of the vendor figures of one wall stack, in their units: what the
    frames' noise leaves in them (the reference's share of Z accuracy is the caller's)."""

    fill_rate_pct: float
    z_accuracy_pct: float
    plane_fit_rms_mm: float
    subpixel_rms_px: float
    spatial_precision_mm: float
    temporal_precision_mm: float


def _spread_of_mean(values: list[float], k: int) -> float:
    """Standard uncertainty of the mean of ``k`` single-frame values whose spread over the frames is that of
    ``values``: s / sqrt(k) (GUM 4.2.2, 4.2.3); NaN with fewer than two finite values."""
    v = np.array([x for x in values if math.isfinite(x)])
    return float(np.std(v, ddof=1) / math.sqrt(k)) if v.size >= 2 else math.nan


def vendor_uncertainties(dqt: Cloud, window: Cloud, reference_mm: float, focal_px: float | None = None,
                         baseline_mm: float | None = None) -> VendorUncertainties:
    """Type A uncertainties of :func:`vendor_figures` of one wall stack.

    ``dqt``: x, y, z (N, h, w) of the Depth Quality Tool's ROI in every frame of the stack; ``window`` as for
    :func:`vendor_figures`. The Depth Quality Tool's figures are means over ``DQT_FRAMES`` frames: s / sqrt(k)
    with s their spread over the stack's frames taken singly (GUM 4.2.2, 4.2.3); spatial precision, a mean over
    all N frames: s / sqrt(N) (GUM 4.2.3); temporal precision, a pooled standard deviation: the jackknife over
    the frames (Efron & Tibshirani 1993, eq. 11.5).

    Examples
    --------
    A flat wall at 1000 mm seen at 1000 + 0.5 k mm in frames k = 0 .. 3: Z accuracy 0, 0.05, 0.1, 0.15 % (s =
    0.0645 %), every frame flat (spatial precision 0 throughout).

    >>> y, x = np.mgrid[-2:2, -2:2].astype(float)
    >>> z = np.stack([np.full(x.shape, 1000.0 + 0.5 * k) for k in range(4)])
    >>> xs, ys = np.broadcast_to(x, z.shape), np.broadcast_to(y, z.shape)
    >>> u = vendor_uncertainties((xs, ys, z), (xs, ys, z), 1000.0)
    >>> round(u.z_accuracy_pct, 4), u.fill_rate_pct, round(u.spatial_precision_mm, 6)
    (0.0645, 0.0, 0.0)
    """
    x, y, z = dqt
    frames = [dqt_frame(x[k], y[k], z[k], reference_mm, focal_px, baseline_mm) for k in range(len(z))]
    wx, wy, wz = window
    n = len(wz)
    (temporal,) = (jackknife_standard_errors(lambda kept: (temporal_precision_mm(wz[kept]),), n) if n >= 3
                   else (math.nan,))
    return VendorUncertainties(
        fill_rate_pct=_spread_of_mean([f.fill_rate_pct for f in frames], DQT_FRAMES),
        z_accuracy_pct=_spread_of_mean([f.z_accuracy_pct for f in frames], DQT_FRAMES),
        plane_fit_rms_mm=_spread_of_mean([f.plane_fit_rms_mm for f in frames], DQT_FRAMES),
        subpixel_rms_px=_spread_of_mean([f.subpixel_rms_px for f in frames], DQT_FRAMES),
        spatial_precision_mm=standard_error_of_mean(
            np.array([spatial_precision_mm(wx[k], wy[k], wz[k]) for k in range(n)])),
        temporal_precision_mm=temporal,
    )
