"""VDI/VDE 2634-2 ball-bar placements: each with its own distance, offset, orientation and tilt towards the wall,
validated, prompted, simulated where they say and evaluated per placement."""

import json
import math

import numpy as np
import pytest

from labctl.cli import main
from labctl.errors import InputError
from labctl.evaluation.evaluate import evaluate_runs
from labctl.evaluation.vdi2634 import bar_sides
from labctl.run.config import parse_campaign
from labctl.run.store import RunReader
from metrics.vdi2634 import fit_sphere_cap

SPACING, DIAMETER, SCALE = 300.0, 50.0, 0.01
#: (distance, offset right / up, orientation, tilt towards the wall): in the image plane on the axis, and two
#: placements off the axis along space diagonals, tilted 60 and -70 deg towards the range axis
PLACEMENTS = [(1000.0, (0.0, 0.0), 0.0, 0.0), (1200.0, (150.0, 100.0), 45.0, 60.0),
              (1000.0, (-200.0, -100.0), 90.0, -70.0)]


def procedure(placements: str, extra: str = "") -> str:
    return f'[[procedure]]\nkind = "sphere_bar"\nframes = 2\n{extra}placements = [{placements}]\n'


def toml_placements(rows=PLACEMENTS) -> str:
    return ", ".join(f"{{distance_mm = {d}, offset_mm = [{o[0]}, {o[1]}], orientation_deg = {p}, tilt_deg = {t}}}"
                     for d, o, p, t in rows)


def invoke(*args) -> int:
    with pytest.raises(SystemExit) as info:
        main([str(a) for a in args])
    return info.value.code


def test_without_placements_the_old_grid_of_distances_and_orientations():
    """No ``placements``: every distance x orientation, centred on the axis, all with the one ``tilt_deg``, the
    stage at distance + gap, and no offset among the target parameters (old campaign files mean what they did)."""
    from tests.conftest import campaign_text

    campaign = parse_campaign(campaign_text(procedures='[[procedure]]\nkind = "sphere_bar"\ndistances_mm = [1000, '
                                                       '2000]\norientations_deg = [0, 90]\ntilt_deg = 20\n'), "c.toml")
    steps = list(campaign.procedure[0].steps(0))
    assert [(s.distance_mm, s.target_params["orientation_deg"], s.target_params["tilt_deg"]) for s in steps] == [
        (1500.0, 0.0, 20.0), (1500.0, 90.0, 20.0), (2500.0, 0.0, 20.0), (2500.0, 90.0, 20.0)]
    assert all("offset_mm" not in s.target_params and "centred on the camera axis" in s.prompt for s in steps)


def test_each_placement_one_step_with_a_prompt_the_operator_can_act_on():
    from tests.conftest import campaign_text

    rows = [(1500.0, (200.0, -100.0), 0.0, 40.0), (1000.0, (0.0, 0.0), 90.0, -30.0)]
    steps = list(parse_campaign(campaign_text(procedures=procedure(toml_placements(rows))), "c.toml")
                 .procedure[0].steps(0))
    assert [s.distance_mm for s in steps] == [2000.0, 1500.0]  # the stage: the bar's middle + the 500 mm gap
    # recorded in the camera frame (x right, y down), as the simulator's scene takes it
    assert [s.target_params["offset_mm"] for s in steps] == [[200.0, 100.0], [0.0, 0.0]]
    assert [(s.target_params["orientation_deg"], s.target_params["tilt_deg"]) for s in steps] == [(0.0, 40.0),
                                                                                                  (90.0, -30.0)]
    first, second = (s.prompt for s in steps)
    assert "1500 mm from the camera" in first and "200 mm right of and 100 mm below the camera axis" in first
    assert "tilted 40 deg" in first and "its right sphere towards the wall" in first
    # 90 deg: vertical, its positive end down; a negative tilt sends the other (upper) end towards the wall
    assert "on the camera axis" in second and "its upper sphere towards the wall" in second


