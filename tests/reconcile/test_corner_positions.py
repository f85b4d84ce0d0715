"""Checkerboard corner positions as residual families: radial_distortion and fov_error become visible.

The measured runs are plain simulated checkerboard runs (two distances, 60 mm
tiles so that the test-size sensor resolves them) rewritten by the forward
models of tests/reconcile/forward.py, written from first principles and not
with the effect library's code: a Brown radial distortion (the pixel sees the
ray its undistorted position would, r_u from a fixed-point iteration), with
the point cloud left uncorrected (points along the pinhole ray of the
distorted pixel) or corrected; a true FOV narrower than the file says
(pixel u sees the ray of slope (u - c) / f_true; the camera's own
calibration keeps the cloud right); and a decentering distortion, which no
library effect has.
"""

from __future__ import annotations

import numpy as np
import pytest

from labctl.reconcile.corners import observe_corner_run
from labctl.reconcile.observe import observe_run
from labctl.reconcile.workflow import reconcile
from labctl.run import store
from tests.reconcile.forward import brown_source, decentering_source, focal_source, warp_run
from tests.reconcile.runs import CAMPAIGN, reconcile_cli, simulated_run

BOARD = ('[campaign]\nname = "board"\n[devices.camera]\nbackend = "blaze"\n[devices.stage]\nprotocol = "zaber"\n'
         'port = "/dev/ttyUSB0"\ntravel_mm = [0, 4000]\nspeed_mm_s = 50\n'
         '[[procedure]]\nkind = "checkerboard"\ndistance_mm = 600\ntile_mm = 60\nframes = {frames}\n'
         '{second}[sim]\nseed = {seed}\n')
SECOND = '[[procedure]]\nkind = "checkerboard"\ndistance_mm = 1000\ntile_mm = 60\nframes = 5\n'
FOV = (67.0, 51.0)  # the blaze-101's datasheet FOV, as the run file reports it


def _board_run(directory, seed=3, frames=5, second=True):
    return simulated_run(directory, "blaze101", campaign=BOARD.format(frames=frames, second=SECOND if second else "",
                                                                      seed=seed))


@pytest.fixture(scope="module")
def plain(tmp_path_factory):
    return _board_run(tmp_path_factory.mktemp("board"))


def test_one_open_run_lists_its_steps_once_for_both_observations(plain, monkeypatch):
    listed = []
    listing = store._complete_steps
    monkeypatch.setattr(store, "_complete_steps", lambda f: listed.append(f) or listing(f))
    with store.RunReader(plain) as run:
        observations, _, _ = observe_run(run)
        corners, _ = observe_corner_run(run, FOV)
        assert run.file.id.valid  # left open: the caller's to close
    assert len(listed) == 1
    assert len(corners) == 2
    by_path, _, _ = observe_run(plain)  # opened and closed by the observation itself
    assert len(listed) == 2
    assert [o.scene for o in by_path] == [o.scene for o in observations]
    for a, b in zip(by_path, observations, strict=True):
        np.testing.assert_array_equal(a.z, b.z)


@pytest.mark.parametrize("corrected", [False, True])
def test_a_hidden_radial_distortion_is_named_from_the_corners(plain, tmp_path, corrected):
    k1 = 0.08
    measured = warp_run(plain, tmp_path / "measured.h5", brown_source(k1), cloud_corrected=corrected)
    result = reconcile(measured)
    assert result.verdict == "effect_found", (result.notes, result.corners.summary())
    assert [e.name for e in result.named] == ["radial_distortion"]
    got = result.named[0]
    assert got.parameters["k1"] == pytest.approx(k1, abs=0.1 * k1)
    assert got.parameters["cloud"] is (not corrected)
    assert got.evidence.stderr["k1"] > 0
    assert result.gap_after <= 0.5 * result.gap_before, (result.gap_before, result.gap_after)
    assert result.corners.after.consistent


def test_a_hidden_fov_error_is_named_from_the_corners(plain, tmp_path):
    true_fov = (64.0, 51.0)
    measured = warp_run(plain, tmp_path / "measured.h5", focal_source(FOV, true_fov), cloud_corrected=True)
    out = tmp_path / "out"
    doc = reconcile_cli(measured, out)
    assert doc["verdict"] == "effect_found", doc["corners"]
    assert [e["name"] for e in doc["named_effects"]] == ["fov_error"]
    fov = doc["named_effects"][0]["parameters"]["fov_deg"]
    assert fov[0] == pytest.approx(true_fov[0], abs=0.3) and fov[1] == pytest.approx(true_fov[1], abs=0.3)
    assert doc["gap_after"] <= 0.5 * doc["gap_before"]
    assert doc["corners"]["after"]["corner_image"]["unit"] == "mm in the board plane"
    assert doc["corners"]["after"]["consistent_with_noise"] is True
    assert "fov_error" in (out / "reconcile.html").read_text()


