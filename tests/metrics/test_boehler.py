"""Known-answer tests for metrics.boehler (Thesis 2024, 5.1.3, 6.3.2, eq. 5-4).

Synthetic clouds are ray-cast exactly: a pinhole camera (640 x 480, 67 x 51
deg unless stated) sees a 400 mm star with a 10 mm disc, ``gap`` mm in front
of a frontal wall, its centre off the optical axis, turned and (optionally)
tilted about the camera's y axis; range noise of 1 mm (1 sigma) along each
ray and 1 % of the pixels invalid. Inside a known radius the segments are
merged, either into a filled disc (every point on the star: one cluster per
ring) or into points at the mean depth of star and wall (no inliers there),
the two ways an unresolved star shows in a cloud. The larger of r0_h and
r0_v holds in a zone around its own axis (horizontal or vertical) and the
smaller one elsewhere, so each orientation has its own known answer: the zone
ends one segment pair before the nominal 45 deg sector boundaries, and the
method moves each boundary by at most one segment (to a slot centre), so the
zone always falls in its own orientation's sectors and the others never see
it.

Expected: r within one 2 mm ring of r0 (the ring holding r0 is partly
merged: it may or may not count as resolved). The merge radii are chosen
well above this camera's sampling limit at 500 mm (measured on unmerged
stars: r <= 34 mm for N = 72 and <= 10 mm for N = 24 over random turns and
tilts), so the answer is set by the merge, not by the pixels.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from metrics.boehler import (
    MIN_MODULATION,
    MIN_SAMPLES_PER_SEGMENT,
    analyze_boehler,
    evaluate_rings,
    resolution_radius,
    star_pattern,
)
from sim.model import parse_model
from sim.preview import simulate_frame

DISTANCE = 500.0


def star_cloud(segments: int, r0_h: float, r0_v: float, *, merged: str = "filled", rotation_deg: float = 0.0,
               tilt_deg: float = 0.0, centre: tuple[float, float] = (40.0, -30.0), distance: float = DISTANCE,
               gap: float = 300.0, size: tuple[int, int] = (640, 480), fov_deg: tuple[float, float] = (67.0, 51.0),
               noise_mm: float = 1.0, seed: int = 0) -> np.ndarray:
    """Organized H x W x 3 cloud of a star merged inside r0_h / r0_v (see the module docstring).

    Star angles run counter-clockwise as the camera sees them from the image's
    x axis; filled segment k spans rotation + [2k, 2k + 1] x 360/N deg.
    """
    rng = np.random.default_rng(seed)
    width, height = size
    fx = (width / 2) / math.tan(math.radians(fov_deg[0] / 2))
    fy = (height / 2) / math.tan(math.radians(fov_deg[1] / 2))
    col, row = np.meshgrid(np.arange(width) + 0.5 - width / 2, np.arange(height) + 0.5 - height / 2)
    ray = np.dstack([col / fx, row / fy, np.ones_like(col)])
    tilt = math.radians(tilt_deg)
    normal = np.array([math.sin(tilt), 0.0, math.cos(tilt)])
    right = np.array([math.cos(tilt), 0.0, -math.sin(tilt)])
    up = np.cross(right, normal)
    middle = np.array([centre[0], centre[1], distance])
    s_star = (normal @ middle) / (ray @ normal)
    rel = ray * s_star[..., None] - middle
    rho = np.hypot(rel @ right, rel @ up)
    theta = np.mod(np.arctan2(rel @ up, rel @ right), 2 * math.pi)
    segment = 2 * math.pi / segments
    filled = np.floor(np.mod(theta - math.radians(rotation_deg), 2 * math.pi) / segment).astype(int) % 2 == 0
    # the larger merge radius holds in a zone around its own axis, ending one segment pair before 45 deg
    axis = 0.0 if r0_h > r0_v else math.pi / 2
    zone = np.abs(np.mod(theta - axis + math.pi / 2, math.pi) - math.pi / 2) < math.pi / 4 - segment
    on_star = rho <= 200.0
    star = on_star & (filled | (rho <= 5.0))
    merge = on_star & (rho < np.where(zone, max(r0_h, r0_v), min(r0_h, r0_v)))
    s_wall = (distance + gap) / ray[..., 2]
    s = np.where(star, s_star, s_wall)
    s = np.where(merge, s_star if merged == "filled" else (s_star + s_wall) / 2, s)
    length = np.linalg.norm(ray, axis=2)
    rng_mm = s * length + rng.normal(0.0, noise_mm, s.shape)
    cloud = ray / length[..., None] * rng_mm[..., None]
    cloud[rng.random(s.shape) < 0.01] = np.nan
    return cloud


def assert_dense_where_resolved(result) -> None:
    """Thesis 2024, 6.3.3: a ring with fewer than 2 points per segment must never count as resolved."""
    least = 2 * MIN_SAMPLES_PER_SEGMENT
    assert np.all(result.points_h[result.resolved_h] >= least * result.expected_h)
    assert np.all(result.points_v[result.resolved_v] >= least * result.expected_v)


def assert_not_finer_than_sensor(result) -> None:
    assert result.resolution_h_mm >= result.sensor_h_mm
    assert result.resolution_v_mm >= result.sensor_v_mm


CASES = [
    # segments, r0_h, r0_v, merged, rotation, tilt, centre
    (72, 51.3, 68.7, "filled", 13.7, 0.0, (40.0, -30.0)),
    (72, 51.3, 68.7, "mean", 201.2, 6.0, (-35.0, 25.0)),
    (72, 63.9, 44.6, "filled", 95.1, -4.0, (10.0, 35.0)),
    (72, 47.2, 57.5, "mean", 333.3, 0.0, (-50.0, -20.0)),
    (24, 19.1, 29.4, "filled", 77.0, -5.0, (30.0, 20.0)),
    (24, 19.1, 29.4, "mean", 311.4, 0.0, (-45.0, -25.0)),
    (24, 31.5, 17.2, "filled", 160.6, 7.0, (-20.0, 30.0)),
    (24, 24.8, 35.9, "mean", 258.0, 3.0, (50.0, 10.0)),
]


@pytest.mark.parametrize("segments,r0_h,r0_v,merged,rotation,tilt,centre", CASES)
def test_resolution_radius_is_the_merge_radius(segments, r0_h, r0_v, merged, rotation, tilt, centre):
    cloud = star_cloud(segments, r0_h, r0_v, merged=merged, rotation_deg=rotation, tilt_deg=tilt, centre=centre)
    result = analyze_boehler(cloud, segments)
    assert abs(result.radius_h_mm - r0_h) <= 2.0
    assert abs(result.radius_v_mm - r0_v) <= 2.0
    # the centre is found, not assumed: the star sits 30-54 mm off the optical axis
    assert result.centre_mm[:2] == pytest.approx(centre, abs=0.5)
    assert result.distance_mm == pytest.approx(math.hypot(*centre, DISTANCE), abs=0.5)
    assert result.normal[0] == pytest.approx(math.sin(math.radians(tilt)), abs=2e-3)
    assert result.resolution_h_mm == pytest.approx(2 * math.pi * result.radius_h_mm / segments)  # eq. 5-4
    assert result.resolution_v_mm == pytest.approx(2 * math.pi * result.radius_v_mm / segments)
    assert result.resolution_mm == max(result.resolution_h_mm, result.resolution_v_mm)
    assert result.angular_h_deg == pytest.approx(math.degrees(math.atan(result.resolution_h_mm / result.distance_mm)))
    # outside the merge every ring shows all N/2 filled segments, N/4 in each orientation
    outside = result.radii_mm >= max(r0_h, r0_v) + 2
    assert np.all(result.clusters[outside] == segments // 2)
    assert result.expected_h == result.expected_v == segments // 4
    assert not result.warnings
    assert_dense_where_resolved(result)
    assert_not_finer_than_sensor(result)


@pytest.mark.parametrize("segments", [72, 24])
def test_filled_segment_across_zero_is_one_cluster(segments):
    """A filled segment spanning angle 0 (-s/2 ... s/2) sits in a horizontal sector: split at 0/2 pi it would
    count twice there (Thesis 2024, 6.3.3) and no ring would be resolved horizontally."""
    half_segment = 180.0 / segments
    r0_h, r0_v = (40.4, 55.2) if segments == 72 else (15.3, 24.7)
    cloud = star_cloud(segments, r0_h, r0_v, merged="filled", rotation_deg=-half_segment, centre=(25.0, 15.0))
    result = analyze_boehler(cloud, segments)
    assert result.filled_phase_deg == pytest.approx(0.0, abs=0.3) or result.filled_phase_deg == pytest.approx(
        720.0 / segments, abs=0.3)
    assert abs(result.radius_h_mm - r0_h) <= 2.0
    assert abs(result.radius_v_mm - r0_v) <= 2.0
    outside = result.radii_mm >= r0_v + 2
    assert np.all(result.clusters[outside] == segments // 2)
    assert np.all(result.clusters_h[outside] == result.expected_h)


def ring_samples(segments: int, per_segment: int, radius: float = 30.0) -> tuple[np.ndarray, ...]:
    """Samples evenly spread over one ring: ``per_segment`` per segment, inliers on the filled ones (filled
    segment k centred at 2k x 360/N deg, so segment 0 straddles angle 0)."""
    segment = 2 * math.pi / segments
    angle = (np.arange(segments * per_segment) + 0.5) * segment / per_segment - segment / 2
    inlier = np.floor((angle + segment / 2) / segment).astype(int) % 2 == 0
    return np.full(angle.size, radius), np.mod(angle, 2 * math.pi), inlier


def test_wrapping_cluster_merged_in_ring_table():
    radius, angle, inlier = ring_samples(24, 4)
    table = evaluate_rings(radius, angle, inlier, 24, max_radius_mm=32.0, phase_rad=0.0)
    ring = 15  # 30 mm in 2 mm rings
    assert table.clusters[ring] == 12
    assert (table.clusters_h[ring], table.clusters_v[ring]) == (table.expected_h, table.expected_v) == (6, 6)
    assert table.resolved_h[ring] and table.resolved_v[ring]
    assert resolution_radius(table.radii_mm[ring:], table.resolved_h[ring:]) == 30.0


def test_sparse_ring_is_never_resolved():
    """One sample per segment: every filled segment is one cluster, so the count is right by construction,
    but the ring holds fewer than 2 points per segment and must not count (Thesis 2024, 6.3.3)."""
    radius, angle, inlier = ring_samples(72, 1)
    table = evaluate_rings(radius, angle, inlier, 72, max_radius_mm=32.0, phase_rad=0.0)
    assert table.clusters[15] == 36 and table.clusters_h[15] == table.expected_h
    assert not table.resolved_h[15] and not table.resolved_v[15]
    radius, angle, inlier = ring_samples(72, 3)
    table = evaluate_rings(radius, angle, inlier, 72, max_radius_mm=32.0, phase_rad=0.0)
    assert table.resolved_h[15] and table.resolved_v[15]


def test_sparse_merged_ring_with_doubled_count_is_not_resolved():
    """A merged ring (all inliers) sampled so sparsely that every point is its own cluster: twice N/2."""
    radius, angle, _ = ring_samples(24, 1)
    table = evaluate_rings(radius, angle, np.ones(angle.size, bool), 24, max_radius_mm=32.0, phase_rad=0.0)
    assert table.clusters[15] == 24
    assert not table.resolved_h[15] and not table.resolved_v[15]


def test_result_is_never_finer_than_the_sensor():
    """A camera whose datasheet FOV is far wider than its real one (Thesis 2024, 5.1.3 on Song 2021): the star is
    really resolved finer than FOV / pixels claims possible, so the result is clamped to that and flagged.
    The real FOV is 40 x 30 deg, so the image border also cuts the star."""
    cloud = star_cloud(72, 0.0, 0.0, fov_deg=(40.0, 30.0), centre=(20.0, -10.0), rotation_deg=31.0)
    free = analyze_boehler(cloud, 72)
    assert any("image border cuts the star" in w for w in free.warnings)
    assert free.centre_mm[:2] == pytest.approx((20.0, -10.0), abs=0.5)
    assert not free.clamped_h and not free.clamped_v
    assert_not_finer_than_sensor(free)
    claimed = (120.0, 100.0)
    floor_v = free.distance_mm * math.tan(math.radians(claimed[1] / 480))
    floor_h = free.distance_mm * math.tan(math.radians(claimed[0] / 640))
    assert free.resolution_h_mm < floor_v and free.resolution_v_mm < floor_h
    clamped = analyze_boehler(cloud, 72, fov_deg=claimed)
    assert clamped.clamped_h and clamped.clamped_v
    # horizontal sectors: segments side by side vertically, so the vertical sensor resolution bounds them
    assert clamped.resolution_h_mm == pytest.approx(floor_v)
    assert clamped.resolution_v_mm == pytest.approx(floor_h)
    assert clamped.radius_h_mm == free.radius_h_mm
    assert sum("finer than the sensor resolution" in w for w in clamped.warnings) == 2


def test_star_merged_everywhere_is_not_resolved():
    cloud = star_cloud(72, 250.0, 250.0, merged="filled")
    result = analyze_boehler(cloud, 72)
    assert math.isnan(result.radius_h_mm) and math.isnan(result.resolution_v_mm)
    assert math.isnan(result.resolution_mm)
    assert any("not resolved anywhere" in w and "24-segment star" in w for w in result.warnings)
    assert result.centre_mm[:2] == pytest.approx((40.0, -30.0), abs=0.5)


def test_bad_input_raises():
    cloud = star_cloud(24, 20.0, 20.0, size=(160, 120))
    with pytest.raises(ValueError, match="H x W x 3"):
        analyze_boehler(cloud[..., :2], 24)
    with pytest.raises(ValueError, match="even number"):
        analyze_boehler(cloud, 23)
    with pytest.raises(ValueError, match="too few valid points"):
        analyze_boehler(np.full_like(cloud, np.nan), 24)
    col, row = np.meshgrid(np.arange(160.0), np.arange(120.0))
    floor = np.dstack([col * 10 - 800, np.full_like(col, 300.0), 500 + row * 20])  # a floor: faces no camera
    with pytest.raises(ValueError, match="no star plane"):
        analyze_boehler(floor, 24)


def simulated_star(model_text: str) -> np.ndarray:
    model = parse_model('camera = "blaze101"\n[effects.flying_pixels]\n' + model_text, "test model")
    x, y, z, *_ = simulate_frame(model, "boehler_star", {"segments": 72, "gap_mm": 300.0, "offset_mm": [8, -5],
                                                          "rotation_deg": 3.0}, distance_mm=DISTANCE + 300.0)
    return np.dstack([x, y, z])


def test_simulated_blaze101_star():
    """The simulator's blaze-101 (640 x 480, 67 x 51 deg, lens PSF sigma 0.71 px, defocus at its hyperfocal
    400 mm, depth from the phase of all light reaching a pixel) 500 mm from the 72-segment star.

    Measured: h 2.44 mm (2.5 px, 0.28 deg), v 2.62 mm (2.5 px, 0.30 deg), close to Thesis 2024, Table 6-4
    (0.22 / 0.24 deg); with a 6 px defocus disc, 4.7 px both ways. A segment stays an inlier cluster only
    while it is about as wide as the blur disc (a wider blur mixes in the wall behind the slots and moves
    the depth out of the +-20 mm band), so the resolution must lie between 0.6 and 1.2 disc diameters.
    """
    result = analyze_boehler(simulated_star("[effects.defocus]\nhyperfocal_mm = 400.0\n"), 72, fov_deg=(67.0, 51.0))
    assert result.centre_mm == pytest.approx((8.0, -5.0, DISTANCE), abs=1.0)
    for lateral, sensor in ((result.resolution_h_mm, result.sensor_h_mm), (result.resolution_v_mm, result.sensor_v_mm)):
        assert 1.0 <= lateral / sensor <= 3.5
    assert not result.clamped_h and not result.clamped_v
    assert_dense_where_resolved(result)

    disc_px = 7.5 * 400.0 / DISTANCE  # defocus disc b(s) = coc_px H / s
    blurred = analyze_boehler(simulated_star("[effects.defocus]\nhyperfocal_mm = 400.0\ncoc_px = 7.5\n"), 72,
                              fov_deg=(67.0, 51.0))
    for lateral, sensor, sharp in ((blurred.resolution_h_mm, blurred.sensor_h_mm, result.resolution_h_mm),
                                   (blurred.resolution_v_mm, blurred.sensor_v_mm, result.resolution_v_mm)):
        assert 0.6 * disc_px <= lateral / sensor <= 1.2 * disc_px
        assert lateral >= sharp + 1.5 * sensor


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_auto_binning_reaches_the_sampling_limit_of_a_coarse_cloud(seed):
    """320 x 240 pixels at 706 mm: 2.9 mm between points on the star. 2 mm rings hold a segment's points only
    here and there and resolve nothing; rings of two spacings (6 mm) resolve an unmerged 72-segment star down
    to about two spacings per segment pair (lateral 2 pi r / N between 1.5 and 2.5 spacings), and a star
    merged inside r0 at r0 within one ring."""
    sharp = star_cloud(72, 0.0, 0.0, size=(320, 240), distance=706.0, seed=seed, rotation_deg=17.0 * seed)
    fixed = analyze_boehler(sharp, 72, binning=2)
    assert math.isnan(fixed.resolution_mm)
    assert any("use a binning of at least 6" in w for w in fixed.warnings)
    auto = analyze_boehler(sharp, 72, binning=None)
    spacing = 706.0 * 2 * math.tan(math.radians(33.5)) / 320
    assert auto.ring_width_mm == 6.0
    for radius in (auto.radius_h_mm, auto.radius_v_mm):
        assert 1.5 * spacing <= 2 * math.pi * radius / 72 <= 2.5 * spacing
    merged = analyze_boehler(star_cloud(72, 120.0, 96.0, size=(320, 240), distance=706.0, seed=seed,
                                        rotation_deg=17.0 * seed, merged="mean"), 72, binning=None)
    assert merged.radius_h_mm == pytest.approx(120.0, abs=merged.ring_width_mm)
    assert merged.radius_v_mm == pytest.approx(96.0, abs=merged.ring_width_mm)


# ---------------------------------------------------------------------- is it a star?
@pytest.mark.parametrize("share", [0.5, 0.3, 0.8])
def test_star_pattern_of_a_sharp_square_wave_is_one(share):
    """Inliers on [0, share) of every one of the N/2 periods: the depth M is 1 whatever the share (the
    fundamental of a square wave of duty p is sin(pi p) / pi), and Z = n M^2 sin^2(pi p) / (pi^2 p (1 - p))."""
    n, segments = 3600, 24
    angle = (np.arange(n) + 0.5) * 2 * math.pi / n
    inlier = np.mod(angle * segments / 2 / (2 * math.pi), 1.0) < share
    depth, significance = star_pattern(np.zeros(n, np.int64), angle, inlier, segments)
    assert depth[0] == pytest.approx(1.0, abs=0.01)
    p = inlier.mean()
    assert significance[0] == pytest.approx(n * math.sin(math.pi * p) ** 2 / (math.pi**2 * p * (1 - p)), rel=0.02)


def test_star_pattern_without_a_pattern_is_noise():
    """Inliers drawn independently of the angle: Z is exponential with mean 1 (P(Z > t) = exp(-t)), so over
    2000 rings its mean is 1 within 4 standard errors and about exp(-3) = 5 % exceed 3; every sample an inlier
    (a plain wall) gives 0."""
    rng = np.random.default_rng(1)
    rings, n = 2000, 400
    ring = np.repeat(np.arange(rings), n)
    angle = rng.uniform(0, 2 * math.pi, rings * n)
    depth, significance = star_pattern(ring, angle, rng.random(rings * n) < 0.7, 72)
    assert significance.mean() == pytest.approx(1.0, abs=4 / math.sqrt(rings))
    assert (significance > 3).mean() == pytest.approx(math.exp(-3), abs=4 * math.sqrt(math.exp(-3) / rings))
    assert np.median(depth) < 0.1
    wall_depth, wall_significance = star_pattern(ring, angle, np.ones(rings * n, bool), 72)
    assert not wall_depth.any() and not wall_significance.any()


def simulated_wall(camera: str, distance_mm: float) -> np.ndarray:
    """The camera's simulated wall, with flying pixels on a ToF camera (outliers off the plane)."""
    effects = "" if camera == "d455" else "[effects.flying_pixels]\n"
    model = parse_model(f'camera = "{camera}"\n{effects}', "test model")
    x, y, z, *_ = simulate_frame(model, "wall", {}, distance_mm=distance_mm)
    return np.dstack([x, y, z])


