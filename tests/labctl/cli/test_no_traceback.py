"""No traceback from any command on bad input or a bad device state: exit 2 (input) or 1 (device or
runtime) with a message naming the file, field or port; valid JSON; no silent garbage."""

from __future__ import annotations

import json
import math
import textwrap
import warnings
from pathlib import Path

import h5py
import numpy as np
import pytest

from labctl.cli import main
from metrics.jsonsafe import dumps_strict, json_safe
from sim.emulators import DimetixEmulator
from tests.conftest import campaign_text

SMALL = 'camera = "blaze101"\n[camera_overrides]\nwidth = 48\nheight = 36\n'

MASK_RUN = """
[[procedure]]
kind = "offset_calibration"
frames = 3

[[procedure]]
kind = "depth_sweep"
start_mm = 2000
stop_mm = 2000
frames = 3

[[procedure]]
kind = "face_mask"
distance_mm = 1000
frames = 3
"""


def labctl(capsys: pytest.CaptureFixture[str], *args: object) -> tuple[int, str, str]:
    """Run the command line in-process: (exit code, stdout, stderr)."""
    with pytest.raises(SystemExit) as done:
        main([str(a) for a in args])
    out, err = capsys.readouterr()
    assert "Traceback" not in err
    return int(done.value.code or 0), out, err


def simulated_run(directory: Path, procedures: str, model: str = SMALL) -> Path:
    directory.mkdir(parents=True, exist_ok=True)
    (directory / "campaign.toml").write_text(campaign_text(procedures=textwrap.dedent(procedures)))
    (directory / "model.toml").write_text(model)
    run = directory / "run.h5"
    with pytest.raises(SystemExit) as done:
        main(["run", str(directory / "campaign.toml"), "--sim", "--model", str(directory / "model.toml"),
              "-o", str(run), "--quiet"])
    assert done.value.code == 0
    return run


