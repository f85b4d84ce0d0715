"""Known answers for the VDI/VDE 2634-2 quantities: analytic spheres, a ball bar and flat plates."""

import math

import numpy as np
import pytest

from metrics.vdi2634 import (
    fit_flat,
    fit_sphere,
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
