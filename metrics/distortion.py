"""Geometric distortion and pixel aspect ratio from a checkerboard (Thesis 2024, 5.2, 6.4).

Distortion is the displacement of a flat target's features from where an ideal
pinhole camera would image them (ISO 17850:2015, EBU Tech 3249-E). The target
is a checkerboard parallel to the sensor; its inner corners are the features.

* Pixel aspect ratio: angular pixel height / angular pixel width (Thesis
  2024, eq. 5-1, Table 6-2) and the distortion it causes, in % of the width (Table
  6-5 row 1).
* Corners: OpenCV's classic detector when the board's size is given (a board
  wholly in view); otherwise, or when it fails, the sector-based detector
  (NORMALIZE_IMAGE, EXHAUSTIVE, ACCURACY, LARGER). Its grid may skip rows or
  be sheared, so only a 2 x 2 block of single-tile steps near the image centre
  is taken from it. Every corner is refined by ``cornerSubPix`` with a
  half-window of 0.4 tile (below half a tile), and the grid is grown corner by
  corner to the image border: each new corner is predicted from its row or
  column, refined, and kept only as a saddle of the right colour parity. So a
  board cut by the image border or smaller than the view gives its largest
  grid, and blurred border corners are not lost (Thesis 2024, 6.4.2). Indices
  (i, j) count from the corner nearest the image centre.
* Expected grid (Thesis 2024, 5.2.1): centred on the corner nearest the image
  centre, spacing tile · f / distance with f_x = (W/2) / tan(FOV_h/2) and
  f_y = (H/2) / tan(FOV_v/2), the lateral pixel size at the image centre. The
  angular pixel size FOV/W would overstate the spacing by 13 % at 67 deg over
  640 px and report distortion for a perfect pinhole camera.
* Misplaced corners: a corner further from the fitted board (below) than
  6 robust standard deviations of all corners' misfit, and at least 1 px, is
  left out of every statistic and the fit is repeated (a corner next to a tile
  cut by the board's edge, refined off its true place; the EBU maximum would
  otherwise report it as distortion). The radial model absorbs smooth
  distortion, so real distortion is not left out.
* Raw distortion (EBU Tech 3249-E, ISO 17850, Thesis 2024, Table 6-5): max
  |found - expected| in % of the image width (x) and height (y), with the
  median so that noise at the border does not dominate.
* Linear and radial distortion separated (Thesis 2024, 6.4.2's open point): a least
  squares fit of board position, in-plane rotation, scale per axis (the
  effective FOV, cf. eq. 6-1) and k1 of eq. 5-5,
  r_d = r_u (1 + k1 (r_u / R)^2) about the image centre, R = half the image
  diagonal. The radial distortion is what remains of found - fitted linear
  grid.
* Point cloud (Thesis 2024, 5.2.1): the same corners' x, y read bilinearly at their
  sub-pixel positions against a grid of the tile size in mm centred on the
  centre corner, in % of the lateral extent of the view at the centre corner's
  depth, 2 z tan(FOV/2) with the given FOV: one pixel of displacement at the
  image centre is then the same percentage in the image and in the cloud, and
  the normalization depends neither on the cloud's own distortion nor on its
  outliers.

Signs follow EBU Tech 3249-E: a maximum displacement outwards (away from the
expected grid's centre corner; for the radial part, from the image centre) is
positive, pincushion; inwards negative, barrel.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np
from scipy import optimize

from metrics.optics import Pinhole, pixel_aspect_distortion_pct, sensor_angular_resolution_deg

__all__ = [
    "CloudDistortion", "Corners", "DistortionResult", "bilinear_samples", "cloud_distortion", "detect_corners",
    "distortion",
    "pixel_aspect_distortion_pct", "pixel_aspect_ratio", "refine_corners", "refined_distortion", "sample_cloud",
]

#: ``cornerSubPix`` stops when a corner moves by less than this (px) or after _SUBPIX_ITERATIONS iterations
SUBPIX_TOLERANCE_PX = 1e-4
_SUBPIX_ITERATIONS = 100
_SB_FLAGS = (cv2.CALIB_CB_NORMALIZE_IMAGE | cv2.CALIB_CB_EXHAUSTIVE | cv2.CALIB_CB_ACCURACY
             | cv2.CALIB_CB_LARGER)
_CLASSIC_FLAGS = cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE
#: a grown corner must refine to within this many tiles of its prediction
_GROW_TOLERANCE_TILES = 0.25
#: tile-centre samples of a grown corner: bright pair minus dark pair, relative to the image's range
_MIN_SADDLE_CONTRAST = 0.05
#: detector corners (nearest the image centre first) tried as the seed of the grid
_SEED_TRIES = 10
#: a corner further than this many robust sigmas (and OUTLIER_MIN_PX) from the fitted board is misplaced
OUTLIER_SIGMAS = 6.0
OUTLIER_MIN_PX = 1.0
#: fewer corners than this (or fewer than 3 per row / column) is no board
MIN_CORNERS = 9

Grid = dict[tuple[int, int], np.ndarray]


def pixel_aspect_ratio(fov_h_deg: float, fov_v_deg: float, width: int, height: int) -> float:
    """Angular pixel height / angular pixel width (Thesis 2024, eq. 5-1, Table 6-2 "1 : ratio").

    Examples
    --------
    >>> pixel_aspect_ratio(64.0, 60.0, 640, 480)  # (60 / 480) / (64 / 640) = 0.125 / 0.1
    1.25
    """
    return sensor_angular_resolution_deg(fov_v_deg, height) / sensor_angular_resolution_deg(fov_h_deg, width)


# ------------------------------------------------------------------------------------------ corners
@dataclass(frozen=True)
class Corners:
    """Inner corners of a checkerboard in an image.

    ``uv`` (N, 2): sub-pixel (u, v), pixel centres at integers (OpenCV).
    ``ij`` (N, 2): integer grid index, (0, 0) the corner nearest the image
    centre ((W-1)/2, (H-1)/2), i growing with u and j with v.
    ``tile_px``: median spacing of neighbouring corners along (u, v).
    """

    uv: np.ndarray
    ij: np.ndarray
    image_shape: tuple[int, int]
    detector: str
    tile_px: tuple[float, float]

    @property
    def centre_uv(self) -> np.ndarray:
        return self.uv[np.flatnonzero((self.ij == 0).all(axis=1))[0]]

    def subset(self, keep: np.ndarray) -> Corners:
        """The corners where ``keep`` is true.

        Examples
        --------
        >>> corners = Corners(np.array([[10.0, 10.0], [30.0, 10.0], [50.0, 10.0]]), np.array([[-1, 0], [0, 0], [1, 0]]),
        ...                   (20, 60), "given", (20.0, 20.0))
        >>> corners.subset(np.array([False, True, True])).ij.tolist()
        [[0, 0], [1, 0]]
        """
        return Corners(self.uv[keep], self.ij[keep], self.image_shape, self.detector, self.tile_px)


def _normalized(image: np.ndarray) -> np.ndarray:
    """The image scaled to 0..255 between its 0.5 % and 99.5 % quantiles (float32, clipped)."""
    lo, hi = np.percentile(image, [0.5, 99.5])
    return np.clip(255 * (image - lo) / (hi - lo if hi > lo else 1.0), 0, 255).astype(np.float32)


def _oriented(grid: np.ndarray) -> Grid:
    """(rows, cols, 2) corner array as {(i, j): uv} with i growing with u and j with v."""
    step_cols = np.nanmean(np.diff(grid, axis=1), axis=(0, 1))
    if abs(step_cols[0]) < abs(step_cols[1]):
        grid = grid.transpose(1, 0, 2)
    if np.nanmean(np.diff(grid, axis=1)[..., 0]) < 0:
        grid = grid[:, ::-1]
    if np.nanmean(np.diff(grid, axis=0)[..., 1]) < 0:
        grid = grid[::-1]
    return {(i, j): grid[j, i].astype(float) for j in range(grid.shape[0]) for i in range(grid.shape[1])}


def _classic(img8: np.ndarray, pattern: tuple[int, int]) -> Grid | None:
    found, corners = cv2.findChessboardCorners(img8, pattern, flags=_CLASSIC_FLAGS)
    if not found:
        return None
    return _oriented(corners.reshape(pattern[1], pattern[0], 2))


def _sector_based(img8: np.ndarray) -> Grid | None:
    found, corners, meta = cv2.findChessboardCornersSBWithMeta(img8, (3, 3), _SB_FLAGS)
    if not found:
        return None
    return _oriented(corners.reshape(meta.shape[0], meta.shape[1], 2))


def _half_window(tile_px: float) -> int:
    """cornerSubPix half-window: 0.4 tile, below half a tile, so no neighbouring corner or edge enters it."""
    return max(1, int(0.4 * tile_px))


def _inside(uv: np.ndarray, shape: tuple[int, int], margin: float) -> np.ndarray:
    u, v = np.asarray(uv, float).reshape(-1, 2).T
    return (u >= margin) & (v >= margin) & (u <= shape[1] - 1 - margin) & (v <= shape[0] - 1 - margin)


def _refine(image: np.ndarray, uv: np.ndarray, half: int, tolerance_px: float = SUBPIX_TOLERANCE_PX) -> np.ndarray:
    pts = np.ascontiguousarray(uv, dtype=np.float32).reshape(-1, 1, 2)
    criteria = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, _SUBPIX_ITERATIONS, tolerance_px)
    return cv2.cornerSubPix(image, pts, (half, half), (-1, -1), criteria).reshape(-1, 2).astype(float)


def _bilinear(image: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Bilinear samples of a 2-D float32 image at (N, 2) positions inside it."""
    uv = np.asarray(uv, np.float32).reshape(1, -1, 2)
    return cv2.remap(image, uv[..., 0], uv[..., 1], cv2.INTER_LINEAR).ravel()


