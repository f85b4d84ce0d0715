"""Checkerboard distortion and pixel aspect ratio (Thesis 2024, 5.2, 6.4, Table 6-5).

Known answers: boards rendered by the simulator (tested in tests/sim) with a
known radial coefficient k1 and a known true FOV, against the formulas worked
out here. The simulated board lies at z = D - 0.2 mm with a tile corner on the
optical axis (shifted by ``offset_mm``); a board point (X, Y) images at
u_u = c_x + f_x X / z, v_u = c_y + f_y Y / z with the true FOV's
f = (W/2) / tan(FOV/2) and c at the image centre, and appears at
r_d = r_u (1 + k1 (r_u / R)^2), R = half the image diagonal (Thesis 2024, eq. 5-5).
A ToF camera reports the measured range r = |(X, Y, z)| along the ray of the
pixel it sees the point in: the distorted one (``cloud = true``) or the true
one (``cloud = false``).

Tolerance: 0.3 % of the image length (Thesis 2024, 5.2 target) on every distortion,
0.5 deg on the FOV. Corner detection is good to about 0.1 px (0.02 % of
640 px, 0.06 % of 172 px), so the margin covers blur and noise at the
border; the effects tested are 1.5-4.5 %, ten times the tolerance.
"""

import math

import cv2
import numpy as np
import pytest

from metrics.distortion import (
    Corners,
    bilinear_samples,
    cloud_distortion,
    detect_corners,
    distortion,
    pixel_aspect_distortion_pct,
    pixel_aspect_ratio,
    sample_cloud,
)
from sim.model import default_model_text, parse_model
from sim.preview import simulate_frame
from sim.profiles import PROFILES

TILE = 19.0
TOL_PCT = 0.3
TOL_FOV = 0.5


def render(camera, effects="", distance=600.0, params=None, overrides=""):
    model = parse_model(default_model_text(camera) + effects + overrides)
    frame = simulate_frame(model, "checkerboard", {"tile_mm": TILE, **(params or {})}, distance_mm=distance,
                           projector=False)
    return model.profile(), frame


def signed_max_pct(dev, outward, length):
    """EBU Tech 3249 sign: + when the largest displacement points outwards."""
    k = np.argmax(np.abs(dev))
    return math.copysign(100 * abs(dev[k]) / length, dev[k] * outward[k])


class Board:
    """The formulas of the module docstring for the corners of index ``ij`` (origin corner at world ``origin``)."""

    def __init__(self, width, height, fov_true, k1, z, ij, origin=(0.0, 0.0)):
        self.w, self.h, self.z = width, height, z
        self.fx = (width / 2) / math.tan(math.radians(fov_true[0]) / 2)
        self.fy = (height / 2) / math.tan(math.radians(fov_true[1]) / 2)
        self.cx, self.cy, big_r = (width - 1) / 2, (height - 1) / 2, math.hypot(width, height) / 2
        self.ij = ij
        self.X, self.Y = origin[0] + ij[:, 0] * TILE, origin[1] + ij[:, 1] * TILE
        self.uu, self.vu = self.cx + self.fx * self.X / z, self.cy + self.fy * self.Y / z
        s = 1 + k1 * ((self.uu - self.cx) ** 2 + (self.vu - self.cy) ** 2) / big_r**2
        self.ud, self.vd = self.cx + (self.uu - self.cx) * s, self.cy + (self.vu - self.cy) * s
        self.o = np.flatnonzero((ij == 0).all(axis=1))[0]

    def raw_pct(self, fov_given, distance):
        """found - (centre corner + index x tile f_given / distance), Thesis 2024, Table 6-5."""
        fx = (self.w / 2) / math.tan(math.radians(fov_given[0]) / 2)
        fy = (self.h / 2) / math.tan(math.radians(fov_given[1]) / 2)
        eu = self.ud[self.o] + self.ij[:, 0] * TILE * fx / distance
        ev = self.vd[self.o] + self.ij[:, 1] * TILE * fy / distance
        return (signed_max_pct(self.ud - eu, eu - self.ud[self.o], self.w),
                signed_max_pct(self.vd - ev, ev - self.vd[self.o], self.h))

    def radial_pct(self):
        return (signed_max_pct(self.ud - self.uu, self.uu - self.cx, self.w),
                signed_max_pct(self.vd - self.vu, self.vu - self.cy, self.h))

    def cloud_pct(self, fov_given, distorted_rays):
        u, v = (self.ud, self.vd) if distorted_rays else (self.uu, self.vu)
        tx, ty = (u - self.cx) / self.fx, (v - self.cy) / self.fy
        r = np.sqrt(self.X**2 + self.Y**2 + self.z**2) / np.sqrt(1 + tx**2 + ty**2)
        x, y = r * tx, r * ty
        ex, ey = x[self.o] + self.ij[:, 0] * TILE, y[self.o] + self.ij[:, 1] * TILE
        width = 2 * self.z * math.tan(math.radians(fov_given[0]) / 2)
        height = 2 * self.z * math.tan(math.radians(fov_given[1]) / 2)
        return (signed_max_pct(x - ex, ex - x[self.o], width), signed_max_pct(y - ey, ey - y[self.o], height))


