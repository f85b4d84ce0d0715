"""Known answers for the VDI/VDE 2634-2 quantities: analytic spheres, a ball bar and flat plates."""

import math

import numpy as np
import pytest

from metrics.vdi2634 import (
    cap_mask,
    fit_flat,
    fit_sphere,
    fit_sphere_cap,
    flatness_error,
    probing_error_form,
    probing_error_size,
    sphere_spacing_error,
)


def cap_directions(n: int, half_angle_deg: float = 75.0) -> np.ndarray:
    """n unit vectors spread evenly (Fibonacci) over the cap around -z that a camera on the z axis sees."""
    k = np.arange(n) + 0.5
    cos_t = 1 - (1 - math.cos(math.radians(half_angle_deg))) * k / n
    phi = math.pi * (1 + 5**0.5) * k
    sin_t = np.sqrt(1 - cos_t**2)
    return np.column_stack([sin_t * np.cos(phi), sin_t * np.sin(phi), -cos_t])


def sphere_points(centre, radius, deviations):
    directions = cap_directions(len(deviations))
    return np.asarray(centre) + directions * (radius + deviations)[:, None]


def test_exact_sphere_is_recovered():
    fit = fit_sphere(sphere_points((10.0, -20.0, 1500.0), 25.0, np.zeros(5000)))
    assert fit.centre == pytest.approx([10.0, -20.0, 1500.0], abs=1e-6)
    assert fit.radius == pytest.approx(25.0, abs=1e-8)
    assert probing_error_form(fit) == pytest.approx(0.0, abs=1e-6)
    assert fit.n_excluded == 0


def test_form_is_the_range_of_known_radial_deviations_and_size_the_radius_error():
    """Radial deviations +-a in an alternating pattern on the sphere (mean 0): the fit keeps centre and
    radius, the form error is 2a; the sphere is 0.06 mm larger than calibrated: size error +0.12 mm."""
    a = 0.15
    deviations = a * np.where(np.arange(6000) % 2 == 0, 1.0, -1.0)
    fit = fit_sphere(sphere_points((0.0, 0.0, 1000.0), 25.03, deviations))
    assert probing_error_form(fit) == pytest.approx(2 * a, abs=0.002)
    assert probing_error_size(fit, 50.0) == pytest.approx(0.06, abs=0.002)
    assert fit.n_excluded == 0


def test_gaussian_radial_noise_gives_its_spread():
    """Uniform radial noise in [-a, a]: the form error approaches 2a, the size error 0."""
    rng = np.random.default_rng(1)
    a = 0.2
    fit = fit_sphere(sphere_points((0.0, 0.0, 800.0), 20.0, rng.uniform(-a, a, 20000)))
    assert probing_error_form(fit) == pytest.approx(2 * a, rel=0.01)
    assert probing_error_size(fit, 40.0) == pytest.approx(0.0, abs=0.01)
    assert np.std(fit.deviations) == pytest.approx(a / math.sqrt(3), rel=0.02)


def test_outliers_up_to_0_3_percent_are_left_out():
    """0.2 % of the points 5 mm off the surface: all left out, form and size as without them.
    1 % off: only 0.3 % may be left out, so the form error shows the rest."""
    rng = np.random.default_rng(2)
    n = 10000
    base = rng.uniform(-0.05, 0.05, n)
    clean = fit_sphere(sphere_points((0, 0, 1000.0), 25.0, base))
    few = base.copy()
    few[rng.choice(n, 20, replace=False)] += 5.0
    fit = fit_sphere(sphere_points((0, 0, 1000.0), 25.0, few))
    assert fit.n_excluded == 20
    assert probing_error_form(fit) == pytest.approx(probing_error_form(clean), abs=1e-3)
    assert fit.radius == pytest.approx(clean.radius, abs=1e-3)
    many = base.copy()
    many[rng.choice(n, 100, replace=False)] += 5.0
    fit = fit_sphere(sphere_points((0, 0, 1000.0), 25.0, many))
    assert fit.n_excluded == 30
    assert probing_error_form(fit) > 4.0


def test_ball_bar_spacing_error():
    """Two spheres 300.25 mm apart measured, 300.00 mm calibrated: SD = +0.25 mm, in any orientation."""
    rng = np.random.default_rng(3)
    for direction in ((1, 0, 0), (0, 1, 0), (1, 1, 1)):
        u = np.asarray(direction, float) / np.linalg.norm(direction)
        c1 = np.array([0.0, 0.0, 1200.0]) - 150.125 * u
        c2 = c1 + 300.25 * u
        first = fit_sphere(sphere_points(c1, 19.05, rng.normal(0, 0.02, 4000)))
        second = fit_sphere(sphere_points(c2, 19.05, rng.normal(0, 0.02, 4000)))
        assert sphere_spacing_error(first, second, 300.0) == pytest.approx(0.25, abs=0.005)