@pytest.fixture(scope="module")
def blank_mask_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A measured run (no /sim) whose face-mask step has no valid point at all."""
    run = simulated_run(tmp_path_factory.mktemp("mask"), MASK_RUN)
    with h5py.File(run, "r+") as f:
        del f["sim"]
        for channel in "xyz":
            f["steps/00002_face_mask"][channel][...] = np.nan
    return run


# ---------------------------------------------------------------------- output locations
def test_sim_preview_into_a_missing_directory(capsys) -> None:
    code, _, err = labctl(capsys, "sim", "preview", "--camera", "flexx2", "-o", "/nodir/p.png")
    assert code == 2 and "directory /nodir for -o does not exist" in err


def test_analyze_plots_into_a_missing_directory(capsys, tmp_path: Path) -> None:
    cloud = tmp_path / "cloud.npy"
    np.save(cloud, np.zeros((20, 30, 3)))
    image = tmp_path / "image.npy"
    np.save(image, np.zeros((20, 30)))
    code, _, err = labctl(capsys, "analyze", "boehler", cloud, "--segments", "72", "--plot", "/nodir/b.png")
    assert code == 2 and "directory /nodir for --plot does not exist" in err
    code, _, err = labctl(capsys, "analyze", "checkerboard", image, "--tile-mm", "19", "--distance-mm", "600",
                          "--fov-deg", "67,51", "--plot", "/nodir/c.png")
    assert code == 2 and "directory /nodir for --plot does not exist" in err


def test_output_directories_that_cannot_be_created(capsys, tmp_path: Path, blank_mask_run: Path) -> None:
    blocker = tmp_path / "a-file"
    blocker.write_text("")
    for command in (["evaluate", blank_mask_run], ["reconcile", blank_mask_run], ["compare", tmp_path]):
        code, _, err = labctl(capsys, *command, "-o", blocker / "out")
        assert code == 2 and f"cannot create the directory {blocker / 'out'} for -o" in err, (command, err)
        code, _, err = labctl(capsys, *command, "-o", blocker)
        assert code == 2 and f"{blocker}' is a file" in err, (command, err)


def test_an_unforeseen_os_error_names_the_file(capsys, tmp_path: Path, blank_mask_run: Path, monkeypatch) -> None:
    from labctl.report import html as report

    def refuse(evaluation, outdir):
        raise PermissionError(13, "Permission denied", str(outdir / "keyfigures.json"))

    monkeypatch.setattr(report, "write_outputs", refuse)
    code, _, err = labctl(capsys, "evaluate", blank_mask_run, "-o", tmp_path / "out", "--quiet")
    assert code == 1 and err.strip() == f"labctl: error: {tmp_path / 'out' / 'keyfigures.json'}: Permission denied"


# ---------------------------------------------------------------------- export and run -o
def test_export_refuses_to_overwrite_without_force(capsys, tmp_path: Path, blank_mask_run: Path) -> None:
    target = tmp_path / "cloud.pcd"
    target.write_bytes(b"precious")
    code, _, err = labctl(capsys, "export", blank_mask_run, "--step", "00001_depth_sweep", "--format", "pcd",
                          "-o", target)
    assert code == 2 and f"-o {target} already exists; add --force to overwrite it" in err
    assert target.read_bytes() == b"precious"
    code, _, _ = labctl(capsys, "export", blank_mask_run, "--step", "00001_depth_sweep", "--format", "pcd",
                        "-o", target, "--force")
    assert code == 0 and target.read_bytes().startswith(b"# .PCD v0.7")


def test_run_onto_a_complete_run_advises_evaluation(capsys, tmp_path: Path, blank_mask_run: Path) -> None:
    campaign = tmp_path / "c.toml"
    campaign.write_text(campaign_text())
    code, _, err = labctl(capsys, "run", campaign, "--sim", "-o", blank_mask_run)
    assert code == 2
    assert f"{blank_mask_run} already exists and is a complete run; evaluate it with 'labctl evaluate" in err
    assert "resume" not in err


# ---------------------------------------------------------------------- resume, evaluate, reconcile
def test_resume_of_a_simulated_run_without_its_model(capsys, tmp_path: Path) -> None:
    run = simulated_run(tmp_path, MASK_RUN)
    with h5py.File(run, "r+") as f:
        del f["sim"]
        f.attrs["status"] = "aborted"
    code, _, err = labctl(capsys, "resume", run)
    assert code == 2 and f"{run} has no group /sim, which resume needs" in err


def test_evaluate_writes_what_it_can_when_the_face_mask_has_no_valid_point(
    capsys, tmp_path: Path, blank_mask_run: Path
) -> None:
    code, _, _ = labctl(capsys, "evaluate", blank_mask_run, "-o", tmp_path / "out", "--quiet")
    assert code == 0
    doc = json.loads((tmp_path / "out" / "keyfigures.json").read_text())
    assert "face mask 00002_face_mask has no valid point: no point cloud or rendering" in doc["notes"]
    assert "face_mask" not in doc and (tmp_path / "out" / "report.html").is_file()
    assert doc["depth_sweep"]  # the rest is evaluated


def strict_json(text: str) -> object:
    """Parse as RFC 8259 JSON: NaN and Infinity are refused."""
    def refuse(name: str) -> object:
        raise ValueError(f"{name} is not JSON")
    return json.loads(text, parse_constant=refuse)


@pytest.mark.slow
def test_reconcile_of_a_step_without_valid_points_prints_no_warning_and_no_nan(
    capsys, tmp_path: Path, blank_mask_run: Path
) -> None:
    with warnings.catch_warnings(record=True) as caught:  # what a terminal would show as "RuntimeWarning: ..."
        warnings.simplefilter("always")
        code, _, err = labctl(capsys, "reconcile", blank_mask_run, "-o", tmp_path / "out", "--quiet")
    assert code == 0 and "Warning" not in err
    assert not [str(w.message) for w in caught if issubclass(w.category, RuntimeWarning)]
    strict_json((tmp_path / "out" / "reconcile.json").read_text())
    page = (tmp_path / "out" / "reconcile.html").read_text()
    row = page[page.index("<td class=l>face_mask</td>"):].split("</tr>")[0]
    assert "nan" not in row and "n/a" in row


@pytest.mark.slow
def test_reconcile_json_is_valid_when_only_one_step_is_usable(capsys, tmp_path: Path) -> None:
    """One comparable step cannot score a candidate (its scores were -Infinity once): the answer is
    ``not_comparable`` with the procedures that would help, in strict JSON on stdout and in the file."""
    run = simulated_run(tmp_path, '[[procedure]]\nkind = "offset_calibration"\nframes = 3\n')
    with h5py.File(run, "r+") as f:
        del f["sim"]
    code, out, _ = labctl(capsys, "reconcile", run, "-o", tmp_path / "out", "--json", "--quiet")
    assert code == 0
    doc = strict_json((tmp_path / "out" / "reconcile.json").read_text())
    assert strict_json(out) == doc
    assert doc["verdict"] == "not_comparable" and doc["named_effects"] == []
    assert "depth_sweep" in doc["not_comparable"]["procedures_needed"]


def test_strict_json_maps_every_non_finite_number_to_null() -> None:
    doc = {"a": math.nan, "b": [1.0, -math.inf, {"c": np.float32("inf")}], "d": np.array([1.5, np.nan]),
           "e": (np.int64(3), "x")}
    assert json_safe(doc) == {"a": None, "b": [1.0, None, {"c": None}], "d": [1.5, None], "e": [3, "x"]}
    assert strict_json(dumps_strict(doc)) == json_safe(doc)


# ---------------------------------------------------------------------- devices
def test_a_failed_offset_calibration_aborts_instead_of_writing_nan_references(capsys, tmp_path: Path) -> None:
    """The camera's range ends at 1.5 m, the wall is at 2 m: no valid pixel in the centre region."""
    (tmp_path / "campaign.toml").write_text(campaign_text(procedures=textwrap.dedent(MASK_RUN)))
    (tmp_path / "model.toml").write_text(SMALL + "max_range_mm = 1500\n")
    code, _, err = labctl(capsys, "run", tmp_path / "campaign.toml", "--sim", "--model", tmp_path / "model.toml",
                          "-o", tmp_path / "run.h5", "--quiet")
    assert code == 1 and "run aborted: camera: offset calibration 00000_offset_calibration: the central 10 % x 10 % region has " \
           "no valid depth in its 3 frames" in err
    with h5py.File(tmp_path / "run.h5", "r") as f:
        assert f.attrs["status"] == "aborted"
        assert not [k for k, g in f["steps"].items() if g.attrs["complete"]]  # nothing with a NaN reference