# --------------------------------------------------------------------------------------- aspect ratio
def test_pixel_aspect_distortion_is_thesis_table_6_5():
    """Row 1 of Table 6-5 (0 / 1.5, 1.5, 2.3, 10.2 %) and the ratios of Table 6-2."""
    table = {"blaze101": (1.5, 1.015), "amt100": (1.5, 1.015), "flexx2": (2.3, 1.023), "d455": (10.2, 1.102)}
    for name, (pct, ratio) in table.items():
        p = PROFILES[name]
        assert pixel_aspect_distortion_pct(p.fov_h_deg, p.fov_v_deg, p.width, p.height) == pytest.approx(pct, abs=0.05)
        assert pixel_aspect_ratio(p.fov_h_deg, p.fov_v_deg, p.width, p.height) == pytest.approx(ratio, abs=5e-4)
    # with the corrected FOV of Table 6-2's brackets: blaze-101 65 x 51 -> 1:1.046, D455 78 x 62 -> 1:1.06
    assert pixel_aspect_ratio(65, 51, 640, 480) == pytest.approx(1.046, abs=5e-4)
    assert pixel_aspect_ratio(78, 62, 640, 480) == pytest.approx(1.06, abs=5e-3)


# --------------------------------------------------------------------------------------- intensity image
def test_perfect_pinhole_board_shows_no_distortion():
    """A distortion-free camera reads ~0 %; the angular pixel size FOV/W as spacing would read several %."""
    p, (*_, intensity, _) = render("blaze101")
    corners = detect_corners(intensity)
    result = distortion(corners, TILE, 599.8, (p.fov_h_deg, p.fov_v_deg))
    for value in (result.raw_distortion_w_pct, result.raw_distortion_h_pct, result.radial_distortion_w_pct,
                  result.radial_distortion_h_pct):
        assert abs(value) < 0.1
    assert result.fov_estimate_deg == pytest.approx((67.0, 51.0), abs=0.1)
    assert abs(result.k1) < 0.003 and result.fit_rms_px < 0.3 and not result.warnings
    angular = TILE / (599.8 * math.tan(math.radians(p.fov_h_deg / p.width)))  # the mistake Thesis 2024, 5.2 warns of
    wrong = corners.centre_uv[0] + corners.ij[:, 0] * angular
    assert 100 * np.max(np.abs(corners.uv[:, 0] - wrong)) / p.width > 3.0


