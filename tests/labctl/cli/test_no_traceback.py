"""No traceback from any command on bad input or a bad device state: exit 2 (input) or 1 (device or
runtime) with a message naming the file, field or port; valid JSON; no silent garbage."""

from __future__ import annotations

import json
import math
import os
import textwrap
import warnings
from pathlib import Path

import h5py
import numpy as np
import pytest

from labctl.cli import main
from labctl.jsondoc import dumps, to_json
from sim.emulators import DimetixEmulator
from tests.conftest import REALTIME_GROUP, campaign_text
from tests.labctl.run.small_fs import unmount

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
    evaluation = tmp_path / "evaluation"
    evaluation.mkdir()
    (evaluation / "keyfigures.json").write_text('{"camera": {"model": "m"}, "figures": {}}')
    for command in (["evaluate", blank_mask_run], ["reconcile", blank_mask_run], ["compare", evaluation]):
        code, _, err = labctl(capsys, *command, "-o", blocker / "out")
        assert code == 2 and f"cannot create the directory {blocker / 'out'} for -o" in err, (command, err)
        code, _, err = labctl(capsys, *command, "-o", blocker)
        assert code == 2 and f"{blocker}' is a file" in err, (command, err)


def test_an_unforeseen_os_error_names_the_file(capsys, tmp_path: Path, blank_mask_run: Path, monkeypatch) -> None:
    from labctl.report import html as report

    def refuse(evaluation, outdir):
        raise PermissionError(13, "Permission denied", str(outdir / "keyfigures.json"))

    monkeypatch.setattr(report, "write_outputs", refuse)
    code, _, err = labctl(capsys, "evaluate", blank_mask_run, "-o", tmp_path / "out", "--quiet", "--no-pdf")
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
    code, _, _ = labctl(capsys, "evaluate", blank_mask_run, "-o", tmp_path / "out", "--quiet", "--no-pdf")
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
@pytest.mark.xdist_group(REALTIME_GROUP)  # its null replicas run on a local Dask cluster that takes both cores
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
    assert to_json(doc) == {"a": None, "b": [1.0, None, {"c": None}], "d": [1.5, None], "e": [3, "x"]}
    assert strict_json(dumps(doc, indent=None)) == to_json(doc)


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


# ---------------------------------------------------------------------- files that are not what the command reads
def test_an_empty_or_a_text_file_given_as_a_run_is_named_for_what_it_is(capsys, tmp_path: Path) -> None:
    empty, text = tmp_path / "empty.h5", tmp_path / "notes.h5"
    empty.write_bytes(b"")
    text.write_text("distance 1000 mm\n")
    for path, kind in ((empty, "is empty (0 bytes)"), (text, "is a text file (it begins 'distance 1000 mm')")):
        for command in (["info", path], ["evaluate", path, "-o", tmp_path / "out"], ["resume", path],
                        ["export", path, "--step", "s", "--format", "pcd", "-o", tmp_path / "c.pcd"]):
            code, _, err = labctl(capsys, *command)
            assert code == 2, (command, err)
            assert f"{path} {kind}, not a labctl run file: a run file is the HDF5 file 'labctl run" in err, (command, err)
    assert empty.read_bytes() == b""  # resume did not open it for writing (HDF5 would have made it a file of 800 bytes)
    assert not (tmp_path / "out").exists()


def test_a_run_file_given_as_the_campaign(capsys, tmp_path: Path, blank_mask_run: Path) -> None:
    for command in (["plan", blank_mask_run], ["run", blank_mask_run, "--sim", "-o", tmp_path / "r.h5"]):
        code, _, err = labctl(capsys, *command)
        assert code == 2 and "utf-8" not in err
        assert (f"{blank_mask_run} is a labctl run file, not a campaign; did you mean 'labctl resume {blank_mask_run}' "
                f"or 'labctl evaluate {blank_mask_run} -o DIR'?") in err
    assert not (tmp_path / "r.h5").exists()