def _saddle(image: np.ndarray, p: np.ndarray, a: np.ndarray, b: np.ndarray, min_contrast: float) -> int:
    """+1 if the tiles towards p ± (a+b) are brighter than those towards p ± (a-b), -1 if darker, 0 if neither.

    ``a``, ``b``: the local steps to the next corner along i and j. Samples
    lie 0.4 of the way to the tile centres, clear of blurred edges. Across a
    checkerboard the sign alternates with i + j.
    """
    q = np.array([p + 0.4 * (a + b), p - 0.4 * (a + b), p + 0.4 * (a - b), p - 0.4 * (a - b)])
    if not _inside(q, image.shape, 0.0).all():
        return 0
    s = _bilinear(image, q)
    if s[:2].min() - s[2:].max() > min_contrast:
        return 1
    if s[2:].min() - s[:2].max() > min_contrast:
        return -1
    return 0


def _is_x_corner(image: np.ndarray, p: np.ndarray, radius: float, min_contrast: float) -> bool:
    """A checkerboard corner seen on a ring: four alternating sectors, opposite sectors alike."""
    angles = np.arange(16) * (2 * math.pi / 16)
    ring = p + radius * np.column_stack([np.cos(angles), np.sin(angles)])
    if not _inside(ring, image.shape, 0.0).all():
        return False
    s = _bilinear(image, ring)
    span = s.max() - s.min()
    above = s > (s.max() + s.min()) / 2
    changes = np.count_nonzero(above != np.roll(above, 1))
    return span > min_contrast and changes == 4 and np.mean(np.abs(s - np.roll(s, 8))) < 0.3 * span


