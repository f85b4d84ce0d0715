"""Measurement error in x and y (Thesis 2024, 5.3, 6.4 Table 6-6, 5.3; ISO 5725-2 terms).

Systematic error on the checkerboard (the distortion target, Thesis 2024, 5.3):
the corners found in the intensity image are read bilinearly at their
sub-pixel positions from the cloud, and the spacing of neighbouring corners is
compared to the tile size,

    e_x = |x(i+1, j) - x(i, j)| - tile,   e_y = |y(i, j+1) - y(i, j)| - tile,

so a scale error of the cloud shows directly, and the board's position does
not matter. Trueness uses the cloud of the stack mean, accuracy a single
frame; each reports the 90 % quantile of |e| and the signed median (Thesis
2024, Table 6-6).

Statistical error on the white wall (Thesis 2024, 5.3, Fig. 5-12): the per-pixel
standard deviation of x and y over a stack; repeatability is the centre
pixel's (the caller takes the maximum over the distance sweep), precision the
90 % quantile over the valid pixels (reported at 2000 mm).

The centre pixel sits on the principal point, where x = y = 0 whatever the
depth noise (x = z (u - cx) / fx): its std of x and y only shows lateral
jitter. The off-axis repeatability is therefore taken where the coordinate
carries the depth noise too: the std of x at the pixel halfway from the centre
to the right edge on the centre row (row H // 2, column W // 2 + W // 4), the
std of y halfway to the bottom edge on the centre column (row H // 2 + H // 4,
column W // 2). There |x| / z = tan(about a quarter of the FOV), so a depth
noise sigma_z adds about sigma_z |x| / z to the std of x.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from metrics.depth import center_pixel, median_q90_abs, precision_q90_uncertainty, quantile_abs
from metrics.distortion import Corners, sample_cloud
from metrics.stack import StackStats, stack_stats
from metrics.uncertainty import sensitivity, standard_error_of_std

#: step (mm) of the tile size for the Q90s' numerical sensitivity to it (:func:`tile_sensitivity`)
TILE_STEP_MM = 0.01


@dataclass(frozen=True)
class SpacingErrors:
    """Neighbour-spacing errors e_x, e_y in mm (see module docstring) and their summary."""

    x_q90_mm: float
    x_median_mm: float
    y_q90_mm: float
    y_median_mm: float
    x_errors: np.ndarray
    y_errors: np.ndarray


@dataclass(frozen=True)
class XYErrors:
    """Trueness (stack mean) and accuracy (one frame) of x and y on the checkerboard."""

    trueness: SpacingErrors
    accuracy: SpacingErrors


@dataclass(frozen=True)
class XYPrecision:
    """Per-pixel std of x and y over a wall stack: centre pixel, median and Q90 over valid pixels."""

    repeatability_center_x_mm: float
    repeatability_center_y_mm: float
    repeatability_off_axis_x_mm: float
    repeatability_off_axis_y_mm: float
    #: mean x and y at the pixels of the repeatabilities (centre and off-axis), to judge what they measure
    center_xy_mm: tuple[float, float]
    off_axis_xy_mm: tuple[float, float]
    precision_median_x_mm: float
    precision_median_y_mm: float
    precision_q90_x_mm: float
    precision_q90_y_mm: float
    invalid_fraction: float
    #: Type A standard uncertainties (x, y) of the repeatabilities: s / sqrt(2 (n - 1)) of a pixel's sample std
    #: over its n valid frames (GUM E.4.3)
    repeatability_center_u_mm: tuple[float, float] = (float("nan"), float("nan"))
    repeatability_off_axis_u_mm: tuple[float, float] = (float("nan"), float("nan"))
    #: Type A standard uncertainties (x, y) of the precision Q90s (metrics.depth.precision_q90_uncertainty), NaN
    #: where not evaluated (the caller asks for them where they become key figures)
    precision_q90_u_mm: tuple[float, float] = (float("nan"), float("nan"))


def _summary(errors: np.ndarray) -> tuple[float, float]:
    q90 = median_q90_abs(errors, (0.9,))[0]
    return q90, float(np.median(errors)) if errors.size else float("nan")


def neighbour_pairs(corners: Corners) -> tuple[np.ndarray, np.ndarray]:
    """(P, 2) indices into the corners of the neighbours along the board's i axis (x) and along its j axis (y).

    Examples
    --------
    >>> ij = np.array([(0, 0), (1, 0), (0, 1)])
    >>> pairs_x, pairs_y = neighbour_pairs(Corners(np.zeros((3, 2)), ij, (4, 4), "given", (1.0, 1.0)))
    >>> pairs_x.tolist(), pairs_y.tolist()
    ([[0, 1]], [[0, 2]])
    """
    index = {(int(i), int(j)): n for n, (i, j) in enumerate(corners.ij)}
    pairs_x = np.array([(n, index[(i + 1, j)]) for (i, j), n in index.items() if (i + 1, j) in index]).reshape(-1, 2)
    pairs_y = np.array([(n, index[(i, j + 1)]) for (i, j), n in index.items() if (i, j + 1) in index]).reshape(-1, 2)
    return pairs_x.astype(int), pairs_y.astype(int)


def spacing_errors(cloud: np.ndarray, corners: Corners, tile_mm: float) -> SpacingErrors:
    """e_x, e_y of every pair of neighbouring corners valid in an organized (H, W, 3) cloud (mm, NaN invalid).

    Examples
    --------
    A cloud of 2 mm per pixel and corners 4 px apart: neighbours lie 8 mm apart, 0.5 mm more than a
    7.5 mm tile.

    >>> v, u = np.mgrid[0:12, 0:12].astype(float)
    >>> cloud = np.dstack([2.0 * u, 2.0 * v, np.full(u.shape, 1000.0)])
    >>> ij = np.array([(i, j) for j in range(3) for i in range(3)])
    >>> corners = Corners(2.0 + 4.0 * ij, ij - 1, (12, 12), "given", (4.0, 4.0))
    >>> e = spacing_errors(cloud, corners, tile_mm=7.5)
    >>> round(e.x_median_mm, 6), round(e.y_median_mm, 6), len(e.x_errors), len(e.y_errors)
    (0.5, 0.5, 6, 6)
    """
    cloud = np.asarray(cloud, dtype=float)
    if cloud.ndim != 3 or cloud.shape[2] != 3 or cloud.shape[:2] != corners.image_shape:
        raise ValueError(f"cloud must be H x W x 3 = {corners.image_shape[0]} x {corners.image_shape[1]} x 3, "
                         f"got shape {cloud.shape}")
    xyz = sample_cloud(cloud, corners.uv)
    pairs_x, pairs_y = neighbour_pairs(corners)
    ex = np.abs(xyz[pairs_x[:, 1], 0] - xyz[pairs_x[:, 0], 0]) - tile_mm
    ey = np.abs(xyz[pairs_y[:, 1], 1] - xyz[pairs_y[:, 0], 1]) - tile_mm
    ex, ey = ex[np.isfinite(ex)], ey[np.isfinite(ey)]
    (xq, xm), (yq, ym) = _summary(ex), _summary(ey)
    return SpacingErrors(xq, xm, yq, ym, ex, ey)


def xy_errors(mean_cloud: np.ndarray, frame_cloud: np.ndarray, corners: Corners, tile_mm: float) -> XYErrors:
    """Trueness from the stack-mean cloud, accuracy from one frame's cloud, at the same corners
    (found in the stack-mean intensity image).

    Examples
    --------
    The stack mean at the right scale (8 mm between corners 4 px apart), one frame 1 % too large.

    >>> v, u = np.mgrid[0:12, 0:12].astype(float)
    >>> mean = np.dstack([2.0 * u, 2.0 * v, np.full(u.shape, 1000.0)])
    >>> frame = mean * np.array([1.01, 1.01, 1.0])
    >>> ij = np.array([(i, j) for j in range(3) for i in range(3)])
    >>> corners = Corners(2.0 + 4.0 * ij, ij - 1, (12, 12), "given", (4.0, 4.0))
    >>> errors = xy_errors(mean, frame, corners, tile_mm=8.0)
    >>> round(errors.trueness.x_median_mm, 6), round(errors.accuracy.x_median_mm, 6)
    (0.0, 0.08)
    """
    return XYErrors(spacing_errors(mean_cloud, corners, tile_mm), spacing_errors(frame_cloud, corners, tile_mm))


def single_frame_q90_spread(x_at_corners: np.ndarray, y_at_corners: np.ndarray, corners: Corners,
                            tile_mm: float) -> tuple[float, float]:
    """Type A standard uncertainties of the x and y accuracy Q90 (one frame's spacing errors): the experimental
    standard deviation of the figure over the N frames, each taken as the single frame (GUM 4.2.2), as for the
    depth accuracy Q90. ``x_at_corners``, ``y_at_corners``: (N, M) x and y of every frame at the M ``corners``
    (``metrics.distortion.bilinear_samples`` of the stacks); NaN with fewer than two frames giving a figure.

    Examples
    --------
    Three frames of a board 10 % too large, 20 % too large, exact (corners 1 px apart, 1 mm tiles): the
    frames' x accuracy Q90 are 0.1, 0.2 and 0 mm, std 0.1 mm; y is exact in every frame.

    >>> ij = np.array([(i, j) for j in range(3) for i in range(3)], dtype=float)
    >>> corners = Corners(ij, ij.astype(int), (3, 3), "given", (1.0, 1.0))
    >>> scale = np.array([1.1, 1.2, 1.0])[:, None]
    >>> [round(u, 6) for u in single_frame_q90_spread(scale * ij[:, 0], np.ones((3, 1)) * ij[:, 1], corners, 1.0)]
    [0.1, 0.0]
    """
    pairs_x, pairs_y = neighbour_pairs(corners)
    out = []
    for values, pairs in ((x_at_corners, pairs_x), (y_at_corners, pairs_y)):
        errors = np.abs(np.abs(values[:, pairs[:, 1]] - values[:, pairs[:, 0]]) - tile_mm)
        q90 = np.array([quantile_abs(frame, 0.9) for frame in errors])
        q90 = q90[np.isfinite(q90)]
        out.append(float(np.std(q90, ddof=1)) if q90.size >= 2 else math.nan)
    return out[0], out[1]


def tile_sensitivity(errors: np.ndarray) -> float:
    """Sensitivity coefficient of the Q90 of |``errors``| (spacing errors |spacing| - tile) to the tile size, by
    central differences of ``TILE_STEP_MM`` (GUM 5.1.3): -1 where every error has one sign and the spacings are
    short or long alike, less in magnitude where the errors lie on both sides of 0.

    Examples
    --------
    >>> round(tile_sensitivity(np.array([0.2, 0.3, 0.4])), 6), round(tile_sensitivity(np.array([-0.3, 0.3])), 6)
    (-1.0, 0.0)
    """
    return sensitivity(lambda tile_change: quantile_abs(errors - tile_change, 0.9), 0.0, TILE_STEP_MM)


def off_axis_pixels(shape: tuple[int, int]) -> tuple[tuple[int, int], tuple[int, int]]:
    """(row, column) of the x and the y off-axis repeatability pixels (see the module docstring).

    Examples
    --------
    >>> off_axis_pixels((480, 640))  # halfway to the right edge, halfway to the bottom edge
    ((240, 480), (360, 320))
    """
    row, col = center_pixel(shape)
    return (row, col + shape[1] // 4), (row + shape[0] // 4, col)


def xy_precision(x_stack: np.ndarray, y_stack: np.ndarray, q90_uncertainty: bool = False,
                 stats: tuple[StackStats, StackStats] | None = None) -> XYPrecision:
    """Repeatability (centre and off-axis pixels) and precision (median, Q90) of x and y over an (N, H, W)
    wall stack, with the repeatabilities' uncertainties; with ``q90_uncertainty`` the precision Q90s' too (a
    jackknife over the frames: time enough only for the steps whose figures become key figures). ``stats``: the
    two stacks' :func:`~metrics.stack.stack_stats` where the caller has them already.

    Examples
    --------
    x seen as x - 1, x, x + 1 and y as y - 2, y, y + 2 at every pixel: std 1 mm and 2 mm.

    >>> y, x = np.mgrid[-2:2, -2:2].astype(float)
    >>> k = np.array([-1.0, 0.0, 1.0])[:, None, None]
    >>> p = xy_precision(x + k, y + 2.0 * k)
    >>> p.precision_median_x_mm, p.precision_median_y_mm, p.repeatability_center_x_mm, p.invalid_fraction
    (1.0, 2.0, 1.0, 0.0)
    >>> [round(u, 3) for u in p.repeatability_center_u_mm]  # s / sqrt(2 (3 - 1)): 1 / 2 and 2 / 2
    [0.5, 1.0]
    """
    sx, sy = stats if stats is not None else (stack_stats(np.asarray(x_stack)), stack_stats(np.asarray(y_stack)))
    centre = center_pixel(sx.std.shape)
    at_x, at_y = off_axis_pixels(sx.std.shape)
    mx, qx = median_q90_abs(sx.std)
    my, qy = median_q90_abs(sy.std)
    invalid = float(np.mean(~(sx.valid & sy.valid)))
    def u(s: StackStats, pixel: tuple[int, int]) -> float:
        return standard_error_of_std(float(s.std[pixel]), int(s.count[pixel])) if s.valid[pixel] else math.nan

    return XYPrecision(float(sx.std[centre]), float(sy.std[centre]), float(sx.std[at_x]), float(sy.std[at_y]),
                       (float(sx.mean[centre]), float(sy.mean[centre])), (float(sx.mean[at_x]), float(sy.mean[at_y])),
                       mx, my, qx, qy, invalid, (u(sx, centre), u(sy, centre)), (u(sx, at_x), u(sy, at_y)),
                       (precision_q90_uncertainty(np.asarray(x_stack), sx), precision_q90_uncertainty(np.asarray(y_stack), sy))
                       if q90_uncertainty else (math.nan, math.nan))