def test_a_serial_port_that_refuses_its_line_settings(capsys) -> None:
    """Linux refuses the Dimetix's 7E1 settings on a pseudo-terminal a previous use left at 7E1
    (termios.error EINVAL): the second use must report the port, not a traceback."""
    with DimetixEmulator(distance_mm=1000.0) as laser:
        port = laser.port
        code, out, _ = labctl(capsys, "device", "laser", "--port", port, "--count", "1")
        assert code == 0 and out.strip() == "1000.0 mm"
        code, _, err = labctl(capsys, "device", "laser", "--port", port, "--count", "1")
    assert code == 1 and f"Dimetix laser on {port}: cannot open the port at 19200 baud" in err


def test_a_run_whose_laser_port_refuses_its_settings_stops_with_the_port_named(capsys, tmp_path: Path) -> None:
    from sim.emulators import ZaberEmulator
    from tests.labctl.run.test_real_lab import STEP, campaign

    with DimetixEmulator(distance_mm=1000.0) as laser, ZaberEmulator(mm_per_microstep=STEP, travel_mm=400.0) as stage:
        port = laser.port
        assert labctl(capsys, "device", "laser", "--port", port, "--count", "1")[0] == 0  # leaves the pty at 7E1
        path = tmp_path / "campaign.toml"
        path.write_text(campaign(f'protocol = "zaber"\nport = "{stage.port}"\nmm_per_microstep = {STEP}', port))
        code, _, err = labctl(capsys, "run", path, "-o", tmp_path / "run.h5", "--quiet")
        assert not stage.moving
    assert code == 1 and f"cannot connect devices: Dimetix laser on {port}: cannot open the port" in err
    assert not (tmp_path / "run.h5").exists()