def _step(grid: Grid, k: tuple[int, int], axis: int) -> np.ndarray | None:
    """Local step to the next corner along ``axis`` (0: i, 1: j) at node ``k``."""
    e = (1, 0) if axis == 0 else (0, 1)
    for lo, hi in ((k, (k[0] + e[0], k[1] + e[1])), ((k[0] - e[0], k[1] - e[1]), k)):
        if lo in grid and hi in grid:
            return grid[hi] - grid[lo]
    return None


def _parities(image: np.ndarray, grid: Grid, min_contrast: float) -> list[int]:
    """Saddle sign times (-1)^(i+j) of every node with both steps: all equal on a true grid."""
    out = []
    for k, p in grid.items():
        a, b = _step(grid, k, 0), _step(grid, k, 1)
        if a is not None and b is not None:
            out.append(_saddle(image, p, a, b, min_contrast) * (-1) ** (k[0] + k[1]))
    return out


def _unit_steps(image: np.ndarray, grid: Grid, k0: tuple[int, int],
                min_contrast: float) -> tuple[np.ndarray, np.ndarray] | None:
    """Single-tile steps (along u, along v) at node ``k0``: the shortest of the integer combinations
    m a + n b (|m|, |n| <= 2) of the grid's steps there, and their fractions 1/2 ... 1/4, that land on a
    corner (a sheared grid, a = 2 tiles along u and b = 2 down and 1 left, has the vertical step (a + 2 b) / 4)."""
    p0 = grid[k0]
    a, b = _step(grid, k0, 0), _step(grid, k0, 1)
    if a is None or b is None:
        return None
    found = []
    combinations = [m * a + n * b for m in range(0, 3) for n in range(-2, 3) if (m, n) > (0, 0)]
    for v in combinations:
        for k in range(1, 5):
            step = v / k
            unit = float(np.linalg.norm(step))
            half = _half_window(unit)
            if unit < 3 or not _inside(p0 + step, image.shape, half + 1)[0]:
                continue
            p = _refine(image, p0 + step, half)[0]
            if np.linalg.norm(p - p0 - step) < _GROW_TOLERANCE_TILES * unit and _is_x_corner(
                    image, p, 0.35 * unit, min_contrast):
                found.append(p - p0)
    if not found:
        return None
    found.sort(key=lambda v: float(np.linalg.norm(v)))
    first = found[0]
    second = next((v for v in found if abs(float(v @ first)) < 0.5 * np.linalg.norm(v) * np.linalg.norm(first)),
                  None)
    if second is None:
        return None
    # Lagrange-Gauss reduction: a square board's two unit steps are a reduced basis (|a.b| <= |a|^2 / 2); a
    # sheared pair such as (a, a + 2 b) is not, and its second step reduces to a step the block check refuses
    second = second - round(float(second @ first) / float(first @ first)) * first
    a, b = (first, second) if abs(first[0]) > abs(first[1]) else (second, first)
    return a * np.sign(a[0]), b * np.sign(b[1])


def _seed(image: np.ndarray, grid: Grid, min_contrast: float) -> Grid | None:
    """A 2 x 2 block of corners with single-tile steps, at the detector's corner nearest the image centre
    that gives one.

    The sector-based detector's grid may skip rows or columns, be sheared
    (steps of (2, 1) tiles) or end in points on the board's edge; every
    corner of the block is therefore checked on a ring and for alternating
    colour parity.
    """
    centre = np.array([(image.shape[1] - 1) / 2, (image.shape[0] - 1) / 2])
    for k0 in sorted(grid, key=lambda k: float(np.linalg.norm(grid[k] - centre)))[:_SEED_TRIES]:
        steps = _unit_steps(image, grid, k0, min_contrast)
        if steps is None:
            continue
        a, b = steps
        unit = float(min(np.linalg.norm(a), np.linalg.norm(b)))
        half = _half_window(unit)
        p0 = grid[k0]
        block = {(0, 0): p0, (1, 0): p0 + a, (0, 1): p0 + b, (1, 1): p0 + a + b}
        if not _inside(np.array(list(block.values())), image.shape, half + 1).all():
            continue
        block = dict(zip(block, _refine(image, np.array(list(block.values())), half)))
        parities = _parities(image, block, min_contrast)
        if (all(_is_x_corner(image, p, 0.35 * unit, min_contrast) for p in block.values())
                and len(set(parities)) == 1 and parities[0] != 0):
            return block
    return None