# ---------------------------------------------------------------------- outputs that cannot be written
@pytest.mark.skipif(not Path("/proc/self").is_dir(), reason="needs /proc, where no file can be created")
def test_outputs_where_no_file_can_be_created_say_so(capsys, tmp_path: Path, blank_mask_run: Path) -> None:
    """Root passes every permission check, but no file can be created in /proc: the cause is named, not a lack
    of free space (run) or a missing file (export)."""
    campaign = tmp_path / "c.toml"
    campaign.write_text(campaign_text())
    code, _, err = labctl(capsys, "run", campaign, "--sim", "-o", "/proc/run.h5")
    assert code == 2 and "-o /proc/run.h5: no file can be created in /proc" in err and "free" not in err
    code, _, err = labctl(capsys, "export", blank_mask_run, "--step", "00001_depth_sweep", "--format", "ply",
                          "-o", "/proc/a.ply")
    assert code == 2 and "-o /proc/a.ply: no file can be created in /proc" in err
    code, _, err = labctl(capsys, "evaluate", blank_mask_run, "-o", "/proc/evaluation", "--quiet", "--no-pdf")
    assert code == 2 and "cannot create the directory /proc/evaluation for -o" in err and "(/proc accepts no new" in err


def test_a_file_output_named_like_a_directory_is_refused(capsys, tmp_path: Path, monkeypatch) -> None:
    monkeypatch.chdir(tmp_path)
    Path("c.toml").write_text(campaign_text())
    code, _, err = labctl(capsys, "run", "c.toml", "--sim", "-o", "newdir/")
    assert code == 2 and "-o newdir/ names a directory; give a file name in it, e.g. newdir/run.h5" in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["c.toml"]


def test_a_plot_that_is_not_a_png_is_refused_before_the_analysis(capsys, tmp_path: Path) -> None:
    cloud = tmp_path / "cloud.npy"
    np.save(cloud, np.zeros((20, 30, 3)))
    code, _, err = labctl(capsys, "analyze", "boehler", cloud, "--segments", "72", "--plot", tmp_path / "b.txt")
    assert code == 2 and f"--plot {tmp_path / 'b.txt'}: the figure is written as PNG; name it {tmp_path / 'b.png'}" in err


def test_export_format_and_file_extension_must_agree(capsys, tmp_path: Path, blank_mask_run: Path) -> None:
    step = ("--step", "00001_depth_sweep")
    code, _, err = labctl(capsys, "export", blank_mask_run, *step, "--format", "ply", "-o", tmp_path / "b.pcd")
    assert code == 2
    assert f"--format ply does not match -o {tmp_path / 'b.pcd'}, a .pcd name: write -o {tmp_path / 'b.ply'}" in err
    assert not (tmp_path / "b.pcd").exists()
    code, _, err = labctl(capsys, "export", blank_mask_run, *step, "--format", "pcd", "-o", tmp_path / "b.txt")
    assert code == 0 and f"warning: -o {tmp_path / 'b.txt'} has no .pcd extension" in err
    assert (tmp_path / "b.txt").read_bytes().startswith(b"# .PCD")


# ---------------------------------------------------------------------- the same input twice, one evaluation
def test_evaluate_counts_a_run_given_twice_once(capsys, tmp_path: Path, blank_mask_run: Path, monkeypatch) -> None:
    monkeypatch.chdir(blank_mask_run.parent)
    code, _, err = labctl(capsys, "evaluate", blank_mask_run.name, f"./{blank_mask_run.name}", blank_mask_run,
                          "-o", tmp_path / "out", "--quiet", "--no-pdf")
    assert code == 0
    assert err.count(f"warning: run file {blank_mask_run.name} given twice") == 2
    assert f"(also as {blank_mask_run}): used once" in err
    doc = json.loads((tmp_path / "out" / "keyfigures.json").read_text())
    assert doc["runs"] == [blank_mask_run.name]
    assert [row["step"] for row in doc["depth_sweep"]] == ["00001_depth_sweep"]  # the run's one depth step, once


@pytest.fixture(scope="module")
def evaluation(tmp_path_factory: pytest.TempPathFactory, blank_mask_run: Path) -> Path:
    """``labctl evaluate`` of the face-mask run: no slanted edge, so no inter-eye distance to chart."""
    out = tmp_path_factory.mktemp("evaluation") / "ev"
    with pytest.raises(SystemExit) as done:
        main(["evaluate", str(blank_mask_run), "-o", str(out), "--quiet", "--no-pdf"])
    assert done.value.code == 0
    return out