def test_flatness_of_a_known_peak_to_valley():
    """A plate tilted 30 deg with a cosine waviness of 0.4 mm peak to valley (even in u on a grid symmetric
    about 0, so uncorrelated with u and v: the least-squares plane is parallel to the plate): F = 0.4 mm."""
    u, v = np.meshgrid(np.linspace(-200, 200, 201), np.linspace(-150, 150, 151))
    w = 0.2 * np.cos(2 * np.pi * u / 100.0)
    tilt = math.radians(30.0)
    e1 = np.array([math.cos(tilt), 0.0, math.sin(tilt)])
    e2 = np.array([0.0, 1.0, 0.0])
    n = np.cross(e1, e2)
    points = (np.array([0.0, 0.0, 1500.0]) + u.reshape(-1, 1) * e1 + v.reshape(-1, 1) * e2
              + w.reshape(-1, 1) * n)
    fit = fit_flat(points)
    assert flatness_error(fit) == pytest.approx(0.4, abs=1e-3)
    assert abs(fit.normal @ n) == pytest.approx(1.0, abs=1e-9)


def pinhole_view(centre, radius: float, pixel_rad: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A camera at the origin with square pixels of ``pixel_rad`` looking at a sphere: per pixel whose ray meets
    it, the exact hit point, the incidence (deg) and how far (rad) the ray passes inside the silhouette."""
    centre = np.asarray(centre, float)
    distance = np.linalg.norm(centre)
    n = int(math.ceil(math.asin(radius / distance) / pixel_rad)) + 3
    a = np.arange(-n, n + 1) * pixel_rad
    ax, ay = np.meshgrid(a, a)
    rays = np.stack([np.tan(ax), np.tan(ay), np.ones_like(ax)], -1).reshape(-1, 3)
    rays = rays / np.linalg.norm(rays, axis=1)[:, None]
    rays = rays @ _rotation_to(centre / distance).T
    b = rays @ centre
    disc = b**2 - (distance**2 - radius**2)
    hit = disc >= 0
    t = b[hit] - np.sqrt(disc[hit])
    gamma = np.arccos(np.clip(b[hit] / distance, -1, 1))
    incidence = np.degrees(np.arcsin(np.clip(distance * np.sin(gamma) / radius, 0, 1)))
    return rays[hit] * t[:, None], incidence, math.asin(radius / distance) - gamma


def _rotation_to(axis: np.ndarray) -> np.ndarray:
    """Rotation taking +z onto ``axis`` (Rodrigues)."""
    z = np.array([0.0, 0.0, 1.0])
    v, c = np.cross(z, axis), float(z @ axis)
    if np.linalg.norm(v) < 1e-12:
        return np.eye(3)
    vx = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    return np.eye(3) + vx + vx @ vx / (1 + c)


def test_rim_rule_keeps_the_cap_of_its_definition():
    """cap_mask on the exact hits of a 25 mm sphere at 1 m off the axis, 0.1 deg pixels: exactly the pixels
    whose incidence is at most 60 deg and whose ray passes at least one pixel inside the silhouette."""
    pixel = math.radians(0.1)
    centre = np.array([150.0, -80.0, 1000.0])
    points, incidence, inside = pinhole_view(centre, 25.0, pixel)
    kept = cap_mask(points, centre, 25.0, 60.0, pixel)
    assert np.array_equal(kept, (incidence <= 60.0) & (inside >= pixel))
    assert 0 < kept.sum() < len(points)


def test_rim_rule_removes_the_mixed_rim():
    """The rim pixels of an area sensor mix the sphere with the wall behind it: here each pixel within one pixel
    outside the silhouette reports the sphere's tangent range along its own ray (outside the sphere), and the
    free fit's size error is positive by millimetres; the rim rule recovers the exact sphere (no noise: to
    1e-6 mm) and counts the points it left out."""
    pixel = math.radians(0.42)  # a 160 px wide sensor behind a 67 deg lens
    centre = np.array([-150.0, 20.0, 1000.0])
    points, _, _ = pinhole_view(centre, 25.0, pixel)
    rays = np.array([[math.tan(x), math.tan(y), 1.0] for x in np.arange(-40, 41) * pixel
                     for y in np.arange(-40, 41) * pixel])
    rays = rays / np.linalg.norm(rays, axis=1)[:, None]
    gamma = np.arccos(rays @ centre / np.linalg.norm(centre))
    silhouette = math.asin(25.0 / np.linalg.norm(centre))
    missing = (gamma > silhouette) & (gamma < silhouette + pixel)
    tangent = math.sqrt(np.linalg.norm(centre) ** 2 - 25.0**2)
    mixed = np.vstack([points, rays[missing] * tangent])
    assert probing_error_size(fit_sphere(mixed), 50.0) > 1.0
    fit = fit_sphere_cap(mixed, 25.0, 60.0, pixel)
    assert probing_error_size(fit, 50.0) == pytest.approx(0.0, abs=1e-6)
    assert fit.centre == pytest.approx(centre, abs=1e-6)
    assert fit.n_rim == len(mixed) - cap_mask(mixed, centre, 25.0, 60.0, pixel).sum() > len(mixed) - len(points)