def _grow(image: np.ndarray, grid: Grid, half: int, min_contrast: float) -> Grid:
    """Add corners beyond the grid's edges until none passes the checks (see module docstring)."""
    votes = [s for s in _parities(image, grid, min_contrast) if s]
    if not votes:
        return grid
    sign = 1 if sum(votes) > 0 else -1
    grid = dict(grid)
    fresh = set(grid)
    directions = ((1, 0), (-1, 0), (0, 1), (0, -1))
    while fresh:
        near = fresh | {(i + d[0], j + d[1]) for i, j in fresh for d in directions}
        candidates: dict[tuple[int, int], tuple[np.ndarray, np.ndarray, np.ndarray]] = {}
        for i, j in near & grid.keys():
            p0 = grid[(i, j)]
            for d in directions:
                new, back1, back2 = (i + d[0], j + d[1]), (i - d[0], j - d[1]), (i - 2 * d[0], j - 2 * d[1])
                across = _step(grid, (i, j), 1 if d[0] else 0)
                if new in grid or new in candidates or back1 not in grid or across is None:
                    continue
                p1 = grid[back1]
                pred = 3 * p0 - 3 * p1 + grid[back2] if back2 in grid else 2 * p0 - p1
                along = (p0 - p1) * (d[0] + d[1])
                candidates[new] = (pred, *((along, across) if d[0] else (across, along)))
        keys = [k for k, c in candidates.items() if _inside(c[0], image.shape, half + 1)[0]]
        fresh = set()
        if not keys:
            break
        for k, p in zip(keys, _refine(image, np.array([candidates[k][0] for k in keys]), half)):
            pred, a, b = candidates[k]
            tile = min(np.linalg.norm(a), np.linalg.norm(b))
            if (np.linalg.norm(p - pred) < _GROW_TOLERANCE_TILES * tile and _inside(p, image.shape, half + 1)[0]
                    and _saddle(image, p, a, b, min_contrast) == sign * (-1) ** (k[0] + k[1])):
                grid[k] = p
                fresh.add(k)
    return grid


def _median_spacing(uv: np.ndarray, ij: np.ndarray) -> tuple[float, float]:
    """Median spacing of neighbouring corners along i (in u) and along j (in v)."""
    index = {tuple(k): n for n, k in enumerate(ij.tolist())}
    du = [uv[n, 0] - uv[index[(i - 1, j)], 0] for (i, j), n in index.items() if (i - 1, j) in index]
    dv = [uv[n, 1] - uv[index[(i, j - 1)], 1] for (i, j), n in index.items() if (i, j - 1) in index]
    return float(np.median(du)), float(np.median(dv))


def detect_corners(image: np.ndarray, pattern: tuple[int, int] | None = None) -> Corners:
    """Inner checkerboard corners of an intensity image (Thesis 2024, 5.2.1, improved per 6.4.2).

    ``pattern`` = (columns, rows) of inner corners of a board wholly in view
    selects OpenCV's classic detector first; otherwise, or when it fails, the
    sector-based detector (NORMALIZE_IMAGE, EXHAUSTIVE, ACCURACY, LARGER)
    seeds the grid. Corners are refined with ``cornerSubPix`` (half-window
    below half a tile) and the grid is grown to the image border. NaN pixels
    count as dark. Raises ValueError when no board of at least
    ``MIN_CORNERS`` corners (three per row and column) is found.

    Examples
    --------
    A board of 20 px tiles, tile edges between pixels 19 and 20, 39 and 40, ...: 9 x 7 inner corners
    at 19.5, 39.5, ...; the one nearest the image centre is (99.5, 79.5).

    >>> v, u = np.mgrid[0:160, 0:200]
    >>> corners = detect_corners(((u // 20 + v // 20) % 2) * 200.0 + 20.0)
    >>> len(corners.uv), np.round(corners.centre_uv, 2).tolist(), np.round(corners.tile_px, 2).tolist()
    (63, [99.5, 79.5], [20.0, 20.0])
    """
    image = np.asarray(image, dtype=float)
    if image.ndim != 2:
        raise ValueError(f"intensity image must be 2-D, got shape {image.shape}")
    finite = np.isfinite(image)
    if not finite.any():
        raise ValueError("intensity image has no finite pixels")
    work = _normalized(np.where(finite, image, np.min(image[finite])))
    img8 = np.round(work).astype(np.uint8)
    min_contrast = _MIN_SADDLE_CONTRAST * 255
    grid, detector = (_classic(img8, pattern), "classic") if pattern else (None, "")
    if grid is None:
        grid, detector = _sector_based(img8), "sector-based"
        grid = _seed(work, grid, min_contrast) if grid is not None else None
    if grid is None:
        raise ValueError("no checkerboard found in the intensity image")
    ij = np.array(list(grid), dtype=int)
    half = _half_window(min(np.abs(_median_spacing(np.array(list(grid.values())), ij))))
    keys = [k for k in grid if _inside(grid[k], image.shape, half + 1)[0]]
    if keys:
        grid = dict(zip(keys, _refine(work, np.array([grid[k] for k in keys]), half)))
        grid = _grow(work, grid, half, min_contrast)
    ij = np.array(list(grid), dtype=int).reshape(-1, 2)
    uv = np.array(list(grid.values())).reshape(-1, 2)
    if len(uv) < MIN_CORNERS or min(np.ptp(ij[:, 0]), np.ptp(ij[:, 1])) < 2:
        raise ValueError("no checkerboard found in the intensity image")
    centre = np.array([(image.shape[1] - 1) / 2, (image.shape[0] - 1) / 2])
    ij = ij - ij[np.argmin(np.linalg.norm(uv - centre, axis=1))]
    return Corners(uv, ij, (image.shape[0], image.shape[1]), detector, _median_spacing(uv, ij))