def test_compare_warns_on_one_evaluation_and_on_the_same_twice(capsys, tmp_path: Path, evaluation: Path) -> None:
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        code, out, err = labctl(capsys, "compare", evaluation, f"{evaluation}/", "-o", tmp_path / "cmp")
    assert code == 0 and out.strip() == f"comparison: {tmp_path / 'cmp' / 'compare.html'}"
    assert f"warning: evaluation {evaluation} given twice" in err
    assert f"warning: one evaluation ({evaluation}): compare puts two or more cameras side by side" in err
    # every camera without an inter-eye distance: the chart's "n/a" once fell outside the axes and matplotlib warned
    assert not [str(w.message) for w in caught if "layout" in str(w.message)]
    assert json.loads((tmp_path / "cmp" / "compare.json").read_text())


def test_a_failed_compare_or_reconcile_leaves_no_output_folder(capsys, tmp_path: Path, evaluation: Path) -> None:
    code, _, err = labctl(capsys, "compare", evaluation, tmp_path / "nope", "-o", tmp_path / "cmp")
    assert code == 2 and f"{tmp_path / 'nope'} has no keyfigures.json" in err
    text = tmp_path / "c.toml"
    text.write_text(campaign_text())
    code, _, err = labctl(capsys, "reconcile", text, "-o", tmp_path / "rec", "--quiet")
    assert code == 2 and f"{text} is a text file (it begins '[campaign]'), not a labctl run file" in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["c.toml"]


# ---------------------------------------------------------------------- a serial port where nothing answers
def device_on_a_silent_port(capsys: pytest.CaptureFixture[str], device: str, *args: object) -> tuple[int, str, str]:
    """``labctl device DEVICE --port PORT ARGS`` on a real pseudo-terminal that nobody reads or answers (a device
    switched off or at another baud rate): (exit code, PORT, stderr)."""
    master, slave = os.openpty()
    try:
        port = os.ttyname(slave)
        code, _, err = labctl(capsys, "device", device, "--port", port, *args)
    finally:
        os.close(slave)
        os.close(master)
    return code, port, err


def test_a_silent_laser_port_gets_a_hint_to_check_power_and_line_settings(capsys) -> None:
    """A real pseudo-terminal that nobody reads or answers: a sensor switched off or at another baud rate."""
    code, port, err = device_on_a_silent_port(capsys, "laser", "--baud", "9600", "--count", "1")
    assert code == 1
    assert f"Dimetix laser on {port}: no complete reply" in err and "in reply to 's0c'" in err
    assert "is the sensor powered and wired to this port, set to 9600 baud 7E1 and device ID 0?" in err


# ---------------------------------------------------------------------- a wall analysed as a star
def test_analyze_boehler_of_a_plain_wall_reports_no_star(capsys, tmp_path: Path, blank_mask_run: Path) -> None:
    """The depth-sweep step of a simulated run is a plain wall at 2000 mm: once reported as a "72-segment
    star at 2006 mm"; a ray-cast star is still reported as one."""
    from tests.metrics.test_boehler import star_cloud

    wall = tmp_path / "wall.pcd"
    assert labctl(capsys, "export", blank_mask_run, "--step", "00001_depth_sweep", "--format", "pcd", "-o", wall)[0] == 0
    code, out, _ = labctl(capsys, "analyze", "boehler", wall, "--segments", "72")
    assert code == 0
    assert out.startswith(f"{wall}: no 72-segment star found on the nearest plane facing the camera (")
    assert "warning: no 72-segment star found: no ring on the plane at" in out and "segment star at" not in out
    code, out, _ = labctl(capsys, "analyze", "boehler", wall, "--segments", "72", "--json")
    doc = strict_json(out)
    assert code == 0 and doc["star_found"] is False and doc["resolution_mm"] is None
    star = tmp_path / "star.npy"
    np.save(star, star_cloud(24, 0.0, 0.0, size=(160, 120)))
    code, out, _ = labctl(capsys, "analyze", "boehler", star, "--segments", "24")
    assert code == 0 and out.startswith(f"{star}: 24-segment star at 50") and "star found" not in out
    doc = strict_json(labctl(capsys, "analyze", "boehler", star, "--segments", "24", "--json")[1])
    assert doc["star_found"] is True and doc["distance_mm"] == pytest.approx(math.hypot(40.0, 30.0, 500.0), abs=1.0)


