"""Automated Böhler-star resolution of an organized point cloud (Thesis 2024, 5.1.3, 6.3.2, eq. 5-4).

The star (N wedges, every other one filled, 400 mm across) stands in front of
the wall; the cloud is usually the stack mean. Steps (Thesis 2024, 5.1.3):

1. the star plane is the nearest large planar region facing the camera
   (sequential RANSAC: the wall behind the star is usually the largest plane);
   the centre is the centroid of the star's rotationally symmetric inlier
   region, found by an area-weighted windowed centroid that starts where the
   optical axis meets the plane (the image centre) and moves to the star,
   then refined to the point about which the filled segments are most
   N/2-fold symmetric (exact also when the image border cuts the rim);
2. inliers: points within +-``inlier_mm`` of the plane;
3. polar coordinates in the plane. Every valid point is projected along its
   own ray onto the plane, so the wall seen through a slot lands in that slot
   (Thesis 2024, 5.1.3: "points lying in the slots ... might have larger x- and
   y-coordinates") and counts as a sample of its ring, and depth noise does
   not move points sideways;
4. rings of ``ring_mm`` (1 mm) binned by ``binning`` (2) into 2 mm rings;
5. per ring the inliers are sorted by angle and split into clusters where two
   neighbours are more than half a segment's angle apart; the cluster running
   across 0/2 pi is one cluster (Thesis 2024 counted it twice, 6.3.3);
6. a ring is resolved in an orientation when its inlier clusters in that
   orientation's sectors number exactly the filled segments there, and the
   ring holds at least 2 samples per segment there (sparse rings fall apart
   into too many clusters, 6.3.3). Horizontal sectors span +-45 deg around
   0 and 180 deg, vertical ones around 90 and 270 deg; the four sector
   boundaries are moved (by at most one segment) to the nearest slot centre,
   so that no filled segment is cut in two by a boundary. Counting only whole
   segments, a resolved ring has N/2 clusters per full circle, N/4 in the two
   horizontal (or vertical) sectors when N is a multiple of 8;
7. the resolution radius r is the inner edge of the innermost ring from which
   every larger ring (out to just inside the star's rim) is resolved; lateral
   resolution = 2 pi r / N (eq. 5-4), angular = atan(lateral / distance) with
   the camera-to-centre distance.

A result finer than the sensor can sample is not credible (Thesis 2024, 5.1.3 on
Song 2021): the lateral resolution is clamped to the sensor resolution at the
star -- the measured point spacing on the star and, when FOV and pixel counts
are given, FOV / pixels (eq. 5-1) -- and flagged. In the horizontal sectors
the segments alternate vertically, so their floor is the vertical sampling,
and vice versa.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from metrics.optics import sensor_angular_resolution_deg

DEFAULT_INLIER_MM = 20.0
DEFAULT_RING_MM = 1.0
DEFAULT_BINNING = 2
MIN_SAMPLES_PER_SEGMENT = 2
#: nominal sector boundaries: vertical sectors [45, 135) and [225, 315) deg, horizontal ones between
_NOMINAL_BOUNDS = np.radians([45.0, 135.0, 225.0, 315.0])
#: sector k (counted from the first boundary) is vertical for k = 0, 2 and horizontal for k = 1, 3
SECTOR_IS_V = np.array([True, False, True, False])
_RANSAC_SAMPLE = 20000
_RANSAC_HYPOTHESES = 256
_RANSAC_PLANES = 4
_MIN_FACING = 0.5  # |cos| between plane normal and optical axis for a star facing the camera
_MIN_VALID = 500
_STAR_FRACTION = 0.25  # a ring is on the star while at least this share of its samples are inliers
_PROFILE_RINGS = 5  # smoothing of that share over 5 rings (10 mm)
_MIN_SYMMETRY = 0.2  # mean N/2-th angular phasor of the outer inliers needed to refine the centre
_RIM_MARGIN = 0.03  # rings this share of the radius inside the rim are not evaluated (rim blur)
#: chance that a cloud without the star's pattern passes the pattern test in any of its rings (star_pattern)
PATTERN_FALSE_ALARM = 1e-6
#: modulation depth a ring needs to show the star (star_pattern): twice what one feature that does not
#: repeat with the segments (an edge, an object, the image border) can put into the N/2-th harmonic of a
#: 24-segment star (at most 2/(N/2) = 0.17 per feature, 0.06 for N = 72)
MIN_MODULATION = 0.33


@dataclass(frozen=True)
class BoehlerResult:
    """Böhler-star evaluation of one point cloud (Thesis 2024, 5.1.3).

    Ring arrays run over the evaluated 2 mm rings, ``radii_mm`` being their
    inner edges. ``clusters`` counts the inlier clusters of the whole ring
    (N/2 when resolved), ``clusters_h``/``clusters_v`` those in the horizontal/
    vertical sectors (``expected_h``/``expected_v`` when resolved), and
    ``points_h``/``points_v`` all valid samples there. ``radius_*_mm`` is
    the resolution radius, ``resolution_*_mm`` the lateral resolution
    2 pi r / N (never finer than ``sensor_*_mm``, the sensor's sampling at the
    star across the sector's segments; ``clamped_*`` when it would have been),
    ``resolution_mm`` the worse of h and v; all NaN where the star is not
    resolved out to the evaluated rim. ``filled_phase_deg``: angle of a
    filled segment's centre, modulo a segment pair. ``star_found``: some
    ring shows the star's alternation of segments and slots
    (:func:`star_pattern`); ``modulation``: the deepest such ring's depth.
    """

    segments: int
    centre_mm: tuple[float, float, float]
    normal: tuple[float, float, float]
    distance_mm: float
    inlier_mm: float
    star_radius_mm: float
    ring_width_mm: float
    radii_mm: np.ndarray
    clusters: np.ndarray
    clusters_h: np.ndarray
    clusters_v: np.ndarray
    points_h: np.ndarray
    points_v: np.ndarray
    expected_h: int
    expected_v: int
    resolved_h: np.ndarray
    resolved_v: np.ndarray
    radius_h_mm: float
    radius_v_mm: float
    resolution_h_mm: float
    resolution_v_mm: float
    resolution_mm: float
    angular_h_deg: float
    angular_v_deg: float
    sensor_h_mm: float
    sensor_v_mm: float
    clamped_h: bool
    clamped_v: bool
    filled_phase_deg: float
    warnings: tuple[str, ...]
    star_found: bool = True
    modulation: float = math.nan

    @property
    def plane_offset_mm(self) -> float:
        """d of the star plane n . P = d."""
        return float(np.dot(self.normal, self.centre_mm))


@dataclass(frozen=True)
class RingTable:
    """Cluster counts and sample counts per ring (docs/metrics.md, Böhler star steps 4-6)."""

    radii_mm: np.ndarray
    width_mm: float
    clusters: np.ndarray
    clusters_h: np.ndarray
    clusters_v: np.ndarray
    points_h: np.ndarray
    points_v: np.ndarray
    expected_h: int
    expected_v: int
    resolved_h: np.ndarray
    resolved_v: np.ndarray


# ---------------------------------------------------------------------- step 5: clusters
def _ring_cluster_labels(ring: np.ndarray, theta: np.ndarray, gap_rad: float) -> np.ndarray:
    """Cluster labels of inliers sorted by (ring, angle in [0, 2 pi)) (docs/metrics.md, Böhler star step 5).

    A cluster starts at a new ring or where neighbours are more than
    ``gap_rad`` apart; per ring, the last cluster is the first one continued
    when the gap across 0/2 pi is not larger than ``gap_rad``.
    """
    new = np.ones(ring.size, dtype=bool)
    new[1:] = (ring[1:] != ring[:-1]) | (np.diff(theta) > gap_rad)
    labels = np.cumsum(new) - 1
    _, first, count = np.unique(ring, return_index=True, return_counts=True)
    last = first + count - 1
    wraps = (labels[last] != labels[first]) & (theta[first] + 2 * math.pi - theta[last] <= gap_rad)
    remap = np.arange(labels[-1] + 1 if labels.size else 0)
    remap[labels[last[wraps]]] = labels[first[wraps]]
    return remap[labels]


def sector_bounds(segments: int, phase_rad: float) -> np.ndarray:
    """The four sector boundaries (rad), each at the slot centre nearest to 45, 135, 225, 315 deg (docs/metrics.md Böhler step 6);
    ``phase_rad``: a filled segment's centre angle.

    Examples
    --------
    24 segments, a filled one centred at 0 deg: slots centred at 15 + k 30 deg, 45 deg among them;
    with the filled segment at 10 deg the slots nearest 45 deg lie at 55 deg (and 145, ...).

    >>> np.round(np.degrees(sector_bounds(24, 0.0)), 6).tolist()
    [45.0, 135.0, 225.0, 315.0]
    >>> np.round(np.degrees(sector_bounds(24, np.radians(10.0))), 6).tolist()
    [55.0, 145.0, 235.0, 325.0]
    """
    pair = 4 * math.pi / segments
    slot = phase_rad + pair / 2
    return slot + np.round((_NOMINAL_BOUNDS - slot) / pair) * pair


def sectors(angle_rad: np.ndarray, segments: int, phase_rad: float) -> tuple[np.ndarray, np.ndarray]:
    """Sector index (0-3, counted from the boundary near 45 deg) of each angle, and the filled segments of each
    sector (docs/metrics.md, Böhler star step 6). Sectors 0 and 2 are vertical (around 90 and 270 deg), 1 and 3 horizontal; every
    boundary lies at the slot centre nearest to its nominal 45 + k 90 deg, ``phase_rad`` being a filled
    segment's centre angle.

    Examples
    --------
    Angles 0, 90, 180, 270 deg lie in the sectors 3 (horizontal), 0 (vertical), 1, 2; each sector of
    90 deg holds 3 of the 24 segments' 12 filled ones.

    >>> index, filled = sectors(np.radians([0.0, 90.0, 180.0, 270.0]), 24, 0.0)
    >>> index.tolist(), filled.tolist()
    ([3, 0, 1, 2], [3, 3, 3, 3])
    """
    bounds = sector_bounds(segments, phase_rad)
    relative = np.mod(np.asarray(angle_rad, float) - bounds[0], 2 * math.pi)
    index = np.searchsorted(np.mod(bounds - bounds[0], 2 * math.pi), relative, side="right") - 1
    widths = np.diff(np.append(bounds, bounds[0] + 2 * math.pi))
    return index, np.round(widths / (4 * math.pi / segments)).astype(int)


def evaluate_rings(radius_mm: np.ndarray, angle_rad: np.ndarray, inlier: np.ndarray, segments: int,
                   max_radius_mm: float, phase_rad: float, *, ring_mm: float = DEFAULT_RING_MM,
                   binning: int = DEFAULT_BINNING) -> RingTable:
    """Clusters and samples per ring and orientation, and which rings are resolved (docs/metrics.md, Böhler star steps 4-6).

    ``radius_mm``, ``angle_rad``: polar coordinates in the star plane of every
    valid sample (1-D); ``inlier``: on the star. ``phase_rad``: the angle of a
    filled segment's centre (it places the sector boundaries in slots).
    Rings of ``ring_mm`` x ``binning`` from 0 to ``max_radius_mm``.

    Examples
    --------
    Rings of 2 mm out to 50 mm, 720 samples each: a sharp 24-segment star (a filled segment centred at
    7.5 deg) outside 20 mm, inside it every sample on the star (the segments merged into a disc). Each
    orientation holds 6 filled segments; the rings are resolved from 20 mm on.

    >>> theta = (np.arange(720) + 0.5) * 2 * np.pi / 720
    >>> star = np.mod(theta * 12 / np.pi, 2) < 1
    >>> radius, angle = np.repeat(np.arange(25) * 2.0 + 1.0, 720), np.tile(theta, 25)
    >>> rings = evaluate_rings(radius, angle, (radius < 20) | np.tile(star, 25), 24, 50.0, np.radians(7.5))
    >>> rings.expected_h, rings.expected_v, float(rings.radii_mm[rings.resolved_h].min()), bool(rings.resolved_h[10:].all())
    (6, 6, 20.0, True)
    """
    if segments < 16 or segments % 2:
        raise ValueError(f"segments must be an even number >= 16, got {segments}")
    width = ring_mm * binning
    n_rings = int(max_radius_mm // width)
    if n_rings < 1:
        raise ValueError(f"no ring of {width:g} mm fits inside {max_radius_mm:.1f} mm")
    radius, inlier = np.asarray(radius_mm, float), np.asarray(inlier, bool)
    keep = np.isfinite(radius) & (radius < n_rings * width)
    ring = (radius[keep] // width).astype(np.int64)
    theta = np.mod(np.asarray(angle_rad, float)[keep], 2 * math.pi)
    sector, filled = sectors(theta, segments, phase_rad)
    points = np.bincount(ring * 2 + SECTOR_IS_V[sector], minlength=2 * n_rings).reshape(n_rings, 2)
    expected_v, expected_h = int(filled[SECTOR_IS_V].sum()), int(filled[~SECTOR_IS_V].sum())

    on = inlier[keep]
    r_in, t_in, s_in = ring[on], theta[on], sector[on]
    order = np.lexsort((t_in, r_in))
    r_in, t_in, s_in = r_in[order], t_in[order], s_in[order]
    labels = _ring_cluster_labels(r_in, t_in, math.pi / segments)
    clusters = np.zeros(n_rings, dtype=np.int64)
    per_sector = np.zeros((n_rings, 2), dtype=np.int64)
    if labels.size:
        first = np.unique(labels, return_index=True)[1]
        clusters = np.bincount(r_in[first], minlength=n_rings)
        pairs = np.unique(labels * 4 + s_in, return_index=True)[1]
        per_sector = np.bincount(r_in[pairs] * 2 + SECTOR_IS_V[s_in[pairs]], minlength=2 * n_rings).reshape(n_rings, 2)
    resolved_h = (per_sector[:, 0] == expected_h) & (points[:, 0] >= MIN_SAMPLES_PER_SEGMENT * 2 * expected_h)
    resolved_v = (per_sector[:, 1] == expected_v) & (points[:, 1] >= MIN_SAMPLES_PER_SEGMENT * 2 * expected_v)
    return RingTable(
        radii_mm=np.arange(n_rings) * width, width_mm=width, clusters=clusters,
        clusters_h=per_sector[:, 0], clusters_v=per_sector[:, 1], points_h=points[:, 0], points_v=points[:, 1],
        expected_h=expected_h, expected_v=expected_v, resolved_h=resolved_h, resolved_v=resolved_v,
    )


def star_pattern(ring: np.ndarray, angle_rad: np.ndarray, inlier: np.ndarray, segments: int) -> tuple[np.ndarray, np.ndarray]:
    """Per ring, the depth and the significance of the star's N/2-fold alternation of inliers (docs/metrics.md,
    Böhler star, "Is it a star?").

    On a ring the camera resolves, the star's segments are on the star plane and its slots show the wall
    behind: whether a sample is an inlier alternates with the angle as a square wave of N/2 periods. With
    the ring's inlier share p, S = sum over its n samples of (inlier - p) exp(i N/2 theta); a perfect square
    wave has |S| / n = sin(pi p) / pi, so the depth M = pi |S| / (n sin(pi p)) is 1 for sharp segments and 0
    where there are none (a plain wall: every sample an inlier; a star blurred into a disc). Where being an
    inlier does not depend on the angle (samples with a fixed chance p each), |S|^2 / (n p (1 - p)) is
    exponentially distributed with mean 1: Z, the significance, exceeds t with probability exp(-t).
    ``ring``: ring index per sample; returns (M, Z) per ring, both 0 where every sample or none is an inlier.

    Examples
    --------
    A ring of 720 samples on a sharp 24-segment star (half of them inliers, in 12 runs) and a ring on
    a plain wall: depths 1 and 0; the star's significance is n 4 / pi^2 = 292.

    >>> theta = (np.arange(720) + 0.5) * 2 * np.pi / 720
    >>> star = np.mod(theta * 12 / np.pi, 2) < 1
    >>> depth, significance = star_pattern(np.repeat([0, 1], 720), np.tile(theta, 2),
    ...                                    np.concatenate([star, np.ones(720, bool)]), 24)
    >>> np.round(depth, 2).tolist(), round(float(significance[0]))
    ([1.0, 0.0], 292)
    """
    ring = np.asarray(ring, np.int64)
    n_rings = int(ring.max()) + 1 if ring.size else 0
    on = np.asarray(inlier, float)
    n = np.bincount(ring, minlength=n_rings).astype(float)
    with np.errstate(invalid="ignore", divide="ignore"):
        p = np.bincount(ring, on, minlength=n_rings) / n
        term = (on - p[ring]) * np.exp(1j * (segments // 2) * np.asarray(angle_rad, float))
        s = np.abs(np.bincount(ring, term.real, minlength=n_rings) + 1j * np.bincount(ring, term.imag, minlength=n_rings))
        mixed = (p > 0) & (p < 1)
        depth = np.where(mixed, math.pi * s / (n * np.sin(math.pi * p)), 0.0)
        significance = np.where(mixed, s**2 / (n * p * (1 - p)), 0.0)
    return depth, significance


def resolution_radius(radii_mm: np.ndarray, resolved: np.ndarray) -> float:
    """Smallest radius from which every larger ring is resolved (docs/metrics.md, Böhler step 7); NaN if the outermost isn't.

    Examples
    --------
    >>> radii = np.array([0.0, 2.0, 4.0, 6.0, 8.0])
    >>> resolution_radius(radii, [False, True, False, True, True]), resolution_radius(radii, [True] * 5)
    (6.0, 0.0)
    >>> resolution_radius(radii, [True, True, True, True, False])
    nan
    """
    resolved = np.asarray(resolved, bool)
    if not resolved.size or not resolved[-1]:
        return math.nan
    bad = np.flatnonzero(~resolved)
    return float(radii_mm[bad[-1] + 1 if bad.size else 0])


# ---------------------------------------------------------------------- step 1: plane and centre
def _plane_through(points: np.ndarray) -> tuple[np.ndarray, float]:
    """Least-squares plane (unit normal with n_z >= 0, offset d: n . P = d)."""
    mean = points.mean(axis=0)
    normal = np.linalg.svd(points - mean, full_matrices=False)[2][-1]
    if normal[2] < 0:
        normal = -normal
    return normal, float(normal @ mean)


def _ransac(points: np.ndarray, tolerance_mm: float, rng: np.random.Generator) -> tuple[np.ndarray, float, np.ndarray]:
    """Best of ``_RANSAC_HYPOTHESES`` three-point planes, refined by least squares; (normal, d, support mask)."""
    p0, p1, p2 = (points[rng.integers(0, len(points), _RANSAC_HYPOTHESES)] for _ in range(3))
    normals = np.cross(p1 - p0, p2 - p0)
    length = np.linalg.norm(normals, axis=1)
    ok = length > 1e-6
    normals = normals[ok] / length[ok, None]
    if not len(normals):
        return np.array([0.0, 0.0, 1.0]), 0.0, np.zeros(len(points), bool)
    offsets = np.einsum("ij,ij->i", normals, p0[ok])
    support = (np.abs(points @ normals.T - offsets) <= tolerance_mm).sum(axis=0)
    best = int(np.argmax(support))
    mask = np.abs(points @ normals[best] - offsets[best]) <= tolerance_mm
    normal, offset = _plane_through(points[mask])
    return normal, offset, np.abs(points @ normal - offset) <= tolerance_mm


def find_star_plane(points: np.ndarray, tolerance_mm: float) -> tuple[np.ndarray, float]:
    """The star plane: the nearest large plane facing the camera (docs/metrics.md, Böhler star step 1).

    ``points``: (M, 3) valid points. Sequential RANSAC extracts up to four
    planes, each holding at least 0.5 % of the points within
    ``tolerance_mm``; of those facing the camera (normal within 60 deg of the
    optical axis) the one with the smallest median depth wins and is refitted
    on all its points. ValueError if none qualifies.

    Examples
    --------
    A 24-segment star of 200 mm radius 1000 mm away, the wall 1500 mm away seen through its slots and
    around it (f = 200 px): the nearer plane, z = 1000 mm.

    >>> v, u = np.mgrid[-50:50, -50:50] + 0.5
    >>> on_star = (np.hypot(u, v) < 40) & (np.mod(np.arctan2(v, u) * 12 / np.pi, 2) < 1)
    >>> z = np.where(on_star, 1000.0, 1500.0)
    >>> normal, offset = find_star_plane(np.column_stack([(u * z / 200).ravel(), (v * z / 200).ravel(), z.ravel()]), 5.0)
    >>> round(float(normal[2]), 6), round(offset, 6)
    (1.0, 1000.0)
    """
    rng = np.random.default_rng(0)
    sample = points[rng.choice(len(points), min(len(points), _RANSAC_SAMPLE), replace=False)]
    min_support = max(30, int(0.005 * len(sample)))
    remaining, planes = sample, []
    for _ in range(_RANSAC_PLANES):
        if len(remaining) < min_support:
            break
        normal, offset, mask = _ransac(remaining, tolerance_mm, rng)
        if mask.sum() < min_support:
            break
        planes.append((normal, offset, float(np.median(remaining[mask, 2]))))
        remaining = remaining[~mask]
    facing = [p for p in planes if abs(p[0][2]) >= _MIN_FACING]
    if not facing:
        raise ValueError("no star plane found: no planar region facing the camera holds 0.5 % of the valid points")
    normal, offset, _ = min(facing, key=lambda p: p[2])
    for _ in range(2):
        on = np.abs(points @ normal - offset) <= tolerance_mm
        normal, offset = _plane_through(points[on])
    return normal, offset


def _plane_axes(normal: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """In-plane axes: u = the camera's x axis projected into the plane, v = u x n (image up)."""
    u = np.array([1.0, 0.0, 0.0]) - normal[0] * normal
    u /= np.linalg.norm(u)
    return u, np.cross(u, normal)