def refine_corners(image: np.ndarray, corners: Corners, tolerance_px: float = SUBPIX_TOLERANCE_PX) -> np.ndarray:
    """The given corners refined again on another image of the same board (e.g. one frame of the stack whose
    mean they were found in): ``cornerSubPix`` from their positions, with the detector's normalization and
    half-window (below half a tile), until a corner moves by less than ``tolerance_px`` (the detector's by
    default). Returns (N, 2) positions; NaN where a corner moved by more than a quarter tile (refined onto
    another feature) or the image has no finite pixels.

    Examples
    --------
    The same board moved by 2 px right and 1 px down: every corner follows.

    >>> v, u = np.mgrid[0:160, 0:200]
    >>> corners = detect_corners(((u // 20 + v // 20) % 2) * 200.0 + 20.0)
    >>> moved = refine_corners((((u - 2) // 20 + (v - 1) // 20) % 2) * 200.0 + 20.0, corners)
    >>> np.round(moved - corners.uv, 2).max(axis=0).tolist(), np.round(moved - corners.uv, 2).min(axis=0).tolist()
    ([2.0, 1.0], [2.0, 1.0])
    """
    image = np.asarray(image, dtype=float)
    finite = np.isfinite(image)
    out = np.full(corners.uv.shape, np.nan)
    if not finite.any() or not len(corners.uv):
        return out
    work = _normalized(np.where(finite, image, np.min(image[finite])))
    tile = min(np.abs(corners.tile_px))
    half = _half_window(tile)
    inside = _inside(corners.uv, image.shape, half + 1)
    if inside.any():
        out[inside] = _refine(work, corners.uv[inside], half, tolerance_px)
    moved = ~(np.linalg.norm(out - corners.uv, axis=1) <= 0.25 * tile)
    out[moved] = np.nan
    return out


# --------------------------------------------------------------------------------------- distortion
@dataclass(frozen=True)
class DistortionResult:
    """Distortion of the intensity image (percentages of the image width w and height h).

    ``raw_*``: found - expected grid of the given FOV (EBU Tech 3249-E; Thesis
    2024, Table 6-5), signed max and median of |.|; ``radial_*``: found - fitted
    linear grid, the radial part; ``fov_estimate_deg``: effective [h, v] FOV
    from the fitted scale (cf. eq. 6-1); ``linear_scale``: fitted / expected
    corner spacing per axis; ``k1``: eq. 5-5 with R = half the image diagonal.
    Arrays (N, 2) in pixels, row n for corner ``ij[n]``, over the corners
    used (``corners``); ``rejected_uv`` (M, 2): corners left out as misplaced.
    """

    raw_distortion_w_pct: float
    raw_distortion_h_pct: float
    raw_median_w_pct: float
    raw_median_h_pct: float
    radial_distortion_w_pct: float
    radial_distortion_h_pct: float
    radial_median_w_pct: float
    radial_median_h_pct: float
    fov_estimate_deg: tuple[float, float]
    k1: float
    linear_scale: tuple[float, float]
    rotation_deg: float
    fit_rms_px: float
    n_corners: int
    ij: np.ndarray
    found: np.ndarray
    expected: np.ndarray
    fitted_linear: np.ndarray
    corners: Corners
    rejected_uv: np.ndarray
    warnings: tuple[str, ...]


def _signed_max_pct(dev: np.ndarray, outward: np.ndarray, length: float) -> tuple[float, float]:
    """(signed max, median) of |dev| in % of ``length``; positive when the largest lies outwards."""
    k = int(np.argmax(np.abs(dev)))
    sign = 1.0 if dev[k] * outward[k] >= 0 else -1.0
    return sign * 100.0 * abs(float(dev[k])) / length, 100.0 * float(np.median(np.abs(dev))) / length


def _model(params: np.ndarray, ij: np.ndarray, centre: np.ndarray, big_r: float,
           radial: bool = True) -> np.ndarray:
    """Corner positions of a board at offset (a, b), scale (sx, sy) px per tile, rotation t, radial k1."""
    a, b, sx, sy, t, k1 = params
    c, s = math.cos(t), math.sin(t)
    du = a + sx * (c * ij[:, 0] - s * ij[:, 1])
    dv = b + sy * (s * ij[:, 0] + c * ij[:, 1])
    scale = 1.0 + k1 * (du**2 + dv**2) / big_r**2 if radial else 1.0
    return centre + np.column_stack([du * scale, dv * scale])


