"""Scene primitives: the compiled caster equals the numpy definition of every texture and shape."""

import numpy as np
import pytest

from metrics.optics import Pinhole
from sim.geometry import Pose
from sim.scenes.base import Hit, Scene
from sim.scenes.targets import build_scene


@pytest.mark.parametrize("target,params,distance", [
    ("wall", {}, 1500.0),
    ("slanted_edge", {"angle_deg": 8.0, "offset_mm": (12.0, -5.0)}, 900.0),
    ("white_sheet", {}, 900.0),
    ("checkerboard", {"tile_mm": 19.0}, 700.0),
    ("boehler_star", {"segments": 72, "gap_mm": 250.0, "rotation_deg": 3.0, "offset_mm": (8.0, -5.0)}, 1200.0),
])
@pytest.mark.parametrize("pose", [Pose.at_origin(), Pose.at_origin(tilt_x_deg=3.0, tilt_y_deg=-4.0)])
def test_compiled_caster_matches_numpy_planes(target, params, distance, pose):
    scene = build_scene(target, params, 940.0, distance)
    rays = Pinhole(96, 72, 67.0, 51.0).unit_rays
    origin, dirs = pose.rays(rays)
    fast = scene.cast(origin, dirs)
    slow = Hit.empty(dirs.shape[1:])
    for index, surface in enumerate(scene.surfaces):
        t, cos, reflectance = surface.intersect(origin, dirs)
        nearer = t < slow.t
        slow.t = np.where(nearer, t, slow.t)
        slow.cos = np.where(nearer, cos, slow.cos)
        slow.reflectance = np.where(nearer, reflectance, slow.reflectance)
        slow.surface = np.where(nearer, index, slow.surface)
    np.testing.assert_allclose(fast.t, slow.t, rtol=1e-12)
    np.testing.assert_allclose(fast.cos, slow.cos, rtol=1e-12)
    np.testing.assert_array_equal(fast.reflectance, slow.reflectance)
    np.testing.assert_array_equal(fast.surface, slow.surface)


def test_star_has_half_its_wedges_and_a_disc():
    scene = build_scene("boehler_star", {"segments": 24, "gap_mm": 300.0}, 940.0, 1300.0)
    star = scene.surfaces[0]
    angles = np.linspace(0, 2 * np.pi, 24 * 50, endpoint=False) + 1e-6
    ring = star.shape(60 * np.cos(angles), 60 * np.sin(angles))
    assert ring.mean() == pytest.approx(0.5, abs=0.01)
    assert np.count_nonzero(np.diff(ring.astype(int)) != 0) == 23  # 24 wedges -> 24 flips around (one at the seam)
    assert star.shape(np.array([3.0]), np.array([-2.0]))[0]  # inside the 10 mm disc
    assert not star.shape(np.array([210.0]), np.array([0.0]))[0]


def test_empty_scene_hits_nothing():
    rays = Pinhole(8, 6, 60.0, 45.0).unit_rays
    hit = Scene().cast(np.zeros(3), rays)
    assert np.isinf(hit.t).all() and (hit.surface == -1).all()


def test_ball_bar_spheres_are_exact():
    """Every ray that hits a sphere ends on it (|p - c| = r) at the near side, the cosine is that of the
    angle between the ray and the outward normal, the silhouette's half-angle is asin(r / |c|), and the
    centres are the given spacing apart along the bar's direction."""
    from sim.scenes.targets import ball_bar_centres

    params = {"diameter_mm": 50.0, "spacing_mm": 300.0, "gap_mm": 500.0, "orientation_deg": 30.0, "tilt_deg": 20.0}
    scene = build_scene("ball_bar", params, 940.0, 1500.0)
    first, second = ball_bar_centres(1500.0, 300.0, 500.0, 30.0, 20.0, (0.0, 0.0))
    assert np.linalg.norm(second - first) == pytest.approx(300.0)
    assert (second - first)[2] == pytest.approx(300.0 * np.sin(np.radians(20.0)))
    rays = Pinhole(400, 300, 40.0, 30.0).unit_rays
    hit = scene.cast(np.zeros(3), rays)
    for index, centre in enumerate((first, second)):
        on = hit.surface == index
        assert on.sum() > 100
        points = rays[:, on] * hit.t[on]
        np.testing.assert_allclose(np.linalg.norm(points.T - centre, axis=1), 25.0, atol=1e-9)
        normals = (points.T - centre) / 25.0
        np.testing.assert_allclose(hit.cos[on], -(normals * rays[:, on].T).sum(1), atol=1e-9)
        assert (hit.t[on] <= np.linalg.norm(centre)).all()  # the near side
        angles = np.arccos(np.clip((rays[:, on].T @ centre) / np.linalg.norm(centre), -1, 1))
        assert angles.max() <= np.arcsin(25.0 / np.linalg.norm(centre)) + 1e-12


def test_flat_plate_is_tilted_about_the_vertical():
    scene = build_scene("flat_plate", {"tilt_deg": 30.0, "gap_mm": 500.0}, 940.0, 1500.0)
    plate = scene.surfaces[0]
    assert abs(plate.normal @ np.array([0.0, 0.0, -1.0])) == pytest.approx(np.cos(np.radians(30.0)))
    assert abs(plate.normal[1]) < 1e-12