def test_a_distortion_outside_the_library_is_unexplained(plain, tmp_path):
    """A decentering distortion (1 % at half the diagonal) is neither radial nor a FOV error."""
    measured = warp_run(plain, tmp_path / "measured.h5", decentering_source(0.01, 0.0), cloud_corrected=True)
    result = reconcile(measured)
    assert result.verdict == "unexplained", result.corners.summary()
    assert result.named == []
    assert not result.corners.after.consistent
    assert any(n.startswith("checkerboard corners: a residual") for n in result.notes)


def test_a_board_with_nothing_hidden_answers_none(plain, tmp_path):
    runs = [plain] + [_board_run(tmp_path / f"seed{seed}", seed=seed) for seed in (11, 12)]
    verdicts = [reconcile(run).verdict for run in runs]
    assert verdicts == ["none"] * 3


def test_a_board_at_one_distance_still_shows_distortion_and_fov(tmp_path):
    """The cloud's lateral positions do not depend on the FOV but do on the board distance: one distance
    separates a FOV error from the profiled distance error."""
    plain = _board_run(tmp_path / "one", second=False)
    measured = warp_run(plain, tmp_path / "k1.h5", brown_source(0.08), cloud_corrected=True)
    result = reconcile(measured)
    assert [e.name for e in result.named] == ["radial_distortion"], result.corners.summary()
    assert result.named[0].parameters["k1"] == pytest.approx(0.08, abs=0.008)
    measured = warp_run(plain, tmp_path / "fov.h5", focal_source(FOV, (64.0, 49.0)), cloud_corrected=True)
    result = reconcile(measured)
    assert [e.name for e in result.named] == ["fov_error"], result.corners.summary()
    assert result.named[0].parameters["fov_deg"] == pytest.approx([64.0, 49.0], abs=0.3)
    assert result.named[0].evidence.determination.well_determined


def test_a_run_with_nothing_comparable_is_still_not_comparable(tmp_path):
    run = _board_run(tmp_path, frames=1, second=False)  # one frame: no scatter, so no corner floor
    out = tmp_path / "out"
    doc = reconcile_cli(run, out)
    assert doc["verdict"] == "not_comparable"
    assert "checkerboard" not in doc["not_comparable"]["procedures_needed"]
    assert "depth_sweep" in doc["not_comparable"]["procedures_needed"]


def test_in_a_campaign_the_corners_and_the_depth_sweep_each_name_their_effect(tmp_path):
    """Offset calibration, 0.4-4 m sweep and the two boards, with a library wiggling hidden in the simulation and
    a Brown k1 = 0.08 (cloud along the distorted pixel's ray, so the sweep's depth shows it too) written over it:
    the corners name the distortion, the depth rounds (starting from the model with it) the wiggling."""
    boards = SECOND.replace("1000", "600") + SECOND
    wiggling = {"amplitude_mm": 3.0, "period_mm": 900.0, "phase_rad": 0.5}
    plain = simulated_run(tmp_path / "plain", "blaze101", {"wiggling": wiggling},
                          campaign=CAMPAIGN.format(backend="blaze", seed=3, sweep_step_mm=200, robot=boards))
    measured = warp_run(plain, tmp_path / "measured.h5", brown_source(0.08), cloud_corrected=False)
    doc = reconcile_cli(measured, tmp_path / "out")
    assert doc["verdict"] == "effect_found", (doc["notes"], doc["corners"])
    named = {e["name"]: e for e in doc["named_effects"]}
    assert sorted(named) == ["radial_distortion", "wiggling"]
    distortion = named["radial_distortion"]
    assert distortion["parameters"]["k1"] == pytest.approx(0.08, abs=0.008) and distortion["parameters"]["cloud"]
    assert distortion["evidence"]["family"] == "corners"
    assert named["wiggling"]["parameters"]["period_mm"] == pytest.approx(900.0, rel=0.02)
    assert doc["corners"]["after"]["consistent_with_noise"] and doc["consistent_with_noise"]
    assert doc["goodness_of_fit"]["after_physical"]["consistent_with_noise"]
    assert doc["gap_after"] <= 0.5 * doc["gap_before"]
    assert "Checkerboard corners" in (tmp_path / "out" / "reconcile.html").read_text()