CASES = {
    "barrel": ("[effects.radial_distortion]\nk1 = -0.08\n", -0.08, None, True),
    "pincushion, corrected cloud": ("[effects.radial_distortion]\nk1 = 0.06\ncloud = false\n", 0.06, None, False),
    "fov error": ("[effects.fov_error]\nfov_deg = [65.0, 51.0]\n", 0.0, (65.0, 51.0), False),
    "barrel and fov error": ("[effects.radial_distortion]\nk1 = -0.05\n[effects.fov_error]\nfov_deg = [65.0, 50.0]\n",
                             -0.05, (65.0, 50.0), True),
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_known_k1_and_fov_give_the_analytic_distortion(case):
    effects, k1, fov_true, cloud_distorted = CASES[case]
    p, (x, y, z, intensity, _) = render("blaze101", effects)
    fov = (p.fov_h_deg, p.fov_v_deg)
    corners = detect_corners(intensity)
    result = distortion(corners, TILE, 599.8, fov)
    board = Board(p.width, p.height, fov_true or fov, k1, 599.8, corners.ij)
    assert np.median(np.hypot(corners.uv[:, 0] - board.ud, corners.uv[:, 1] - board.vd)) < 0.2
    raw, radial = board.raw_pct(fov, 599.8), board.radial_pct()
    measured_raw = (result.raw_distortion_w_pct, result.raw_distortion_h_pct)
    measured_radial = (result.radial_distortion_w_pct, result.radial_distortion_h_pct)
    assert measured_raw == pytest.approx(raw, abs=TOL_PCT), case
    assert measured_radial == pytest.approx(radial, abs=TOL_PCT), case
    assert result.fov_estimate_deg == pytest.approx(fov_true or fov, abs=TOL_FOV)
    assert result.k1 == pytest.approx(k1, abs=0.005)
    assert max(map(abs, raw + radial)) > 1.5  # the effect is well above the tolerance
    in_cloud = cloud_distortion(np.dstack([x, y, z]), corners, TILE, fov)
    expected_cloud = board.cloud_pct(fov, cloud_distorted)
    assert (in_cloud.distortion_w_pct, in_cloud.distortion_h_pct) == pytest.approx(expected_cloud, abs=TOL_PCT)
    assert (fov_true is not None) == any("FOV" in w for w in result.warnings)


def origin_corner(width, height, fov, k1, z, offset, span):
    """World (X, Y) of the board corner imaged nearest the image centre; corners at offset + (m, n) tiles."""
    m, n = np.meshgrid(np.arange(-span[0], span[0] + 1), np.arange(-span[1], span[1] + 1))
    every = Board(width, height, fov, k1, z, np.column_stack([m.ravel(), n.ravel()]), offset)
    k = np.argmin(np.hypot(every.ud - every.cx, every.vd - every.cy))
    return offset[0] + every.ij[k, 0] * TILE, offset[1] + every.ij[k, 1] * TILE


def test_board_not_filling_the_image_offset_from_the_axis():
    """A 20 x 14 tile board off centre: exactly its 19 x 13 inner corners, with the analytic distortion;
    the classic detector, given the board's size, finds the same corners."""
    offset = (102.0, -33.0)
    params = {"board_mm": (20 * TILE, 14 * TILE), "offset_mm": offset}
    p, (*_, intensity, _) = render("blaze101", "[effects.radial_distortion]\nk1 = -0.06\n", params=params)
    corners = detect_corners(intensity)
    assert len(corners.uv) == 19 * 13 and np.ptp(corners.ij, axis=0).tolist() == [18, 12]
    origin = origin_corner(p.width, p.height, (67, 51), -0.06, 599.8, offset, (9, 6))
    board = Board(p.width, p.height, (67, 51), -0.06, 599.8, corners.ij, origin)
    assert np.median(np.hypot(corners.uv[:, 0] - board.ud, corners.uv[:, 1] - board.vd)) < 0.2
    result = distortion(corners, TILE, 599.8, (67, 51))
    raw, radial = board.raw_pct((67, 51), 599.8), board.radial_pct()
    assert (result.raw_distortion_w_pct, result.raw_distortion_h_pct) == pytest.approx(raw, abs=TOL_PCT)
    assert (result.radial_distortion_w_pct, result.radial_distortion_h_pct) == pytest.approx(radial, abs=TOL_PCT)
    assert result.fov_estimate_deg == pytest.approx((67, 51), abs=TOL_FOV)
    assert any("cover only" in w for w in result.warnings)
    classic = detect_corners(intensity, pattern=(19, 13))
    assert classic.detector == "classic" and corners.detector == "sector-based"
    order = np.lexsort(corners.ij.T), np.lexsort(classic.ij.T)
    np.testing.assert_array_equal(corners.ij[order[0]], classic.ij[order[1]])
    np.testing.assert_allclose(corners.uv[order[0]], classic.uv[order[1]], atol=0.05)


def test_board_cut_by_the_image_border():
    """The board's left edge stands 93 mm left of the axis; it runs off the other three borders."""
    offset = (507.0, 0.0)  # the 1200 x 900 mm board spans x = -93 ... 1107 mm
    p, (*_, intensity, _) = render("blaze101", "[effects.radial_distortion]\nk1 = 0.05\n",
                                   params={"offset_mm": offset})
    corners = detect_corners(intensity)
    left_edge_u = (p.width - 1) / 2 - (p.width / 2) / math.tan(math.radians(33.5)) * 93.0 / 599.8
    assert left_edge_u < corners.uv[:, 0].min() < left_edge_u + 17 and corners.uv[:, 0].max() > p.width - 10
    assert corners.uv[:, 1].min() < 10 and corners.uv[:, 1].max() > p.height - 10
    origin = origin_corner(p.width, p.height, (67, 51), 0.05, 599.8, offset, (30, 22))
    assert origin == (-6.0, 0.0)
    board = Board(p.width, p.height, (67, 51), 0.05, 599.8, corners.ij, origin)
    assert np.median(np.hypot(corners.uv[:, 0] - board.ud, corners.uv[:, 1] - board.vd)) < 0.2
    result = distortion(corners, TILE, 599.8, (67, 51))
    assert (result.raw_distortion_w_pct, result.raw_distortion_h_pct) == pytest.approx(
        board.raw_pct((67, 51), 599.8), abs=TOL_PCT)
    assert (result.radial_distortion_w_pct, result.radial_distortion_h_pct) == pytest.approx(
        board.radial_pct(), abs=TOL_PCT)
    assert result.k1 == pytest.approx(0.05, abs=0.005)


def test_blurred_low_resolution_board():
    """flexx2 (224 x 172) with its lens blur tripled (sigma 1.2 px) on 6.7 px tiles: every corner to the
    border, the analytic distortion and the true FOV."""
    p, (x, y, z, intensity, _) = render("flexx2", "[effects.radial_distortion]\nk1 = -0.06\n",
                                        overrides="[camera_overrides]\nlens_sigma_px = 1.2\n")
    corners = detect_corners(intensity)
    assert corners.uv[:, 0].min() < 8 and corners.uv[:, 0].max() > p.width - 9
    assert corners.uv[:, 1].min() < 8 and corners.uv[:, 1].max() > p.height - 9
    result = distortion(corners, TILE, 599.8, (56, 44))
    board = Board(p.width, p.height, (56, 44), -0.06, 599.8, corners.ij)
    assert (result.raw_distortion_w_pct, result.raw_distortion_h_pct) == pytest.approx(
        board.raw_pct((56, 44), 599.8), abs=TOL_PCT)
    assert (result.radial_distortion_w_pct, result.radial_distortion_h_pct) == pytest.approx(
        board.radial_pct(), abs=TOL_PCT)
    assert result.fov_estimate_deg == pytest.approx((56, 44), abs=TOL_FOV)
    in_cloud = cloud_distortion(np.dstack([x, y, z]), corners, TILE, (56, 44))
    assert (in_cloud.distortion_w_pct, in_cloud.distortion_h_pct) == pytest.approx(
        board.cloud_pct((56, 44), True), abs=TOL_PCT)


def test_fit_separates_rotation_scale_and_k1_on_exact_corners():
    """Exact corners of a board turned by 2 deg, seen with a true FOV of 64 x 49 deg and k1 = 0.04."""
    i, j = np.meshgrid(np.arange(-15, 16), np.arange(-11, 12))
    ij = np.column_stack([i.ravel(), j.ravel()])
    t = math.radians(2.0)
    turned = np.column_stack([ij[:, 0] * math.cos(t) - ij[:, 1] * math.sin(t),
                              ij[:, 0] * math.sin(t) + ij[:, 1] * math.cos(t)])
    board = Board(640, 480, (64, 49), 0.04, 700.0, turned)
    corners = Corners(np.column_stack([board.ud, board.vd]), ij, (480, 640), "exact", (0.0, 0.0))
    result = distortion(corners, TILE, 700.0, (67, 51))
    assert result.fov_estimate_deg == pytest.approx((64, 49), abs=1e-6)
    assert result.k1 == pytest.approx(0.04, abs=1e-8) and result.rotation_deg == pytest.approx(2.0, abs=1e-6)
    assert (result.radial_distortion_w_pct, result.radial_distortion_h_pct) == pytest.approx(board.radial_pct())
    assert result.linear_scale[0] == pytest.approx(math.tan(math.radians(33.5)) / math.tan(math.radians(32)))


def test_the_grid_does_not_depend_on_the_sector_detectors_random_start():
    """OpenCV's sector-based detector starts from random samples: on the flexx2's 6.7 px tiles one start in
    twelve returned a grid sheared by two tiles along u and one down, whose unit steps are only integer
    combinations of its own ((a + 2 b) / 4); the grown grid then skipped every other row. Every start now
    gives the same full board."""
    _, (*_, intensity, _) = render("flexx2")
    found = set()
    for seed in range(12):
        cv2.setRNGSeed(seed)
        corners = detect_corners(intensity)
        found.add((len(corners.uv), tuple(np.round(corners.tile_px, 1))))
    assert len(found) == 1
    (count, tile), = found
    assert tile == pytest.approx((6.7, 6.7), abs=0.15) and count > 800


def test_a_misplaced_corner_is_left_out_and_strong_distortion_is_not():
    """Exact corners of a strongly barrel-distorted board (k1 = -0.12: 8 px at the image corners) with
    0.05 px of noise, one border corner refined 2.5 px off its place: that corner alone is left out, and
    the distortion is the board's own."""
    i, j = np.meshgrid(np.arange(-15, 16), np.arange(-11, 12))
    ij = np.column_stack([i.ravel(), j.ravel()])
    board = Board(640, 480, (67, 51), -0.12, 700.0, ij)
    uv = np.column_stack([board.ud, board.vd]) + np.random.default_rng(4).normal(0, 0.05, (len(ij), 2))
    bad = int(np.flatnonzero((ij == (15, 3)).all(axis=1))[0])
    uv[bad, 0] += 2.5
    result = distortion(Corners(uv, ij, (480, 640), "exact", (0.0, 0.0)), TILE, 700.0, (67, 51))
    assert result.rejected_uv.tolist() == [uv[bad].tolist()] and len(result.found) == len(ij) - 1
    assert any("1 corner(s) left out" in w for w in result.warnings)
    assert result.k1 == pytest.approx(-0.12, abs=2e-3)
    assert (result.radial_distortion_w_pct, result.radial_distortion_h_pct) == pytest.approx(
        board.radial_pct(), abs=0.03)


@pytest.mark.parametrize("image", [np.full((120, 160), 500.0), np.random.default_rng(1).random((120, 160)),
                                   np.full((120, 160), np.nan)])
def test_no_board_is_an_error(image):
    with pytest.raises(ValueError, match="no checkerboard|no finite"):
        detect_corners(image)


def test_distortion_rejects_bad_geometry():
    corners = Corners(np.zeros((9, 2)), np.zeros((9, 2), int), (10, 10), "exact", (1.0, 1.0))
    with pytest.raises(ValueError, match="FOV"):
        distortion(corners, TILE, 600.0, (67.0, 190.0))
    with pytest.raises(ValueError, match="positive"):
        distortion(corners, 0.0, 600.0, (67.0, 51.0))


# --------------------------------------------------------------------------------------- point cloud
def test_sample_cloud_is_bilinear_and_respects_invalid_pixels():
    v, u = np.mgrid[0:6, 0:8].astype(float)
    cloud = np.dstack([3 * u - 2 * v, u * v, np.full_like(u, 500.0)])
    uv = np.array([[2.25, 3.5], [0.0, 0.0], [6.9, 4.99]])
    got = sample_cloud(cloud, uv)
    np.testing.assert_allclose(got[:, 0], 3 * uv[:, 0] - 2 * uv[:, 1])
    np.testing.assert_allclose(got[:, 1], uv[:, 0] * uv[:, 1])  # bilinear is exact on u v
    np.testing.assert_allclose(sample_cloud(cloud, np.array([[7.0, 5.0]])), [[21 - 10, 35, 500]])  # last pixel
    cloud[4, 7, 0] = np.nan  # one coordinate invalid: the whole point is
    got = sample_cloud(cloud, uv)
    assert np.isnan(got[2]).all() and np.isfinite(got[:2]).all()
    assert np.isnan(sample_cloud(cloud, np.array([[7.5, 1.0], [-0.1, 2.0], [2.0, 5.2]]))).all()


def test_bilinear_samples_of_a_stack_are_each_frames_own():
    """Frames along the last axis: each frame sampled as it alone would be, an invalid pixel voiding only its frame."""
    v, u = np.mgrid[0:6, 0:8].astype(float)
    frames = np.stack([3 * u - 2 * v, u * v, u + 0 * v], axis=-1)
    frames[4, 7, 1] = np.nan
    uv = np.array([[2.25, 3.5], [6.9, 4.99]])
    got = bilinear_samples(frames, uv)
    np.testing.assert_allclose(got[:, 0], 3 * uv[:, 0] - 2 * uv[:, 1])
    np.testing.assert_allclose(got[:, 2], uv[:, 0])
    assert np.isfinite(got[0, 1]) and np.isnan(got[1, 1])


def test_cloud_distortion_follows_the_clouds_axes_and_rejects_wrong_shapes():
    """A perfect cloud with y pointing up (real cameras differ) still reads 0 %."""
    i, j = np.meshgrid(np.arange(-4, 5), np.arange(-3, 4))
    ij = np.column_stack([i.ravel(), j.ravel()])
    uv = np.column_stack([49.5 + 10 * ij[:, 0] + 0.3, 39.5 + 10 * ij[:, 1] - 0.2])
    corners = Corners(uv, ij, (80, 100), "exact", (10.0, 10.0))
    v, u = np.mgrid[0:80, 0:100].astype(float)
    cloud = np.dstack([(u - 49.5) * TILE / 10, -(v - 39.5) * TILE / 10, np.full_like(u, 800.0)])
    result = cloud_distortion(cloud, corners, TILE, (60.0, 50.0))
    assert abs(result.distortion_w_pct) < 1e-9 and abs(result.distortion_h_pct) < 1e-9
    assert result.extent_mm[0] == pytest.approx(2 * 800 * math.tan(math.radians(30)))
    with pytest.raises(ValueError, match="H x W x 3"):
        cloud_distortion(cloud[:, :-1], corners, TILE, (60.0, 50.0))
    with pytest.raises(ValueError, match="valid cloud points"):
        cloud_distortion(np.full_like(cloud, np.nan), corners, TILE, (60.0, 50.0))
