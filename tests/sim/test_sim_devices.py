"""Simulated devices: geometry, laser statistics, limits, determinism, virtual clock."""

import math

import numpy as np
import pytest

from drivers.errors import LimitViolation
from labctl.run.config import parse_campaign
from labctl.run.lab import build_sim_lab
from labctl.run.operator import Operator
from labctl.run.planning import schedule
from labctl.run.progress import Reporter
from labctl.run.runner import Runner
from labctl.run.store import RunWriter
from metrics.optics import Pinhole
from procedures.steps import Step
from sim.geometry import Pose
from sim.model import default_model_text, parse_model
from sim.scenes.targets import wall_scene
from tests.conftest import campaign_text

MODEL = 'camera = "blaze101"\n[camera_overrides]\nwidth = 40\nheight = 30\n'


def sim_lab(text=None, model=MODEL, seed=3):
    campaign = parse_campaign(text or campaign_text())
    lab = build_sim_lab(campaign, parse_model(model), seed)
    for device in lab.devices().values():
        device.connect()
    return campaign, lab


def test_pinhole_focal_length_from_fov():
    cam = Pinhole(640, 480, 67.0, 51.0)
    assert cam.fx == pytest.approx(320 / math.tan(math.radians(33.5)))
    # the outer edge of the outermost pixel sees half the FOV
    assert math.degrees(math.atan((cam.width - 1 - cam.cx + 0.5) / cam.fx)) == pytest.approx(33.5)
    rays = cam.unit_rays
    np.testing.assert_allclose(np.linalg.norm(rays, axis=0), 1.0)


def test_wall_is_flat_at_the_distance_and_tilt_changes_range():
    rays = Pinhole(64, 48, 67.0, 51.0).unit_rays
    scene = wall_scene(1500.0, 940.0)
    hit = scene.cast(*Pose.at_origin().rays(rays))
    np.testing.assert_allclose(hit.t * rays[2], 1500.0)
    np.testing.assert_allclose(hit.reflectance, 0.90)
    tilted = scene.cast(*Pose.at_origin(tilt_y_deg=2.0).rays(rays))
    z = tilted.t * rays[2]
    assert z[:, 0].mean() != pytest.approx(z[:, -1].mean(), abs=1.0)


def test_laser_statistics_and_resolution():
    campaign, lab = sim_lab()
    world = lab.camera.world
    lab.stage.move_to(2000.0)
    readings = []
    for index in range(400):
        world.begin_step(Step(index, "depth_sweep", "wall", 1), 0.0)
        readings.append(lab.laser.measure_mm())
    readings = np.array(readings)
    truth = 2000.0 + world.lab.camera_mount_error_mm + world.lab.laser_offset_mm
    assert readings.mean() == pytest.approx(truth + world.lab.laser_bias_mm, abs=0.03)
    assert readings.std() == pytest.approx(world.lab.laser_noise_mm, rel=0.15)
    np.testing.assert_allclose(readings * 10, np.round(readings * 10), atol=1e-6)


def test_stage_refuses_positions_beyond_travel_without_moving():
    _, lab = sim_lab()
    lab.stage.move_to(1000.0)
    with pytest.raises(LimitViolation, match="outside travel"):
        lab.stage.move_to(4000.5)
    assert lab.stage.position_mm() == 1000.0


def test_frames_depend_only_on_seed_step_and_index():
    _, lab1 = sim_lab(seed=5)
    _, lab2 = sim_lab(seed=5)
    _, lab3 = sim_lab(seed=6)
    for lab in (lab1, lab2, lab3):
        lab.camera.world.begin_step(Step(3, "depth_sweep", "wall", 4), 0.0)
        lab.stage.move_to(1500.0)
    a = [f.z for f in lab1.camera.capture(4)]
    b = [f.z for f in lab2.camera.capture(2, first_index=2)]
    c = [f.z for f in lab3.camera.capture(4)]
    np.testing.assert_array_equal(a[2], b[0])
    np.testing.assert_array_equal(a[3], b[1])
    assert not np.array_equal(a[0], c[0])


def test_dry_run_spends_planned_lab_time_on_virtual_clock(tmp_path):
    campaign, lab = sim_lab()
    run = RunWriter.create(tmp_path / "r.h5", campaign_toml=campaign_text(), simulated=True,
                           devices={}, camera=lab.camera.info(), steps=len(campaign.steps()), sim=(MODEL, 3))
    reporter = Reporter(quiet=True)
    Runner(campaign, lab, run, reporter, Operator(True, reporter.message)).execute()
    planned = schedule(campaign)
    total = planned[-1].start_s + planned[-1].duration_s
    assert lab.clock.now() == pytest.approx(total)
    assert total > 60  # minutes of lab time, dry-run in well under a second of compute


def test_amt100_stores_integer_millimetres():
    _, lab = sim_lab(model=default_model_text("amt100") + "[camera_overrides]\nwidth = 32\nheight = 24\n")
    lab.camera.world.begin_step(Step(0, "depth_sweep", "wall", 1), 0.0)
    lab.stage.move_to(1234.0)
    frame = next(lab.camera.capture(1))
    z = frame.z[np.isfinite(frame.z)]
    np.testing.assert_array_equal(z, np.round(z))
    assert frame.confidence.dtype == np.uint16


def test_close_range_saturates_and_far_low_signal_is_invalid():
    model = 'camera = "blaze101"\n[camera_overrides]\nwidth = 32\nheight = 24\nsaturation_ratio = 10.0\n'
    _, lab = sim_lab(model=model)
    lab.camera.world.begin_step(Step(0, "depth_sweep", "wall", 1), 0.0)
    lab.stage.move_to(500.0)  # amplitude ~ (2000/506)^2 = 15.6 A_ref > 10 A_ref
    assert np.isnan(next(lab.camera.capture(1)).z).mean() > 0.5
    lab.stage.move_to(2000.0)
    assert np.isnan(next(lab.camera.capture(1)).z).mean() == 0.0