@pytest.mark.parametrize(("placements", "extra", "message"), [
    # the bar along the line of sight to its middle (500 mm above the axis at 1 m: 26.6 deg up): the near sphere
    # hides the far one
    ("{distance_mm = 1000, offset_mm = [0, 500], orientation_deg = 90, tilt_deg = -63.43}", "",
     r"placements\[0\] .*the spheres would overlap in the image"),
    # gap 300: the far sphere reaches 150 sin 60 + 25 = 155 mm behind the middle, past half the gap (150 mm)
    ("{distance_mm = 1000, tilt_deg = 60}", "gap_mm = 300\n", r"placements\[0\] .*not clear of half the gap"),
    ("{distance_mm = 1000, tilt_deg = 85}", "", r"placements\.0\.tilt_deg|placements\[0\]\.tilt_deg"),
    ("{distance_mm = 1000, offset_mm = [1, 2, 3]}", "", r"placements\[0\]\.offset_mm"),
    ("{distance_mm = 1000, spin_deg = 3}", "", r"unknown key 'spin_deg' in \[procedure\[0\]\.placements\[0\]\]"),
    ("{distance_mm = 1000}", "tilt_deg = 10\n", "placements gives every placement's distance, orientation and "
                                               "tilt: leave out tilt_deg"),
])
def test_placements_are_validated_naming_the_field(placements, extra, message):
    from tests.conftest import campaign_text

    with pytest.raises(InputError, match=message):
        parse_campaign(campaign_text(procedures=procedure(placements, extra)), "c.toml")


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """The blaze-101 at 320 x 240 with almost no temporal noise (0.01 mm at 2 m), the same seed with and without
    a hidden 1 % range scale."""
    from tests.conftest import campaign_text

    directory = tmp_path_factory.mktemp("placements")
    campaign = directory / "campaign.toml"
    campaign.write_text(campaign_text(procedures=procedure(toml_placements())))
    paths = {}
    for scale in (0.0, SCALE):
        model = directory / f"model{scale}.toml"
        model.write_text('camera = "blaze101"\n[camera_overrides]\nwidth = 320\nheight = 240\n'
                         f"noise_mm_at_2m = 0.01\n[effects.range_scale]\nscale = {scale}\n")
        paths[scale] = directory / f"run{scale}.h5"
        assert invoke("run", campaign, "--sim", "--model", model, "-o", paths[scale], "--quiet") == 0
    return paths


def test_the_simulator_puts_each_placement_where_the_campaign_says(runs):
    """Each sphere fitted on its own (the points nearest to where it should be) lies where the placement puts it: the middle
    ``right`` mm right of and ``up`` mm above the axis at its distance, in the camera frame (x right, y down)
    (right, -up, distance), the centres half the spacing either way along the bar, (cos o cos t, sin o cos t,
    sin t) for orientation o (clockwise from horizontal as seen from the camera) and tilt t towards the wall.
    The stage's distance is nominal (the simulated lab's wall stands 6.7 mm further), so the middle's depth is
    taken as the wall's, as the camera reads it in the image's top rows, less the 500 mm gap. Each sphere is
    fitted with the rim rule (the rim pixels mix the sphere with the wall); within 0.5 mm: its points are
    footprint means slightly inside the sphere."""
    with RunReader(runs[0.0]) as reader:
        steps = reader.steps("sphere_bar")
        assert len(steps) == len(PLACEMENTS)
        for step, (distance, (right, up), orientation, tilt) in zip(steps, PLACEMENTS):
            o, t = math.radians(orientation), math.radians(tilt)
            axis = np.array([math.cos(o) * math.cos(t), math.sin(o) * math.cos(t), math.sin(t)])
            cloud = np.mean([np.stack([step.frame(c, k) for c in "xyz"], -1) for k in range(2)], axis=0)
            middle = np.array([right, -up, float(np.nanmedian(cloud[:5, :, 2])) - 500.0])
            assert abs(middle[2] - distance) < 10.0
            expected = [middle - axis * SPACING / 2, middle + axis * SPACING / 2]
            cloud = cloud.reshape(-1, 3)
            cloud = cloud[np.all(np.isfinite(cloud), axis=1) & (cloud[:, 2] < distance + 250.0)]
            nearest = np.argmin([np.linalg.norm(cloud - c, axis=1) for c in expected], axis=0)
            for n, centre in enumerate(expected):
                fitted = fit_sphere_cap(cloud[nearest == n], DIAMETER / 2).centre
                assert np.linalg.norm(fitted - centre) < 0.5, (step.step_id, n, fitted, centre)