# ---------------------------------------------------------------------- numbers that are not numbers
@pytest.mark.parametrize("args,message", [
    (["analyze", "boehler", "c.npy", "--segments", "72", "--inlier-mm", "nan"], "'--inlier-mm': 'nan' is not a finite number"),
    (["analyze", "checkerboard", "i.npy", "--tile-mm", "-3", "--distance-mm", "600", "--fov-deg", "67,51"],
     "'--tile-mm': '-3' is not positive"),
    (["analyze", "checkerboard", "i.npy", "--tile-mm", "19", "--distance-mm", "inf", "--fov-deg", "67,51"],
     "'--distance-mm': 'inf' is not a finite number"),
    (["device", "stage", "--port", "/dev/null", "--protocol", "zaber", "--mm-per-microstep", "inf"],
     "'--mm-per-microstep': 'inf' is not a finite number"),
    (["device", "stage", "--port", "/dev/null", "--protocol", "zaber", "--mm-per-microstep", "0.1", "--move-mm", "-5"],
     "'--move-mm': '-5' is below 0: positions count from home"),
    (["device", "camera", "--backend", "blaze", "--exposure-us", "nan", "-o", "x.h5"],
     "'--exposure-us': 'nan' is not a finite number"),
])
def test_numbers_that_are_not_finite_or_out_of_range_are_refused(capsys, tmp_path: Path, monkeypatch, args, message) -> None:
    """--inlier-mm nan was a traceback; --mm-per-microstep inf moved nothing and printed 'nan mm'."""
    monkeypatch.chdir(tmp_path)
    np.save("c.npy", np.zeros((20, 30, 3)))
    np.save("i.npy", np.zeros((20, 30)))
    code, _, err = labctl(capsys, *args)
    assert code == 2 and message in err


# ---------------------------------------------------------------------- batch inputs
def test_batch_refuses_a_run_file_as_the_sweep_and_a_text_file_as_a_run(capsys, tmp_path: Path,
                                                                         blank_mask_run: Path) -> None:
    """The sweep file was read as UTF-8 (a UnicodeDecodeError traceback); a text file named as a run started a
    cluster and failed as a task (exit 1)."""
    code, _, err = labctl(capsys, "batch", "sweep", blank_mask_run, "-o", tmp_path / "sweep")
    assert code == 2
    assert (f"sweep file {blank_mask_run} is an HDF5 file, not a TOML text file (a run file is evaluated with "
            "'labctl batch runs')") in err
    notes = tmp_path / "notes.h5"
    notes.write_text("run 3: laser off\n")
    code, _, err = labctl(capsys, "batch", "runs", notes, "-o", tmp_path / "runs", "--workers", "1")
    assert code == 2 and f"{notes} is a text file (it begins 'run 3: laser off'), not a labctl run file" in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["notes.h5"]


def test_an_empty_npy_file_is_bad_input_not_an_abort(capsys, tmp_path: Path) -> None:
    """numpy raises EOFError on an empty .npy, which click turns into "aborted" with exit 130 (as for Ctrl-C)."""
    empty = tmp_path / "empty.npy"
    empty.write_bytes(b"")
    for args, what in ((["sfr", empty], "image"), (["boehler", empty, "--segments", "24"], "cloud"),
                       (["checkerboard", empty, "--tile-mm", "19", "--distance-mm", "600", "--fov-deg", "67,51"], "image")):
        code, _, err = labctl(capsys, "analyze", *args)
        assert code == 2 and "aborted" not in err
        assert f"cannot read {what} {empty}: the file ends before its data (0 bytes; empty or truncated)" in err


def test_a_failed_evaluate_removes_the_output_folder_it_made(capsys, tmp_path: Path, blank_mask_run: Path) -> None:
    """Runs of two cameras: refused after the output folder was made, which is removed again (its parents
    too); an existing output folder stays."""
    (tmp_path / "flexx2.toml").write_text(campaign_text(backend="flexx2", procedures=textwrap.dedent(MASK_RUN)))
    (tmp_path / "model.toml").write_text(SMALL.replace("blaze101", "flexx2"))
    other = tmp_path / "flexx2.h5"
    assert labctl(capsys, "run", tmp_path / "flexx2.toml", "--sim", "--model", tmp_path / "model.toml", "-o", other,
                  "--quiet")[0] == 0
    code, _, err = labctl(capsys, "evaluate", blank_mask_run, other, "-o", tmp_path / "new" / "out", "--quiet", "--no-pdf")
    assert code == 2 and "evaluate one camera at a time" in err
    assert not (tmp_path / "new").exists()
    (tmp_path / "kept").mkdir()
    assert labctl(capsys, "evaluate", blank_mask_run, other, "-o", tmp_path / "kept", "--quiet", "--no-pdf")[0] == 2
    assert (tmp_path / "kept").is_dir()