@pytest.mark.parametrize("camera,distance_mm,segments", [("blaze101", 1000.0, 72), ("flexx2", 600.0, 24),
                                                         ("d455", 2500.0, 72)])
def test_a_plain_wall_is_no_star(camera, distance_mm, segments):
    """A simulated wall: every sample is on the plane, nothing alternates, so no star is reported there."""
    result = analyze_boehler(simulated_wall(camera, distance_mm), segments, binning=None)
    assert not result.star_found and result.modulation == 0.0
    assert any(w.startswith(f"no {segments}-segment star found: no ring on the plane at") for w in result.warnings)
    assert math.isnan(result.resolution_mm)


@pytest.mark.parametrize("segments,size", [(72, (640, 480)), (24, (640, 480)), (72, (160, 120))])
def test_a_star_is_found_with_the_depth_of_sharp_segments(segments, size):
    """Ray-cast stars with sharp segments: the resolved rings alternate fully (M about 1; the pixel grid of
    a coarse cloud moves a ring's M by some 20 %), and so does the simulated blaze-101's star."""
    result = analyze_boehler(star_cloud(segments, 0.0, 0.0, size=size), segments, binning=None)
    assert result.star_found and result.modulation == pytest.approx(1.0, abs=0.25)
    assert not any("star found" in w for w in result.warnings)
    simulated = analyze_boehler(simulated_star("[effects.defocus]\nhyperfocal_mm = 400.0\n"), 72)
    assert simulated.star_found and simulated.modulation == pytest.approx(1.0, abs=0.25)


def test_a_star_blurred_into_a_disc_is_not_found_but_explained():
    """Segments merged into a filled disc out to beyond the rim: a disc in front of the wall, no alternation."""
    result = analyze_boehler(star_cloud(72, 250.0, 250.0), 72)
    assert not result.star_found and result.modulation < MIN_MODULATION
    assert any("a plain wall, or a star whose segments this cloud resolves nowhere" in w for w in result.warnings)
