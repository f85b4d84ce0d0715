"""Single-capture summary on known scenes: a tilted noisy wall, a wall with a box, one frame."""

import math

import numpy as np
import pytest
from scipy.stats import chi2

from metrics.capture import summarize_capture


def pinhole_cloud(z: np.ndarray, f: float = 200.0):
    """x, y of organized depth stacks (N, H, W) for a pinhole camera with the principal point at the centre."""
    _, h, w = z.shape
    v, u = np.mgrid[0:h, 0:w]
    return z * (u - w // 2) / f, z * (v - h // 2) / f


def wall(n: int, h: int, w: int, distance: float, tilt_deg: float, sigma: float, seed: int = 0,
         f: float = 200.0) -> np.ndarray:
    """z of a wall tilted about y by tilt_deg (z = distance + tan(tilt) x), with per-frame noise sigma."""
    _, u = np.mgrid[0:h, 0:w]
    t = math.tan(math.radians(tilt_deg))
    z0 = distance / (1 - t * (u - w // 2) / f)  # ray z where z = distance + t x and x = z (u - cx) / f
    return z0[None] + np.random.default_rng(seed).standard_normal((n, h, w)) * sigma


def test_tilted_noisy_wall_is_planar_with_its_distance_tilt_and_noise():
    n, sigma = 30, 2.0
    z = wall(n, 60, 80, 1000.0, 10.0, sigma)
    z[:, :5, :] = np.nan  # five rows never valid
    z[: n // 3, 10, :] = np.nan  # a row valid in 2/3 of the frames: valid
    x, y = pinhole_cloud(z)
    s = summarize_capture(x, y, z)
    assert s.frames == n
    assert s.valid_fraction == pytest.approx(55 / 60)
    assert s.validity[10, 0] == pytest.approx(2 / 3) and s.validity[0, 0] == 0.0
    factor = [math.sqrt(chi2.ppf(q, n - 1) / (n - 1)) for q in (0.5, 0.9)]
    assert s.temporal_noise_median_mm == pytest.approx(sigma * factor[0], rel=0.05)
    assert s.temporal_noise_q90_mm == pytest.approx(sigma * factor[1], rel=0.05)
    plane = s.plane
    assert plane.planar and plane.inlier_fraction > 0.99
    assert plane.distance_on_axis_mm == pytest.approx(1000.0, abs=0.2)
    # z = 1000 + tan(10 deg) x: normal (-tan, 0, 1), turned away from +x by 10 deg
    assert plane.tilt_about_y_deg == pytest.approx(-10.0, abs=0.05)
    assert plane.tilt_about_x_deg == pytest.approx(0.0, abs=0.05)
    assert plane.rms_mm == pytest.approx(sigma / math.sqrt(n), rel=0.1)  # the mean of n frames


def test_a_box_in_front_of_the_wall_is_not_planar():
    z = wall(10, 60, 80, 1500.0, 0.0, 1.0, seed=1)
    z[:, 20:50, 20:60] -= 200.0  # a box 200 mm in front: 25 % of the image
    x, y = pinhole_cloud(z)
    s = summarize_capture(x, y, z)
    assert not s.plane.planar and s.plane.inlier_fraction < 0.95
    assert s.depth_q05_mm == pytest.approx(1300.0, abs=5) and s.depth_q95_mm == pytest.approx(1500.0, abs=5)


def test_one_frame_has_depth_and_plane_but_no_temporal_noise():
    z = wall(1, 40, 50, 800.0, 0.0, 0.5, seed=2)
    x, y = pinhole_cloud(z)
    s = summarize_capture(x, y, z, intensity=np.full(z.shape, 7.0))
    assert math.isnan(s.temporal_noise_q90_mm) and np.isnan(s.noise).all()
    assert s.valid_fraction == 1.0 and s.depth_median_mm == pytest.approx(800.0, abs=0.5)
    assert s.plane.planar and s.plane.distance_on_axis_mm == pytest.approx(800.0, abs=0.1)
    assert (s.intensity == 7.0).all()