def test_range_scale_known_answer_at_every_tilt(runs, tmp_path):
    """A range scale s acts on the range along each pixel's ray, and the camera reports x, y, z along that ray
    (x = r u_x, ...): every point p becomes (1 + s) p, a similarity about the projection centre. A sphere
    (c, R) becomes the sphere ((1 + s) c, (1 + s) R), and a least-squares sphere fit commutes with a
    similarity, so the fitted centres move to (1 + s) c and the fitted radius to (1 + s) R whatever the bar's
    orientation and tilt: SD_s = (1 + s) (L + SD_0) - L and P_S,s = (1 + s) (D + P_S,0) - D, with SD_0 and P_S,0
    the same placement without the scale (same seed: the renderer's footprint bias cancels). So the bar in the
    image plane shows s L = 3 mm exactly as the bars tilted 60 and 70 deg towards the range axis do: its lateral
    coordinates follow the range. (A camera that scaled z alone would show L (sqrt(cos^2 t + (1 + s)^2 sin^2 t)
    - 1), 0 in the image plane.) Left over: the noise, not scaled (0.01 mm at 2 m), and the rim rule's cap,
    drawn with the calibrated radius, keeping slightly different pixels: 0.015 mm."""
    plain, scaled = (evaluate_runs([runs[s]]).acceptance for s in (0.0, SCALE))
    assert not plain.notes and not scaled.notes
    assert [(m.distance_mm, m.offset_mm, m.pose_deg, m.tilt_deg) for m in scaled.measurements] == [
        (d, o, p, t) for d, o, p, t in PLACEMENTS]
    for before, after in zip(plain.measurements, scaled.measurements):
        sd0, sd = before.values["sphere_spacing_error_mm"], after.values["sphere_spacing_error_mm"]
        assert abs(sd - ((1 + SCALE) * (SPACING + sd0) - SPACING)) < 0.015, (after.tilt_deg, sd0, sd)
        assert abs(sd - SCALE * SPACING) < 0.1, (after.tilt_deg, sd)  # the footprint bias: below 0.1 mm
        size0, size = before.values["probing_error_size_mm"], after.values["probing_error_size_mm"]
        assert abs(size - ((1 + SCALE) * (DIAMETER + size0) - DIAMETER)) < 0.015, (after.tilt_deg, size0, size)

    # keyfigures.json: each placement's position and orientation next to its figures; SD the extreme of all
    assert invoke("evaluate", runs[SCALE], "-o", tmp_path, "--quiet", "--no-pdf") == 0
    document = json.loads((tmp_path / "keyfigures.json").read_text())
    assert document["schema_version"] == "1.2"
    rows = document["acceptance_positions"]
    assert [(r["distance_mm"], tuple(r["offset_mm"]), r["orientation_deg"], r["tilt_deg"]) for r in rows] == [
        (d, o, p, t) for d, o, p, t in PLACEMENTS]
    worst = max((r["sphere_spacing_error_mm"] for r in rows), key=abs)
    assert document["acceptance_test"]["sphere_spacing_error_mm"]["value"] == pytest.approx(worst)


@pytest.mark.parametrize("tilt", [0.0, 60.0, 80.0, 90.0])
def test_the_spheres_split_along_the_bar_in_space(tilt):
    """Caps of the two spheres (radius 25 mm, 300 mm apart, middle at 1 m), the near one with twice the points of
    the far one: split along the bar's direction in space, each point goes to its own sphere, down to a bar along
    the range axis (90 deg), where the spheres' x, y overlap and no split in the image plane could tell them
    apart."""
    rng = np.random.default_rng(3)
    t = math.radians(tilt)
    axis = np.array([math.cos(t), 0.0, math.sin(t)])
    centres = [np.array([0.0, 0.0, 1000.0]) - axis * 150.0, np.array([0.0, 0.0, 1000.0]) + axis * 150.0]
    caps = []
    for centre, n in zip(centres, (400, 200)):
        directions = rng.normal(size=(n, 3))
        directions /= np.linalg.norm(directions, axis=1, keepdims=True)
        directions[:, 2] = -np.abs(directions[:, 2])  # the half facing the camera
        caps.append(centre + 25.0 * directions)
    sides = bar_sides(np.vstack(caps), 0.0, tilt)
    assert sides.tolist() == [False] * 400 + [True] * 200