def _fit(found: np.ndarray, ij: np.ndarray, centre: np.ndarray, big_r: float,
         spacing: tuple[float, float]) -> np.ndarray:
    """Least squares (soft-L1 beyond 1 px, so a few bad corners do not pull the fit)."""
    origin = found[np.flatnonzero((ij == 0).all(axis=1))[0]] - centre
    start = np.array([origin[0], origin[1], spacing[0], spacing[1], 0.0, 0.0])

    def residual(p: np.ndarray) -> np.ndarray:
        return (_model(p, ij, centre, big_r) - found).ravel()

    return optimize.least_squares(residual, start, loss="soft_l1", f_scale=1.0, x_scale="jac").x


def distortion(corners: Corners, tile_mm: float, distance_mm: float,
               fov_deg: tuple[float, float]) -> DistortionResult:
    """Distortion of the intensity image from its checkerboard corners (Thesis 2024, 5.2, 5.2.1, 6.4).

    ``distance_mm``: camera - board distance; ``fov_deg``: the given
    (datasheet) [h, v] field of view. The principal point and the centre of
    radial distortion are taken at the image centre ((W-1)/2, (H-1)/2).

    Examples
    --------
    A pinhole camera of 90 x 90 deg over 480 x 480 px (f = 240 px) sees 50 mm tiles 1000 mm away
    12 px apart; with radial distortion k1 = 0.1 (R^2 = 115200 px^2) the outermost corner, 60 px
    out in u and v, moves out by 60 x 0.1 x 7200 / 115200 = 0.375 px: 0.078 % of the width.

    >>> ij = np.array([(i, j) for j in range(-5, 6) for i in range(-5, 6)])
    >>> ideal = 12.0 * ij
    >>> found = 239.5 + ideal * (1.0 + 0.1 * np.sum(ideal**2, axis=1, keepdims=True) / 115200.0)
    >>> result = distortion(Corners(found, ij, (480, 480), "given", (12.0, 12.0)), 50.0, 1000.0, (90.0, 90.0))
    >>> round(result.k1, 6), round(result.radial_distortion_w_pct, 3), [round(f, 3) for f in result.fov_estimate_deg]
    (0.1, 0.078, [90.0, 90.0])
    """
    if tile_mm <= 0 or distance_mm <= 0:
        raise ValueError("tile size and distance must be positive")
    if not all(0 < f < 180 for f in fov_deg):
        raise ValueError(f"FOV must lie in (0, 180) deg, got {list(fov_deg)}")
    height, width = corners.image_shape
    pin = Pinhole(width, height, *fov_deg)
    spacing = (tile_mm * pin.fx / distance_mm, tile_mm * pin.fy / distance_mm)
    centre = np.array([pin.cx, pin.cy])
    big_r = math.hypot(width, height) / 2
    params = _fit(corners.uv, corners.ij, centre, big_r, spacing)
    miss = np.linalg.norm(_model(params, corners.ij, centre, big_r) - corners.uv, axis=1)
    keep = (miss <= max(OUTLIER_MIN_PX, OUTLIER_SIGMAS * 1.4826 * float(np.median(miss)))) | (corners.ij == 0).all(axis=1)
    rejected = corners.uv[~keep]
    if not keep.all():
        corners = corners.subset(keep)
        params = _fit(corners.uv, corners.ij, centre, big_r, spacing)
    found, ij = corners.uv, corners.ij
    origin = corners.centre_uv
    expected = origin + ij * np.array(spacing)
    raw = found - expected
    raw_w = _signed_max_pct(raw[:, 0], expected[:, 0] - origin[0], width)
    raw_h = _signed_max_pct(raw[:, 1], expected[:, 1] - origin[1], height)

    linear = _model(params, ij, centre, big_r, radial=False)
    radial = found - linear
    rad_w = _signed_max_pct(radial[:, 0], linear[:, 0] - centre[0], width)
    rad_h = _signed_max_pct(radial[:, 1], linear[:, 1] - centre[1], height)
    rms = float(np.sqrt(np.mean(np.sum((_model(params, ij, centre, big_r) - found) ** 2, axis=1))))
    sx, sy = abs(params[2]), abs(params[3])
    fov = (2 * math.degrees(math.atan(width / 2 / (sx * distance_mm / tile_mm))),
           2 * math.degrees(math.atan(height / 2 / (sy * distance_mm / tile_mm))))

    warnings = []
    if len(rejected):
        warnings.append(f"{len(rejected)} corner(s) left out as misplaced: more than "
                        f"{max(OUTLIER_MIN_PX, OUTLIER_SIGMAS * 1.4826 * float(np.median(miss))):.2f} px off the fitted "
                        "board (a partial tile next to them, or a false corner)")
    extent = (np.ptp(found[:, 0]) / width, np.ptp(found[:, 1]) / height)
    if min(extent) < 0.8:
        warnings.append(f"corners cover only {100 * extent[0]:.0f} % x {100 * extent[1]:.0f} % of the image; "
                        "the distortion at its border is not measured")
    if rms > 0.5:
        warnings.append(f"residual of the radial model is {rms:.2f} px rms: tilted board, tangential "
                        "distortion or misplaced corners")
    if max(abs(fov[0] - fov_deg[0]), abs(fov[1] - fov_deg[1])) > 1.0:
        warnings.append(f"the corners imply a FOV of {fov[0]:.1f} x {fov[1]:.1f} deg, not the given "
                        f"{fov_deg[0]:g} x {fov_deg[1]:g} deg (or the distance is off)")
    return DistortionResult(
        raw_distortion_w_pct=raw_w[0], raw_distortion_h_pct=raw_h[0],
        raw_median_w_pct=raw_w[1], raw_median_h_pct=raw_h[1],
        radial_distortion_w_pct=rad_w[0], radial_distortion_h_pct=rad_h[0],
        radial_median_w_pct=rad_w[1], radial_median_h_pct=rad_h[1],
        fov_estimate_deg=fov, k1=float(params[5]), linear_scale=(sx / spacing[0], sy / spacing[1]),
        rotation_deg=math.degrees(params[4]), fit_rms_px=rms, n_corners=len(found), ij=ij,
        found=found, expected=expected, fitted_linear=linear, corners=corners, rejected_uv=rejected,
        warnings=tuple(warnings),
    )


