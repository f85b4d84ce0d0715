"""Known answers from Thesis 2024, reproduced by the simulator (docs/simulation.md)."""

import math

import numpy as np
import pytest

from metrics.optics import pixel_aspect_distortion_pct, sensor_angular_resolution_deg
from sim.geometry import Pose
from sim.model import default_model_text, parse_model
from sim.optics import depth_of_field_mm
from sim.profiles import PROFILES, SOURCES
from sim.render import render
from sim.scenes.targets import build_scene, plate_scene
from sim.tof import ToFSensor, surface_properties

# Thesis 2024, Table 6-2 (sensor resolution, deg) and Table 6-5 row 1 (pixel aspect distortion, %)
TABLE_6_2 = {"blaze101": (0.105, 0.106), "amt100": (0.105, 0.106), "flexx2": (0.25, 0.256), "d455": (0.117, 0.129)}
TABLE_6_5_ROW_1 = {"blaze101": 1.5, "amt100": 1.5, "flexx2": 2.3, "d455": 10.2}


@pytest.mark.parametrize("name", sorted(PROFILES))
def test_sensor_angular_resolution_matches_table_6_2(name):
    p = PROFILES[name]
    h, v = TABLE_6_2[name]
    assert sensor_angular_resolution_deg(p.fov_h_deg, p.width) == pytest.approx(h, abs=0.0006)
    assert sensor_angular_resolution_deg(p.fov_v_deg, p.height) == pytest.approx(v, abs=0.0006)


@pytest.mark.parametrize("name", sorted(PROFILES))
def test_pixel_aspect_distortion_matches_table_6_5(name):
    p = PROFILES[name]
    assert pixel_aspect_distortion_pct(p.fov_h_deg, p.fov_v_deg, p.width, p.height) == pytest.approx(
        TABLE_6_5_ROW_1[name], abs=0.06)


def test_corrected_fovs_of_table_6_2():
    """Thesis 2024's corrected FOVs: blaze 65 x 51 -> 0.102 deg, D455 78 x 62 -> 0.122 deg (bracketed values)."""
    assert sensor_angular_resolution_deg(65.0, 640) == pytest.approx(0.102, abs=0.0006)
    assert sensor_angular_resolution_deg(78.0, 640) == pytest.approx(0.122, abs=0.0006)


@pytest.mark.parametrize("name", sorted(PROFILES))
def test_every_profile_number_has_a_source(name):
    text = " ".join(SOURCES[name].keys())
    for field in ("width", "fov", "wavelength", "frame_rate", "noise_mm_at_2m", "hyperfocal_mm", "lens_sigma_px"):
        assert field in text, f"{name}: no source for {field}"


def test_depth_of_field_of_figure_5_4():
    """f = 8 mm, focus 150 mm, CoC 5.3 um: about 147-154 mm at f/2 and 137-166 mm at f/8 (Thesis 2024, Fig. 5-4, eq. 2-5)."""
    near, far = depth_of_field_mm(8.0, 150.0, 0.0053, 2.0)
    assert (round(near), round(far)) == (147, 154)
    near, far = depth_of_field_mm(8.0, 150.0, 0.0053, 8.0)
    assert (round(near), round(far)) == (137, 166)


def sensor(camera="blaze101", effects=""):
    model = parse_model(default_model_text(camera) + effects)
    return ToFSensor(model.profile(), model.effect_params())


def test_34_by_25_tiles_of_19_mm_visible_at_500_mm():
    """67 x 51 deg at 500 mm sees 2 d tan(FOV/2) / 19 mm = 34.8 x 25.1 tiles: count them in the image."""
    s = sensor()
    prep = s.prepare(build_scene("checkerboard", {}, 940.0, 500.0), Pose.at_origin(), 1000.0, 0, 0)
    image = prep.amplitude
    row = image[240] > np.median(image[240])
    col = image[:, 320] > np.median(image[:, 320])
    # each tile boundary crossing the centre row/column flips the binary profile
    across, down = np.count_nonzero(np.diff(row)), np.count_nonzero(np.diff(col))
    expected = (2 * 500 * math.tan(math.radians(33.5)) / 19, 2 * 500 * math.tan(math.radians(25.5)) / 19)
    assert expected == pytest.approx((34.8, 25.1), abs=0.05)
    assert across in (34, 35) and down in (24, 25, 26)


@pytest.mark.parametrize("delta,e", [(20.0, 0.0), (0.0, 20.0), (20.0, -15.0)])
def test_misalignment_geometry_of_figure_5_15(delta, e):
    """Centre pixel on the robot circle: R + delta / cos(theta) - e tan(theta) (Thesis 2024, 5.4.2)."""
    radius = 850.0
    cam = sensor()
    for theta in range(-80, 81, 10):
        pose = Pose.on_circle(theta, radius, e)
        scene = plate_scene("ptfe", 940.0, plate_mm=3000.0, offset_mm=delta)
        r = render(scene, pose, cam.geometry.optics, surface_properties(scene, {}), supersample=1)
        h, w = r.range_dom.shape
        # the centre of the 640 x 480 grid lies between pixels: average the four central ones
        centre = r.range_dom[h // 2 - 1 : h // 2 + 1, w // 2 - 1 : w // 2 + 1].mean()
        expected = radius + delta / math.cos(math.radians(theta)) - e * math.tan(math.radians(theta))
        assert centre == pytest.approx(expected, abs=0.05), theta


def test_misalignment_numbers_quoted_in_spec():
    """20 mm: +95 mm at 80 deg relative to 0 deg (target), -113 mm at 80 deg (camera axis)."""
    assert 20 / math.cos(math.radians(80)) - 20 == pytest.approx(95.2, abs=0.1)
    assert 20 * math.tan(math.radians(80)) == pytest.approx(113.4, abs=0.1)
