"""Sharpness over distance: plateau rule, best focus, imagery resolution, eq. 6-2 (Thesis 2024, 6.6)."""

import math

import numpy as np
import pytest

from metrics.sharpness import (
    best_focus_distance,
    hyperfocal_distance,
    ied_pixels,
    ied_pixels_at_centre,
    imagery_resolution_deg,
    lateral_mm,
    plateau,
    sharpness_peak_at_sweep_end,
)


def focus_curve(distances, hyperfocal):
    """A lens focused at infinity: SFR area falls as 1 / (1 + (H / d)^4) below H."""
    d = np.asarray(distances, float)
    return 0.45 / (1 + 0.111 * (hyperfocal / d) ** 4)  # 0.1111: 90 % of the plateau exactly at H


def test_hyperfocal_is_the_left_edge_of_the_plateau():
    d = np.arange(100, 3001, 100)
    area = focus_curve(d, 600)
    valid = np.ones(d.size, bool)
    assert area[5] / plateau(d, area, valid) == pytest.approx(0.9, abs=0.01)
    assert hyperfocal_distance(d, area, valid) == 600


def test_a_dip_below_90_percent_restarts_the_plateau():
    d = np.arange(100, 2001, 100)
    area = np.full(d.size, 0.4)
    area[:2] = 0.1
    area[6] = 0.3  # a blurred outlier at 700 mm: the plateau only starts after it
    assert hyperfocal_distance(d, area, np.ones(d.size, bool)) == 800


def test_invalid_positions_are_ignored():
    d = np.arange(100, 1501, 100)
    area = focus_curve(d, 400)
    valid = np.ones(d.size, bool)
    valid[4] = False
    area[4] = 0.0  # a clipped position does not break the plateau
    assert hyperfocal_distance(d, area, valid) == 400
    assert math.isnan(hyperfocal_distance(d, area, np.zeros(d.size, bool)))


def test_best_focus_is_the_nearest_distance_within_5_pct_of_the_smoothed_maximum():
    d = np.arange(100, 1601, 100)
    area = np.linspace(0.2, 0.4, d.size)
    area[8] = 0.5  # a lone spike is smoothed away
    area[12:15] = [0.44, 0.47, 0.46]
    # smoothed: ... 0.44 at 1300, 0.46 at 1400, 0.46 at 1500: 0.95 * 0.46 = 0.437 -> 1300 is the nearest
    assert best_focus_distance(d, area, np.ones(d.size, bool)) == 1300
    # with no tolerance only the maximum counts (1400 and 1500 tie; the nearer wins)
    assert best_focus_distance(d, area, np.ones(d.size, bool), tolerance=0.0) == 1400


def test_a_peak_at_the_end_of_the_sweep_is_reported():
    d = np.arange(100, 1501, 100)
    rising = np.linspace(0.1, 0.5, d.size)
    ok = np.ones(d.size, bool)
    assert sharpness_peak_at_sweep_end(d, rising, ok) == "far"
    assert sharpness_peak_at_sweep_end(d, rising[::-1], ok) == "near"
    assert sharpness_peak_at_sweep_end(d, focus_curve(d, 400) * np.r_[np.ones(10), np.linspace(1, 0.7, 5)], ok) is None
    far_invalid = ok.copy()
    far_invalid[-3:] = False  # the last valid position counts as the end
    assert sharpness_peak_at_sweep_end(d, rising, far_invalid) == "far"


def test_imagery_resolution_and_lateral_size():
    assert imagery_resolution_deg(0.102, 0.5) == pytest.approx(0.204)
    assert math.isnan(imagery_resolution_deg(0.1, 0.0))
    assert lateral_mm(0.23, 600) == pytest.approx(2.41, abs=0.01)


@pytest.mark.parametrize("res,distance,pixels", [
    (0.102, 400, 88),   # Blaze101 at 40 cm (Thesis 2024, 6.6: about 88 px)
    (0.105, 600, 57),   # AM-T100 at 60 cm (about 57 px)
    (0.25, 200, 72),    # flexx2 at 20 cm (about 72 px)
    (0.122, 500, 59),   # RealSense at 50 cm, corrected FOV 78 deg (about 59 px)
])
def test_ied_coverage_of_thesis_6_6(res, distance, pixels):
    assert ied_pixels(res, distance) == pytest.approx(pixels, abs=1.0)


def test_ied_at_the_image_centre_with_the_pinhole_model():
    """blaze-101 (640 px, 67 deg) at 400 mm: f = 320 / tan(33.5 deg) = 483.5 px, so 62.5 mm span 75.5 px,
    where the mean angular pixel size (67 / 640 deg) gives 85.5 px."""
    assert ied_pixels_at_centre(67.0, 640, 400.0) == pytest.approx(75.5, abs=0.1)
    assert ied_pixels(67.0 / 640, 400.0) == pytest.approx(85.5, abs=0.1)
    # a narrow field of view: both agree (tan x ~ x)
    assert ied_pixels_at_centre(2.0, 1000, 5000.0) == pytest.approx(ied_pixels(2.0 / 1000, 5000.0), rel=1e-3)