def refined_distortion(image: np.ndarray, corners: Corners, tile_mm: float, distance_mm: float,
                       fov_deg: tuple[float, float], tolerance_px: float = SUBPIX_TOLERANCE_PX) -> DistortionResult:
    """:func:`distortion` of ``corners`` refined again on ``image``, another image of the same board (e.g. the
    stack mean without some of its frames, a jackknife replicate of the mean the corners were found in):
    :func:`refine_corners` (``tolerance_px``), the corners that do not refine (NaN) left out. Raises ValueError
    when the centre corner is among them or fewer than ``MIN_CORNERS`` remain.

    Examples
    --------
    The board of :func:`detect_corners`'s example moved by 2 px right: every corner follows, no distortion.

    >>> v, u = np.mgrid[0:160, 0:200]
    >>> corners = detect_corners(((u // 20 + v // 20) % 2) * 200.0 + 20.0)
    >>> moved = refined_distortion((((u - 2) // 20 + v // 20) % 2) * 200.0 + 20.0, corners, 50.0, 1000.0, (90.0, 90.0))
    >>> moved.n_corners, np.round(moved.found - corners.uv, 3).max(axis=0).tolist(), abs(moved.radial_distortion_w_pct) < 1e-4
    (63, [2.0, 0.0], True)
    """
    uv = refine_corners(image, corners, tolerance_px)
    ok = np.isfinite(uv).all(axis=1)
    if not ok[(corners.ij == 0).all(axis=1)].all() or np.count_nonzero(ok) < MIN_CORNERS:
        raise ValueError(f"{np.count_nonzero(~ok)} of {len(ok)} corners do not refine on the image, the centre "
                         "corner among them or too many")
    return distortion(Corners(uv[ok], corners.ij[ok], corners.image_shape, corners.detector, corners.tile_px),
                      tile_mm, distance_mm, fov_deg)