def _project(cloud: np.ndarray, normal: np.ndarray, offset: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every point moved along its ray onto the plane: in-plane (a, b) about the foot point, and its z."""
    along = cloud @ normal
    with np.errstate(invalid="ignore", divide="ignore"):
        scale = np.where(along > 0, offset / along, np.nan)
    q = cloud * scale[..., None]
    u, v = _plane_axes(normal)
    rel = q - offset * normal
    return rel @ u, rel @ v, q[..., 2]


def _inlier_share_profile(r: np.ndarray, inlier: np.ndarray, weight: np.ndarray, width: float) -> tuple[np.ndarray, np.ndarray]:
    """Outer ring edges and the smoothed area share of inliers per ring around a centre."""
    ring = (r // width).astype(np.int64)
    n = int(ring.max()) + 1
    total = np.bincount(ring, weight, minlength=n)
    star = np.bincount(ring, weight * inlier, minlength=n)
    kernel = np.ones(_PROFILE_RINGS)
    with np.errstate(invalid="ignore", divide="ignore"):
        share = np.convolve(star, kernel, "same") / np.convolve(total, kernel, "same")
    return (np.arange(n) + 1) * width, share


def _star_radius(a: np.ndarray, b: np.ndarray, inlier: np.ndarray, weight: np.ndarray, centre: np.ndarray,
                 width: float) -> float:
    """Outermost radius around ``centre`` at which the star still covers ``_STAR_FRACTION`` of the ring."""
    edges, share = _inlier_share_profile(np.hypot(a - centre[0], b - centre[1]), inlier, weight, width)
    on = np.flatnonzero(share >= _STAR_FRACTION)
    return float(edges[on[-1]]) if on.size else math.nan


def _windowed_centroid(a: np.ndarray, b: np.ndarray, inlier: np.ndarray, weight: np.ndarray, start: np.ndarray,
                       width_mm: float) -> tuple[np.ndarray, float]:
    """Area-weighted centroid of the inliers within the star radius around the current centre, iterated from
    ``start``; the fixed point is the centre of a star whose rim is in view. Returns (centre, star radius)."""
    centre = np.asarray(start, float)
    sa, sb, sw = a[inlier], b[inlier], weight[inlier]
    radius = math.nan
    for _ in range(100):
        radius = _star_radius(a, b, inlier, weight, centre, width_mm)
        window = np.hypot(sa - centre[0], sb - centre[1]) <= radius
        if not window.any():
            break
        new = np.array([np.average(sa[window], weights=sw[window]), np.average(sb[window], weights=sw[window])])
        moved = float(np.hypot(*(new - centre)))
        centre = new
        if moved < 0.01:
            break
    if not math.isfinite(radius):
        raise ValueError("no star found on the star plane: its inliers cover no ring around the image centre")
    return centre, radius


def _symmetric_centre(a: np.ndarray, b: np.ndarray, centre: np.ndarray, outer_mm: float, segments: int) -> np.ndarray:
    """The point about which the inliers ``a``, ``b`` are most N/2-fold symmetric, searched around ``centre``.

    Symmetry = |sum of exp(i N/2 theta)| over the inliers of the outer rings
    (0.4 to 1 x ``outer_mm``): largest when every filled segment sits at the
    same phase. Grids of 3, 0.5 and 0.1 mm over +-24, 3 and 0.5 mm. Where the
    segments are not resolved there is no pattern to align (the mean phasor
    stays below ``_MIN_SYMMETRY``; 2/pi for resolved segments): ``centre`` is kept.
    """
    m = segments // 2
    start = centre
    for half, step, most in ((24.0, 3.0, 3000), (3.0, 0.5, 6000), (0.5, 0.1, 6000)):
        r = np.hypot(a - centre[0], b - centre[1])
        use = np.flatnonzero((r >= 0.4 * outer_mm) & (r < outer_mm))
        use = use[:: max(1, use.size // most)]
        if not use.size:
            return start
        offsets = np.arange(-half, half + step / 2, step)
        grid = centre + np.stack(np.meshgrid(offsets, offsets), axis=-1).reshape(-1, 2)
        theta = np.arctan2(b[use][None, :] - grid[:, 1:], a[use][None, :] - grid[:, :1])
        score = np.abs(np.exp(1j * m * theta).mean(axis=1))
        if score.max() < _MIN_SYMMETRY:
            return start
        centre = grid[int(np.argmax(score))]
    return centre


def find_centre(a: np.ndarray, b: np.ndarray, inlier: np.ndarray, weight: np.ndarray, start: np.ndarray,
                width_mm: float, border_mm: np.ndarray, segments: int) -> tuple[np.ndarray, float, float]:
    """Centre of the star's rotational symmetry in the plane (docs/metrics.md, Böhler star step 1).

    First the centroid: from ``start`` (where the optical axis meets the
    plane), repeatedly the area-weighted centroid of the inliers within the
    star radius around the current centre -- a region with N/2-fold symmetry
    has its centroid at its centre. Then, because the image border may cut
    the star's rim (which biases a centroid), the point about which the
    segments are most N/2-fold symmetric, searched within 24 mm of it.
    ``a``, ``b``: in-plane coordinates of every valid sample; ``weight``: their
    area; ``border_mm``: (K, 2) in-plane coordinates of the image border.
    Returns (centre, star radius, radius visible inside the image).

    Examples
    --------
    A 24-segment star of radius 50 mm about (10, -5) mm, sampled every 1 mm, searched from (0, 0).

    >>> b, a = np.mgrid[-80:80, -80:80] + 0.5
    >>> da, db = a - 10.0, b + 5.0
    >>> inlier = (np.hypot(da, db) < 50) & (np.mod(np.arctan2(db, da) * 12 / np.pi, 2) < 1)
    >>> centre, radius, visible = find_centre(a.ravel(), b.ravel(), inlier.ravel(), np.ones(a.size), np.zeros(2),
    ...                                       2.0, np.empty((0, 2)), 24)
    >>> [round(c) for c in centre], round(radius), visible
    ([10, -5], 50, inf)
    """
    centre, radius = _windowed_centroid(a, b, inlier, weight, start, width_mm)
    visible = float(np.min(np.hypot(*(border_mm - centre).T))) if len(border_mm) else math.inf
    centre = _symmetric_centre(a[inlier], b[inlier], centre, min(radius, visible), segments)
    radius = _star_radius(a, b, inlier, weight, centre, width_mm)
    visible = float(np.min(np.hypot(*(border_mm - centre).T))) if len(border_mm) else math.inf
    return centre, radius, visible


def _filled_phase(angle: np.ndarray, radius: np.ndarray, inlier: np.ndarray, segments: int, outer_mm: float) -> float:
    """Angle of a filled segment's centre, from the N/2-th angular harmonic of the inliers of the outer rings."""
    use = inlier & (radius >= 0.6 * outer_mm) & (radius < outer_mm)
    m = segments // 2
    phasor = np.exp(1j * m * angle[use]).sum()
    return float(np.angle(phasor) / m)


def _median_spacing(a: np.ndarray, b: np.ndarray, inlier: np.ndarray, axis: int) -> float:
    """Median in-plane distance between neighbouring star points along image columns (axis 1) or rows (axis 0)."""
    both = (inlier[:, 1:] & inlier[:, :-1]) if axis == 1 else (inlier[1:] & inlier[:-1])
    step = np.hypot(np.diff(a, axis=axis), np.diff(b, axis=axis))[both]
    return float(np.median(step)) if step.size else math.nan


def star_coordinates(cloud: np.ndarray, result: BoehlerResult) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(radius mm, angle rad, inlier) per pixel of ``cloud`` in the star plane of ``result`` (docs/metrics.md, Böhler step 3).

    Angles run counter-clockwise as seen by the camera from the camera's x axis.

    Examples
    --------
    The star of :func:`analyze_boehler`'s example: the pixel 40.5 px right of and 0.5 px below the
    principal point sees the wall past the rim, along a ray that meets the star plane 202.5 mm right
    of and 2.5 mm below the centre: radius 202.515 mm, angle -atan(2.5 / 202.5) = -0.707 deg.

    >>> v, u = np.mgrid[-50:50, -50:50] + 0.5
    >>> on_star = (np.hypot(u, v) < 40) & (np.mod(np.arctan2(v, u) * 12 / np.pi, 2) < 1)
    >>> z = np.where(on_star, 1000.0, 1500.0)
    >>> cloud = np.dstack([u * z / 200, v * z / 200, z])
    >>> radius, angle, inlier = star_coordinates(cloud, analyze_boehler(cloud, 24))
    >>> round(float(radius[50, 90]), 2), round(float(np.degrees(angle[50, 90])) - 360.0, 2), bool(inlier[50, 90])
    (202.52, -0.71, False)
    """
    cloud = np.asarray(cloud, float)
    normal, offset = np.asarray(result.normal), result.plane_offset_mm
    a, b, _ = _project(cloud, normal, offset)
    u, v = _plane_axes(normal)
    rel = np.asarray(result.centre_mm) - offset * normal
    a, b = a - rel @ u, b - rel @ v
    inlier = np.abs(cloud @ normal - offset) <= result.inlier_mm
    return np.hypot(a, b), np.mod(np.arctan2(b, a), 2 * math.pi), inlier & np.isfinite(a)


# ---------------------------------------------------------------------- the whole evaluation
def auto_binning(spacing_mm: float, ring_mm: float = DEFAULT_RING_MM) -> int:
    """Rings binned together so that a ring is at least two point spacings wide (docs/metrics.md, Böhler star steps 4-6).

    A ring narrower than that holds a filled segment's points only here and
    there, so it falls apart into too many clusters well outside the sampling
    limit; two spacings put about two points across the ring at every angle.
    Never less than the default 2 (Thesis 2024, 5.1.3: 2 mm rings).

    Examples
    --------
    >>> auto_binning(0.5), auto_binning(3.2), auto_binning(float("nan"))  # 2 spacings: 1 mm, 6.4 mm
    (2, 7, 2)
    """
    if not math.isfinite(spacing_mm):
        return DEFAULT_BINNING
    return max(DEFAULT_BINNING, math.ceil(2 * spacing_mm / ring_mm))


def _orientation(name: str, rings: RingTable, segments: int, floor_mm: float, distance_mm: float
                 ) -> tuple[float, float, float, bool, list[str]]:
    """(radius, lateral, angular, clamped, warnings) of one orientation (docs/metrics.md, Böhler star step 7, eq. 5-4)."""
    resolved, points, expected = ((rings.resolved_h, rings.points_h, rings.expected_h) if name == "h"
                                  else (rings.resolved_v, rings.points_v, rings.expected_v))
    radius = resolution_radius(rings.radii_mm, resolved)
    lateral = 2 * math.pi * radius / segments
    warnings = []
    if math.isnan(radius):
        hint = ": use the 24-segment star" if segments == 72 else ""
        outer = rings.radii_mm[-1] + rings.width_mm
        warnings.append(f"{name}: {segments}-segment star not resolved anywhere out to {outer:.0f} mm{hint}")
    else:
        sparse = rings.radii_mm[points < MIN_SAMPLES_PER_SEGMENT * 2 * expected]
        if sparse.size and sparse.max() + rings.width_mm >= radius:
            warnings.append(f"{name}: resolved down to the rings that hold fewer than {MIN_SAMPLES_PER_SEGMENT} "
                            f"points per segment (inside {sparse.max() + rings.width_mm:.0f} mm): the result is "
                            "limited by the point spacing")
    clamped = lateral < floor_mm
    if clamped:
        warnings.append(f"{name}: {lateral:.2f} mm is finer than the sensor resolution {floor_mm:.2f} mm at "
                        f"{distance_mm:.0f} mm: reported as the sensor resolution")
        lateral = floor_mm
    return radius, lateral, math.degrees(math.atan(lateral / distance_mm)), clamped, warnings


def angular_resolution_u_deg(result: BoehlerResult, orientation: str) -> float:
    """Standard uncertainty (deg) of the angular resolution of one ``orientation`` ("h" or "v") from the ring
    width: the resolution radius moves in whole rings of width w, so where between its ring's edges the star
    stops being resolved is unknown; as the figure's resolution that is rectangular over one ring, w / sqrt(12)
    in radius (GUM F.2.2.1), through the sensitivity of atan(2 pi r / (N d)) to r (GUM 5.1.3). NaN where the
    figure is not a ring's radius: not resolved, or clamped to the sensor resolution (a bound).

    Examples
    --------
    A 72-segment star 1000 mm away resolved from r = 40 mm on, in 2 mm rings: u_r = 2 / sqrt(12) = 0.577 mm,
    d(angle)/dr = (2 pi / 72) / 1000 / (1 + 0.00349^2) rad/mm, so 0.577 x 8.7266e-5 x 57.2958 = 0.00289 deg.

    >>> from types import SimpleNamespace
    >>> star = SimpleNamespace(segments=72, distance_mm=1000.0, ring_width_mm=2.0, radius_h_mm=40.0, clamped_h=False)
    >>> round(angular_resolution_u_deg(star, "h"), 5)
    0.00289
    """
    radius = result.radius_h_mm if orientation == "h" else result.radius_v_mm
    clamped = result.clamped_h if orientation == "h" else result.clamped_v
    if clamped or not math.isfinite(radius):
        return math.nan
    per_mm = 2 * math.pi / result.segments / result.distance_mm  # d(lateral / d)/dr
    slope = per_mm / (1 + (radius * per_mm) ** 2)
    return math.degrees(slope * result.ring_width_mm / math.sqrt(12))


def analyze_boehler(cloud: np.ndarray, segments: int, *, inlier_mm: float = DEFAULT_INLIER_MM,
                    ring_mm: float = DEFAULT_RING_MM, binning: int | None = DEFAULT_BINNING,
                    fov_deg: tuple[float, float] | None = None) -> BoehlerResult:
    """Böhler-star resolution of an organized cloud (Thesis 2024, 5.1.3, 6.3.2, eq. 5-4).

    ``cloud``: H x W x 3 (mm, camera frame, NaN = invalid), usually the stack
    mean; ``segments``: N of the star (72 or 24); ``fov_deg``: the camera's
    (horizontal, vertical) field of view, which with the cloud's W x H gives
    the sensor resolution (eq. 5-1) the result may not beat; the measured
    point spacing on the star is always a floor. ``binning=None`` chooses
    the binning from the median point spacing on the star (``auto_binning``:
    rings at least two spacings wide). ValueError on a malformed
    cloud, too few valid points or no star plane.

    Examples
    --------
    A sharp 24-segment star of 200 mm radius facing the camera 1000 mm away, the wall 1500 mm away
    (f = 200 px: 5 mm per pixel on the star).

    >>> v, u = np.mgrid[-50:50, -50:50] + 0.5
    >>> on_star = (np.hypot(u, v) < 40) & (np.mod(np.arctan2(v, u) * 12 / np.pi, 2) < 1)
    >>> z = np.where(on_star, 1000.0, 1500.0)
    >>> result = analyze_boehler(np.dstack([u * z / 200, v * z / 200, z]), 24)
    >>> result.star_found, [round(c) for c in result.centre_mm], round(result.star_radius_mm, 3)
    (True, [0, 0, 1000], 200.0)
    >>> round(result.distance_mm, 3), round(result.sensor_h_mm, 3)
    (1000.0, 5.0)
    """
    cloud = np.asarray(cloud, dtype=float)
    if cloud.ndim != 3 or cloud.shape[2] != 3:
        raise ValueError(f"the cloud must be organized H x W x 3 (x, y, z in mm), got shape {cloud.shape}")
    if segments < 16 or segments % 2:
        raise ValueError(f"segments must be an even number >= 16 (72 or 24), got {segments}")
    if inlier_mm <= 0 or ring_mm <= 0 or (binning is not None and binning < 1):
        raise ValueError("inlier_mm and ring_mm must be > 0 and binning >= 1")
    valid = np.isfinite(cloud).all(axis=2) & (cloud[..., 2] > 0)
    if valid.sum() < _MIN_VALID:
        raise ValueError(f"too few valid points: {int(valid.sum())} (at least {_MIN_VALID} needed)")
    normal, offset = find_star_plane(cloud[valid], tolerance_mm=inlier_mm / 4)
    a, b, z = _project(np.where(valid[..., None], cloud, np.nan), normal, offset)
    sample = np.isfinite(a)
    inlier = sample & (np.abs(cloud @ normal - offset) <= inlier_mm)
    if inlier.sum() < 4 * segments:
        raise ValueError(f"too few points on the star plane: {int(inlier.sum())} (at least {4 * segments} needed)")

    spacing_h, spacing_v = _median_spacing(a, b, inlier, axis=1), _median_spacing(a, b, inlier, axis=0)
    if binning is None:
        binning = auto_binning(max(spacing_h, spacing_v), ring_mm)
    width = ring_mm * binning
    border = np.zeros(a.shape, bool)
    border[[0, -1], :] = border[:, [0, -1]] = True
    border &= sample
    u, v = _plane_axes(normal)
    axis_point = np.array([0.0, 0.0, offset / normal[2]]) - offset * normal
    centre_ab, star_radius, visible = find_centre(
        a[sample], b[sample], inlier[sample], z[sample] ** 3, np.array([axis_point @ u, axis_point @ v]),
        width, np.column_stack([a[border], b[border]]), segments)
    centre = offset * normal + centre_ab[0] * u + centre_ab[1] * v
    distance = float(np.linalg.norm(centre))

    warnings: list[str] = []
    outer = star_radius * (1 - _RIM_MARGIN) - width
    if visible < outer:
        warnings.append(f"the image border cuts the star: rings evaluated out to {visible:.0f} mm only")
        outer = visible
    da, db = a[sample] - centre_ab[0], b[sample] - centre_ab[1]
    radius, angle = np.hypot(da, db), np.mod(np.arctan2(db, da), 2 * math.pi)
    phase = _filled_phase(angle, radius, inlier[sample], segments, outer)
    rings = evaluate_rings(radius, angle, inlier[sample], segments, outer, phase, ring_mm=ring_mm, binning=binning)
    inside = radius < len(rings.radii_mm) * width
    depth, significance = star_pattern((radius[inside] // width).astype(np.int64), angle[inside],
                                       inlier[sample][inside], segments)
    showing = significance > math.log(max(len(depth), 1) / PATTERN_FALSE_ALARM)
    modulation = float(depth[showing].max()) if showing.any() else 0.0
    star_found = modulation >= MIN_MODULATION
    if not star_found:
        warnings.append(f"no {segments}-segment star found: no ring on the plane at {distance:.0f} mm alternates "
                        f"between segments and slots (modulation depth {modulation:.2f}, a star needs "
                        f"{MIN_MODULATION:g}); a plain wall, or a star whose segments this cloud resolves nowhere")

    if max(spacing_h, spacing_v) > width:
        warnings.append(f"the point spacing on the star ({max(spacing_h, spacing_v):.1f} mm) exceeds the ring width "
                        f"({width:g} mm): rings are sparse and the result pessimistic; use a binning of at least "
                        f"{auto_binning(max(spacing_h, spacing_v), ring_mm)}")
    if fov_deg is not None:
        rows, cols = cloud.shape[:2]
        spacing_h = max(spacing_h, distance * math.tan(math.radians(sensor_angular_resolution_deg(fov_deg[0], cols))))
        spacing_v = max(spacing_v, distance * math.tan(math.radians(sensor_angular_resolution_deg(fov_deg[1], rows))))
    # in the horizontal sectors the segments alternate vertically: the vertical sampling limits them
    radius_h, lateral_h, angular_h, clamped_h, warn_h = _orientation("h", rings, segments, spacing_v, distance)
    radius_v, lateral_v, angular_v, clamped_v, warn_v = _orientation("v", rings, segments, spacing_h, distance)
    return BoehlerResult(
        segments=segments, centre_mm=tuple(float(c) for c in centre), normal=tuple(float(c) for c in normal),
        distance_mm=distance, inlier_mm=inlier_mm, star_radius_mm=star_radius, ring_width_mm=width,
        radii_mm=rings.radii_mm, clusters=rings.clusters, clusters_h=rings.clusters_h,
        clusters_v=rings.clusters_v, points_h=rings.points_h, points_v=rings.points_v,
        expected_h=rings.expected_h, expected_v=rings.expected_v, resolved_h=rings.resolved_h,
        resolved_v=rings.resolved_v, radius_h_mm=radius_h, radius_v_mm=radius_v,
        resolution_h_mm=lateral_h, resolution_v_mm=lateral_v, resolution_mm=float(np.max([lateral_h, lateral_v])),
        angular_h_deg=angular_h, angular_v_deg=angular_v, sensor_h_mm=spacing_v, sensor_v_mm=spacing_h,
        clamped_h=clamped_h, clamped_v=clamped_v, filled_phase_deg=math.degrees(phase) % (720 / segments),
        warnings=tuple(warnings + warn_h + warn_v), star_found=star_found, modulation=modulation,
    )