def test_a_run_file_not_named_h5_is_written_with_a_warning(capsys, tmp_path: Path) -> None:
    """Legal, but 'labctl batch runs DIRECTORY' finds only *.h5 and *.hdf5."""
    campaign = tmp_path / "c.toml"
    campaign.write_text(campaign_text(procedures='[[procedure]]\nkind = "offset_calibration"\nframes = 2\n'))
    model = tmp_path / "m.toml"
    model.write_text(SMALL)
    code, _, err = labctl(capsys, "run", campaign, "--sim", "--model", model, "-o", tmp_path / "run.txt", "--quiet")
    assert code == 0 and (tmp_path / "run.txt").is_file()
    assert (f"warning: -o {tmp_path / 'run.txt'}: run files are named .h5 (labctl batch runs finds only *.h5 and "
            f"*.hdf5 in a directory); name it {tmp_path / 'run.h5'}") in err


@pytest.fixture
def read_only_disk(tmp_path: Path):
    """A small tmpfs mounted read-only (root only), unmounted again whatever the test does (``unmount``)."""
    import subprocess

    if os.geteuid() != 0:
        pytest.skip("mounting a read-only tmpfs needs root")
    mount = tmp_path / "ro"
    mount.mkdir()
    subprocess.run(["mount", "-t", "tmpfs", "-o", "ro,size=1m", "tmpfs", str(mount)], check=True)
    yield mount
    unmount(mount)


def test_outputs_on_a_read_only_disk_say_so(capsys, tmp_path: Path, read_only_disk: Path, blank_mask_run: Path) -> None:
    campaign = tmp_path / "c.toml"
    campaign.write_text(campaign_text())
    code, _, err = labctl(capsys, "run", campaign, "--sim", "-o", read_only_disk / "run.h5")
    assert code == 2 and f"-o {read_only_disk / 'run.h5'}: no file can be created in {read_only_disk} (Read-only" in err
    code, _, err = labctl(capsys, "evaluate", blank_mask_run, "-o", read_only_disk / "ev", "--quiet", "--no-pdf")
    assert code == 2
    assert f"cannot create the directory {read_only_disk / 'ev'} for -o: Read-only file system ({read_only_disk} " \
           "accepts no new entries)" in err


def test_a_stage_port_where_no_zaber_answers_gets_a_hint(capsys) -> None:
    """A real pseudo-terminal nobody answers, and a Grbl controller given as a Zaber stage."""
    from sim.emulators import GrblEmulator

    hint = "is a Zaber controller (ASCII protocol, device 1) powered and wired to this port at 115200 baud?"
    code, port, err = device_on_a_silent_port(capsys, "stage", "--protocol", "zaber", "--mm-per-microstep", "0.001")
    assert code == 1 and f"Zaber stage 1/1 on {port}: no complete reply" in err and hint in err
    with GrblEmulator(max_travel_mm=300.0) as grbl:
        port = grbl.port
        code, _, err = labctl(capsys, "device", "stage", "--port", port, "--protocol", "zaber", "--mm-per-microstep", "0.001")
    assert code == 1 and f"Zaber stage 1/1 on {port}: reply" in err and hint in err


def test_an_empty_output_name_is_refused(capsys, tmp_path: Path, blank_mask_run: Path, monkeypatch) -> None:
    """-o '' was the current directory: evaluate wrote its report there, run said '. already exists'."""
    monkeypatch.chdir(tmp_path)
    Path("c.toml").write_text(campaign_text())
    for command in (["evaluate", blank_mask_run, "--quiet"], ["run", "c.toml", "--sim"],
                    ["export", blank_mask_run, "--step", "00001_depth_sweep", "--format", "pcd"]):
        code, _, err = labctl(capsys, *command, "-o", "")
        assert code == 2 and "-o '' is empty: give the output's name" in err, (command, err)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["c.toml"]


def test_a_device_file_given_as_a_run_is_not_called_missing(capsys) -> None:
    code, _, err = labctl(capsys, "info", "/dev/null")
    assert code == 2 and "run file /dev/null is not a regular file" in err