# -------------------------------------------------------------------------------------- point cloud
def sample_cloud(cloud: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Bilinear (N, 3) samples of an organized (H, W, 3) cloud at sub-pixel (u, v) (not rounded, cf.
    Thesis 2024, 5.2.2); NaN where one of the four neighbouring points is invalid (any NaN) or outside.

    Examples
    --------
    A cloud with x = u, y = v is sampled exactly between pixels; a sample touching an invalid point is NaN.

    >>> v, u = np.mgrid[0:4, 0:4].astype(float)
    >>> cloud = np.dstack([u, v, np.full(u.shape, 1000.0)])
    >>> cloud[3, 3] = np.nan
    >>> sample_cloud(cloud, np.array([[1.25, 0.5], [2.5, 2.5]])).tolist()
    [[1.25, 0.5, 1000.0], [nan, nan, nan]]
    """
    out = bilinear_samples(cloud, uv)
    out[~np.isfinite(out).all(axis=1)] = np.nan
    return out


def bilinear_samples(values: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Bilinear (N, ...) samples of (H, W, ...) ``values`` at sub-pixel (u, v), each trailing element on its own:
    NaN where that element is invalid (NaN) at one of the four neighbouring pixels, or the sample lies outside.

    Examples
    --------
    Two frames of a 3 x 3 image as its trailing axis, the second with an invalid pixel next to the sample.

    >>> v, u = np.mgrid[0:3, 0:3].astype(float)
    >>> frames = np.dstack([u, np.where((u == 1) & (v == 1), np.nan, v)])
    >>> bilinear_samples(frames, np.array([[0.5, 0.25]])).tolist()
    [[0.5, nan]]
    """
    values = np.asarray(values)
    uv = np.asarray(uv, dtype=float).reshape(-1, 2)
    h, w = values.shape[:2]
    u0, v0 = np.floor(uv[:, 0]).astype(int), np.floor(uv[:, 1]).astype(int)
    u0, v0 = np.where(u0 == w - 1, w - 2, u0), np.where(v0 == h - 1, h - 2, v0)  # the last row / column
    ok = (u0 >= 0) & (v0 >= 0) & (u0 + 1 <= w - 1) & (v0 + 1 <= h - 1) & np.isfinite(uv).all(axis=1)
    ok &= (uv[:, 0] <= w - 1) & (uv[:, 1] <= h - 1)
    u0, v0 = np.where(ok, u0, 0), np.where(ok, v0, 0)
    # only the four neighbours of each sample are read (not the whole array converted and masked)
    p00, p01, p10, p11 = (np.asarray(values[v, u], dtype=float)
                          for v, u in ((v0, u0), (v0, u0 + 1), (v0 + 1, u0), (v0 + 1, u0 + 1)))
    trailing = (slice(None),) + (None,) * (values.ndim - 2)
    fu, fv = (uv[:, 0] - u0)[trailing], (uv[:, 1] - v0)[trailing]
    out = (1 - fu) * (1 - fv) * p00 + fu * (1 - fv) * p01 + (1 - fu) * fv * p10 + fu * fv * p11
    out[~ok] = np.nan
    return out


@dataclass(frozen=True)
class CloudDistortion:
    """Distortion of the point cloud at the checkerboard corners (Thesis 2024, 5.2.1, Table 6-5 row 3).

    ``distortion_*_pct``: signed max |found - expected| in % of ``extent_mm``
    (the lateral extent of the view at the centre corner's depth,
    2 z tan(FOV/2)); ``median_*_pct`` the median of |.|. Arrays (M, 2) in mm
    for the M corners valid in the cloud, row n for corner ``ij[n]``.
    """

    distortion_w_pct: float
    distortion_h_pct: float
    median_w_pct: float
    median_h_pct: float
    extent_mm: tuple[float, float]
    centre_z_mm: float
    n_corners: int
    ij: np.ndarray
    found: np.ndarray
    expected: np.ndarray
    warnings: tuple[str, ...]


def cloud_distortion(cloud: np.ndarray, corners: Corners, tile_mm: float,
                     fov_deg: tuple[float, float]) -> CloudDistortion:
    """Distortion of an organized (H, W, 3) cloud in mm (NaN invalid) at the image's corners.

    The expected grid has the tile size in mm and is centred on the valid
    corner nearest the image centre; its axes follow the cloud's (x along i,
    y along j, each with the sign the cloud shows).

    Examples
    --------
    The corners of an undistorted 12 px grid (f = 240 px, 50 mm tiles at 1000 mm) on a cloud 1 % too
    large: the corner 5 tiles out lies 2.5 mm out, 0.125 % of the 2000 mm view (2 x 1000 x tan 45 deg).

    >>> ij = np.array([(i, j) for j in range(-5, 6) for i in range(-5, 6)])
    >>> corners = Corners(239.5 + 12.0 * ij, ij, (480, 480), "given", (12.0, 12.0))
    >>> v, u = np.mgrid[0:480, 0:480].astype(float)
    >>> cloud = np.dstack([1.01 * (u - 239.5) * 1000.0 / 240.0, 1.01 * (v - 239.5) * 1000.0 / 240.0, np.full(u.shape, 1000.0)])
    >>> result = cloud_distortion(cloud, corners, 50.0, (90.0, 90.0))
    >>> round(result.distortion_w_pct, 6), round(result.distortion_h_pct, 6), [round(e, 6) for e in result.extent_mm]
    (0.125, 0.125, [2000.0, 2000.0])
    """
    cloud = np.asarray(cloud, dtype=float)
    if cloud.ndim != 3 or cloud.shape[2] != 3 or cloud.shape[:2] != corners.image_shape:
        raise ValueError(f"cloud must be H x W x 3 = {corners.image_shape[0]} x {corners.image_shape[1]} x 3, "
                         f"got shape {cloud.shape}")
    xyz = sample_cloud(cloud, corners.uv)
    ok = np.isfinite(xyz).all(axis=1)
    if np.count_nonzero(ok) < MIN_CORNERS:
        raise ValueError(f"only {np.count_nonzero(ok)} corners have valid cloud points")
    xyz, ij, uv = xyz[ok], corners.ij[ok], corners.uv[ok]
    centre = np.array([(corners.image_shape[1] - 1) / 2, (corners.image_shape[0] - 1) / 2])
    o = int(np.argmin(np.linalg.norm(uv - centre, axis=1)))
    rel = ij - ij[o]
    signs = np.array([_axis_sign(xyz[:, 0], rel[:, 0]), _axis_sign(xyz[:, 1], rel[:, 1])])
    expected = xyz[o, :2] + rel * signs * tile_mm
    dev = xyz[:, :2] - expected
    z = float(xyz[o, 2])
    extent = (2 * z * math.tan(math.radians(fov_deg[0]) / 2), 2 * z * math.tan(math.radians(fov_deg[1]) / 2))
    w = _signed_max_pct(dev[:, 0], expected[:, 0] - xyz[o, 0], extent[0])
    h = _signed_max_pct(dev[:, 1], expected[:, 1] - xyz[o, 1], extent[1])
    warnings = []
    if not ok.all():
        warnings.append(f"{np.count_nonzero(~ok)} of {len(ok)} corners have no valid cloud point")
    return CloudDistortion(w[0], h[0], w[1], h[1], extent, z, len(xyz), ij, xyz[:, :2], expected, tuple(warnings))


def _axis_sign(coord: np.ndarray, index: np.ndarray) -> float:
    """+1 if the cloud coordinate grows with the grid index, -1 if it falls."""
    slope = np.polyfit(index, coord, 1)[0] if np.ptp(index) > 0 else 1.0
    return 1.0 if slope >= 0 else -1.0
