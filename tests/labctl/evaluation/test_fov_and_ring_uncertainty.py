"""The uncertainties of the figures taken from the field of view and of the Böhler star's cloud resolution.

Known answers, derived here by hand rather than by the code's central differences:

* pixel aspect distortion P = 100 ((FOV_v / H) / (FOV_h / W) - 1): dP/dFOV_v = (P + 100) / FOV_v and
  dP/dFOV_h = -(P + 100) / FOV_h, each angle +-0.5 deg assumed, rectangular (u = 0.5 / sqrt(3) deg);
* inter-eye distance at the centre, 62.5 (W / 2) / tan(FOV_h / 2) / d pixels: its derivative by FOV_h (in rad)
  is -IED / sin(FOV_h), and it does not depend on FOV_v;
* the cloud resolution atan(2 pi r / (N d)) from the inner edge r of a ring of width w: the angle across the
  ring the figure lies in, atan(2 pi (r + w/2) / (N d)) - atan(2 pi (r - w/2) / (N d)), over sqrt(12)
  (rectangular over one ring, GUM F.2.2.1).
"""

from __future__ import annotations

import math

import pytest

from labctl.cli import main
from labctl.evaluation.evaluate import evaluate_runs
from labctl.evaluation.uncertainty import fov_components
from metrics.optics import pixel_aspect_distortion_pct
from metrics.sharpness import ied_pixels_at_centre
from tests.conftest import campaign_text

U_DEG = 0.5 / math.sqrt(3.0)
STAR = """
[[procedure]]
kind = "boehler_star"
distance_mm = 800
segments = [72]
gap_mm = 300
frames = 4
"""


def test_the_pixel_aspect_takes_both_fov_angles_tolerance():
    fov_h, fov_v, width, height = 75.0, 62.0, 640, 480
    p = 100 * ((fov_v / height) / (fov_h / width) - 1)  # 10.22 %: the simulated D455's
    components = {c.name: c.value for c in
                  fov_components(lambda h, v: pixel_aspect_distortion_pct(h, v, width, height), (fov_h, fov_v))}
    assert components == {
        "FOV horizontal: +-0.5 deg (assumed, rectangular)": pytest.approx(U_DEG * (p + 100) / fov_h, rel=1e-6),
        "FOV vertical: +-0.5 deg (assumed, rectangular)": pytest.approx(U_DEG * (p + 100) / fov_v, rel=1e-6),
    }
    # together 0.66 %: U = 1.33 %, so 10.22 % lies within U of the +-10 % limit
    assert 2 * math.hypot(*components.values()) == pytest.approx(1.33, abs=0.01)


def test_the_inter_eye_distance_takes_the_horizontal_fov_only():
    fov_h, width, distance = 67.0, 640, 600.0
    ied = 62.5 * (width / 2) / math.tan(math.radians(fov_h) / 2) / distance
    (component,) = fov_components(lambda h, v: ied_pixels_at_centre(h, width, distance), (fov_h, 51.0))
    assert component.name.startswith("FOV horizontal")
    assert component.value == pytest.approx(U_DEG * math.radians(1) * ied / math.sin(math.radians(fov_h)), rel=1e-6)


@pytest.fixture(scope="module")
def star_run(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("star")
    model = tmp / "model.toml"
    model.write_text('camera = "blaze101"\n[camera_overrides]\nwidth = 320\nheight = 240\n')
    campaign = tmp / "star.toml"
    campaign.write_text(campaign_text(procedures=STAR, seed=3))
    out = tmp / "star.h5"
    with pytest.raises(SystemExit) as info:
        main(["run", str(campaign), "--sim", "--model", str(model), "-o", str(out), "--quiet"])
    assert info.value.code == 0
    return evaluate_runs([out])


def test_the_cloud_resolution_takes_the_ring_width_as_its_resolution(star_run):
    star = star_run.geometry.chosen_star.result
    n, d, w = star.segments, star.distance_mm, star.ring_width_mm
    for axis in "hv":
        r = getattr(star, f"radius_{axis}_mm")
        assert not getattr(star, f"clamped_{axis}") and math.isfinite(r)
        across_ring = math.atan(2 * math.pi * (r + w / 2) / (n * d)) - math.atan(2 * math.pi * (r - w / 2) / (n * d))
        figure = star_run.figures[f"cloud_resolution_{axis}_deg"]
        assert figure.value == pytest.approx(math.degrees(math.atan(2 * math.pi * r / (n * d))))
        (component,) = figure.budget
        assert component.name == f"ring width {w:g} mm: resolution of the figure (Type B)"
        assert component.value == pytest.approx(math.degrees(across_ring) / math.sqrt(12), rel=1e-4)


def test_a_clamped_cloud_resolution_is_a_bound_without_uncertainty(star_run):
    from dataclasses import replace

    from metrics.boehler import angular_resolution_u_deg

    star = star_run.geometry.chosen_star.result
    assert math.isnan(angular_resolution_u_deg(replace(star, clamped_h=True), "h"))
    assert math.isfinite(angular_resolution_u_deg(replace(star, clamped_h=True), "v"))
