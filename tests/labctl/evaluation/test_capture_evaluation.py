"""``labctl evaluate`` on a single ``labctl device camera`` capture: maps, temporal noise, plane fit."""

import json
import math

import pytest

from labctl.cli.devices import _capture_file
from procedures.steps import Step
from tests.labctl.cli.test_cli_devices import labctl_main as labctl_main  # the in-process entry point fixture
from tests.shared_data import shared_data
from tests.sim.test_sim_devices import sim_lab

BAG = shared_data("realsense_d4xx_640x480.bag")


def test_capture_of_a_realsense_recording_is_summarized_not_a_page_of_na(labctl_main, tmp_path):
    """The recording (two frames of a room, read by pyrealsense2) is not planar: depth, noise and validity
    are reported, the plane is not."""
    run = tmp_path / "c.h5"
    code, _, err = labctl_main("device", "camera", "--backend", "realsense", "--playback", BAG, "--frames", "2",
                               "-o", run)
    assert code == 0, err
    code, _, err = labctl_main("evaluate", run, "-o", tmp_path / "out", "--quiet", "--no-pdf")
    assert code == 0, err
    doc = json.loads((tmp_path / "out" / "keyfigures.json").read_text())
    [row] = doc["capture"]
    assert row["step"] == "00000_capture" and row["frames"] == 2
    assert 0.5 < row["valid_fraction"] <= 1.0
    assert row["depth_q05_mm"] < row["depth_median_mm"] < row["depth_q95_mm"]
    assert 1000 < row["depth_median_mm"] < 2000  # the centre of the room reads about 1.5 m
    assert row["temporal_noise_median_mm"] > 0 and row["temporal_noise_q90_mm"] >= row["temporal_noise_median_mm"]
    assert row["planar"] is False and row["plane_distance_on_axis_mm"] is None
    assert any("capture steps only" in n for n in doc["notes"])
    report = (tmp_path / "out" / "report.html").read_text()
    assert "Single capture 00000_capture" in report and "plots/capture_00000_capture.png" in report
    assert (tmp_path / "out" / "plots" / "capture_00000_capture.png").stat().st_size > 10_000
    # the page opens with what was captured, not with a summary of n/a figures and "suitable for 0 of 5"
    summary = report[report.index('<div class="summary">'):report.index("</div>", report.index('<div class="summary">'))]
    assert "suitable for" not in summary and "no key figure and no suitability verdict" in summary
    assert f"{row['frames']} frame(s), {100 * row['valid_fraction']:.3g} % valid" in summary
    assert f"depth median {row['depth_median_mm']:.0f} mm" in summary and "not planar" in summary
    assert report.index("Single capture 00000_capture") < report.index("<h2>Key figures</h2>")


def test_capture_of_a_simulated_wall_finds_the_plane(labctl_main, tmp_path):
    """The capture path of ``labctl device camera`` on a simulated blaze-101 facing the wall: planar, the plane
    at the simulated camera-wall distance and square to the axis, the noise of the stack."""
    _, lab = sim_lab(seed=4)
    lab.camera.world.begin_step(Step(0, "capture", "wall", 6), 0.0)
    lab.stage.move_to(1200.0)
    truth = lab.camera.world.camera_distance_mm()
    run = tmp_path / "wall.h5"
    _capture_file(lab.camera, run, 6, None, {}, "[campaign]\nname = \"capture\"\n")
    code, _, err = labctl_main("evaluate", run, "-o", tmp_path / "out", "--quiet", "--no-pdf")
    assert code == 0, err
    [row] = json.loads((tmp_path / "out" / "keyfigures.json").read_text())["capture"]
    assert row["planar"] is True and row["plane_inlier_fraction"] > 0.95
    assert row["plane_distance_on_axis_mm"] == pytest.approx(truth, rel=0.01)
    assert abs(row["plane_tilt_about_x_deg"]) < 1.0 and abs(row["plane_tilt_about_y_deg"]) < 1.0
    assert row["plane_rms_mm"] < row["temporal_noise_q90_mm"]  # a mean of 6 frames is smoother than one frame
    assert not math.isnan(row["depth_median_mm"])
