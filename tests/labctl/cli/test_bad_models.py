"""Bad simulation models and simulation options: exit 2 and one message naming the file, field or option and
its value, before any run file exists; a warning where the input is legal but likely a mistake (a model of
another camera than the measured run's)."""

from __future__ import annotations

import json
from pathlib import Path

import h5py
import pytest

from labctl.cli import main
from tests.conftest import campaign_text


def labctl(capsys: pytest.CaptureFixture[str], *args: object) -> tuple[int, str, str]:
    """Run the command line in-process: (exit code, stdout, stderr); never a traceback."""
    with pytest.raises(SystemExit) as done:
        main([str(a) for a in args])
    out, err = capsys.readouterr()
    assert "Traceback" not in out + err
    return int(done.value.code or 0), out, err


def model_file(directory: Path, extra: str, camera: str = "blaze101", name: str = "model.toml") -> Path:
    """A 32 x 24 model of ``camera``: the ``key = value`` lines of ``extra`` before its first ``[table]`` line
    go to [camera_overrides] (replacing width or height), the rest is appended."""
    lines = extra.splitlines()
    first_table = next((i for i, line in enumerate(lines) if line.startswith("[")), len(lines))
    overrides = {"width": "32", "height": "24"}
    for line in lines[:first_table]:
        key, _, value = line.partition("=")
        overrides[key.strip()] = value.strip()
    text = f'camera = "{camera}"\n[camera_overrides]\n' + "".join(f"{k} = {v}\n" for k, v in overrides.items())
    path = directory / name
    path.write_text(text + "".join(f"{line}\n" for line in lines[first_table:]))
    return path


@pytest.fixture(scope="module")
def measured_flexx2(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A small flexx2 run without /sim, as a measured run is."""
    directory = tmp_path_factory.mktemp("flexx2")
    (directory / "campaign.toml").write_text(campaign_text(backend="flexx2"))
    model = model_file(directory, "", camera="flexx2")
    run = directory / "run.h5"
    with pytest.raises(SystemExit) as done:
        main(["run", str(directory / "campaign.toml"), "--sim", "--model", str(model), "-o", str(run), "--quiet"])
    assert done.value.code == 0
    with h5py.File(run, "r+") as f:
        del f["sim"]
    return run


# ---------------------------------------------------------------------- [camera_overrides] and the other tables
# (the model's extra lines, what the message must name, the value it must show); every value here made a
# traceback, a division by zero or a silent nonsense run before the model was validated
BAD_MODELS = [
    ("width = -160", "camera_overrides.width", "(got -160)"),
    ("height = 0", "camera_overrides.height", "(got 0)"),
    ("width = 0", "camera_overrides.width", "(got 0)"),
    ('width = "160"', "camera_overrides.width", "(got '160')"),
    ("width = 100.5", "camera_overrides.width", "(got 100.5)"),
    ("fov_h_deg = 0", "camera_overrides.fov_h_deg", "(got 0)"),
    ("fov_v_deg = 180", "camera_overrides.fov_v_deg", "(got 180)"),
    ("modulation_mhz = 0", "modulation_mhz = 0 on a ToF camera", ">= 1 MHz"),
    ("modulation_mhz = 1e-300", "modulation_mhz = 1e-300 on a ToF camera", ">= 1 MHz"),
    ("frame_rate_hz = 0", "camera_overrides.frame_rate_hz", "(got 0)"),
    ("exposure_us = 0", "camera_overrides.exposure_us", "(got 0)"),
    ("noise_mm_at_2m = -2", "camera_overrides.noise_mm_at_2m", "(got -2)"),
    ("noise_mm_at_2m = 0", "noise_mm_at_2m = 0 on a ToF camera", ">= 0.001 mm"),
    ("wavelength_nm = 0", "camera_overrides.wavelength_nm", "(got 0)"),
    ("pixel_pitch_um = 0", "camera_overrides.pixel_pitch_um", "(got 0)"),
    ("lens_sigma_px = 50", "camera_overrides.lens_sigma_px", "(got 50)"),
    ("min_range_mm = 20000", "max_range_mm = 10000 is not above min_range_mm = 20000", "min_range_mm < max_range_mm"),
    ("technology = \"stereo\"", "baseline_mm = 0 on a stereo camera", ">= 1 mm"),
    ("fov_h_deg = nan", "camera_overrides.fov_h_deg", "finite number (got nan)"),
    ("colour = 3", "unknown profile field 'colour'", "fov_h_deg"),
    ("[lab]\ncamera_mount_error_mm = inf", "lab.camera_mount_error_mm", "(got inf)"),
    ("[lab]\ncamera_mount_error_mm = -5000", "lab.camera_mount_error_mm", "(got -5000)"),
    ("[lab]\nlaser_noise_mm = 1e12", "lab.laser_noise_mm", "(got 1000000000000.0)"),
    ("[effects.fixed_pattern]\npixel_sigma_mm = 1\ngrid_px = [0, 24]", "effects.fixed_pattern: grid_px.0", "(got 0)"),
    ("[effects.fixed_pattern]\ncolumn_offsets_mm = [0.5, 1e300]", "effects.fixed_pattern: column_offsets_mm.1",
     "(got 1e+300)"),
    ("[effects.empirical_range]\nrange_mm = [0, nan]\ncorrection_mm = [0, 1]", "effects.empirical_range: range_mm.1",
     "(got nan)"),
    ("[effects.wiggling]\nperiod_mm = 0", "effects.wiggling: period_mm", "(got 0)"),
]


@pytest.mark.parametrize(("extra", "field", "value"), BAD_MODELS, ids=[b[0].splitlines()[-1] for b in BAD_MODELS])
def test_a_bad_model_stops_the_run_before_the_run_file_exists(capsys, tmp_path: Path, extra: str, field: str,
                                                              value: str) -> None:
    (tmp_path / "campaign.toml").write_text(campaign_text())
    model = model_file(tmp_path, extra)
    code, _, err = labctl(capsys, "run", tmp_path / "campaign.toml", "--sim", "--model", model,
                          "-o", tmp_path / "run.h5", "--quiet")
    assert code == 2
    assert err.startswith(f"labctl: error: {model} is not a valid simulation model: ")
    assert field in err and value in err, err
    assert not (tmp_path / "run.h5").exists()


def test_a_stereo_model_takes_no_tof_bounds(capsys, tmp_path: Path) -> None:
    """The ToF-only checks leave a stereo camera alone: a noiseless D455 has no modulation and is legal."""
    (tmp_path / "campaign.toml").write_text(campaign_text(backend="d455"))
    model = model_file(tmp_path, "noise_mm_at_2m = 0\nmodulation_mhz = 0", camera="d455")
    code, _, err = labctl(capsys, "run", tmp_path / "campaign.toml", "--sim", "--model", model,
                          "-o", tmp_path / "run.h5", "--quiet")
    assert code == 0, err
    model = model_file(tmp_path, "baseline_mm = 0", camera="d455")
    code, _, err = labctl(capsys, "run", tmp_path / "campaign.toml", "--sim", "--model", model,
                          "-o", tmp_path / "run2.h5", "--quiet")
    assert code == 2 and "baseline_mm = 0 on a stereo camera (d455): give the baseline, >= 1 mm" in err


def test_the_same_bad_model_in_preview_and_reconcile(capsys, tmp_path: Path, measured_flexx2: Path) -> None:
    model = model_file(tmp_path, "fov_h_deg = 0", camera="flexx2")
    expected = f"{model} is not a valid simulation model: camera_overrides.fov_h_deg: Input should be greater than 0 (got 0)"
    code, _, err = labctl(capsys, "sim", "preview", "--model", model, "--target", "wall", "-o", tmp_path / "p.png")
    assert code == 2 and expected in err
    code, _, err = labctl(capsys, "reconcile", measured_flexx2, "--model", model, "-o", tmp_path / "out", "--quiet")
    assert code == 2 and expected in err
    assert not (tmp_path / "p.png").exists() and not (tmp_path / "out" / "reconcile.json").exists()


def test_resume_of_a_file_whose_stored_model_is_bad(capsys, tmp_path: Path) -> None:
    """A run file an older labctl wrote with an unchecked model (``camera -160 x 0``): resume names the stored
    model's field instead of failing like the run did."""
    (tmp_path / "campaign.toml").write_text(campaign_text())
    model = model_file(tmp_path, "")
    run = tmp_path / "run.h5"
    assert labctl(capsys, "run", tmp_path / "campaign.toml", "--sim", "--model", model, "-o", run, "--quiet")[0] == 0
    with h5py.File(run, "r+") as f:
        f["sim"].attrs["model_toml"] = 'camera = "blaze101"\n[camera_overrides]\nwidth = -160\nheight = 0\n'
        f.attrs["status"] = "aborted"
    code, _, err = labctl(capsys, "resume", run, "--quiet")
    assert code == 2
    assert f"{run} (stored model) is not a valid simulation model: camera_overrides.width" in err
    assert "(got -160)" in err and "camera_overrides.height" in err and "(got 0)" in err


# ---------------------------------------------------------------------- a model of another camera
def test_a_flexx2_campaign_with_a_blaze101_model_is_refused(capsys, tmp_path: Path) -> None:
    (tmp_path / "campaign.toml").write_text(campaign_text(backend="flexx2"))
    model = model_file(tmp_path, "")
    code, _, err = labctl(capsys, "run", tmp_path / "campaign.toml", "--sim", "--model", model,
                          "-o", tmp_path / "run.h5", "--quiet")
    assert code == 2
    assert (f"--model {model} does not fit campaign {tmp_path / 'campaign.toml'}: the model simulates camera "
            "'blaze101', but the campaign's [devices.camera] backend = 'flexx2' is simulated as 'flexx2'") in err
    assert 'camera = "flexx2"' in err and 'backend = "blaze101"' in err  # the two fixes
    assert not (tmp_path / "run.h5").exists()


def test_reconcile_with_a_model_of_another_camera_warns(capsys, tmp_path: Path, measured_flexx2: Path) -> None:
    model = model_file(tmp_path, "")
    code, _, err = labctl(capsys, "reconcile", measured_flexx2, "--model", model, "-o", tmp_path / "out",
                          "--null-runs", "0", "--quiet")
    assert code == 0
    warning = (f"labctl: warning: {model}: the model simulates camera 'blaze101' but the run was taken with backend "
               "'flexx2' (profile 'flexx2')")
    assert warning in err
    notes = json.loads((tmp_path / "out" / "reconcile.json").read_text())["notes"]
    assert any(n.startswith("camera mismatch: the model simulates camera 'blaze101'") for n in notes)


# ---------------------------------------------------------------------- sim preview options
@pytest.mark.parametrize(("args", "message"), [
    (["--camera", "flexx2", "--target", "boehler_star", "--param", "segments=abc"],
     "--param 'segments=abc': segments of boehler_star is a whole number (default 72), got 'abc'"),
    (["--camera", "flexx2", "--target", "boehler_star", "--param", "foo=bar"],
     "--param 'foo=bar': target boehler_star has no parameter 'foo'; its parameters are segments, gap_mm,"),
    (["--camera", "flexx2", "--target", "checkerboard", "--param", "tile_mm=0"],
     "--param 'tile_mm=0': tile_mm of checkerboard must be > 0"),
    (["--camera", "flexx2", "--target", "boehler_star", "--param", "segments=1"],
     "--param 'segments=1': segments of boehler_star must be at least 2"),
    (["--camera", "flexx2", "--target", "face_mask", "--param", "gap_mm=1500"],
     "--param gap_mm=1500: the target stands gap_mm in front of the wall, so 0 <= gap_mm < --distance-mm (1000)"),
    (["--camera", "flexx2", "--target", "wall", "--param", "gap_mm=2"],
     "--param 'gap_mm=2': target wall has no parameter 'gap_mm'; it takes none"),
    (["--camera", "flexx2", "--target", "wall", "--distance-mm", "-100"],
     "Invalid value for '--distance-mm': -100.0 is not in the range x>0"),
    (["--camera", "flexx2", "--target", "silicone", "--angle-deg", "95"],
     "Invalid value for '--angle-deg': 95.0 is not in the range -90.0<x<90.0"),
    (["--camera", "flexx2", "--target", "silicone", "--distance-mm", "500"],
     "--distance-mm does not apply to target silicone: it is placed with --angle-deg"),
    (["--camera", "flexx2", "--target", "wall", "--angle-deg", "30"],
     "--angle-deg does not apply to target wall: it is placed with --distance-mm"),
    (["--camera", "flexx2", "--param", "segments=24"], "--param applies to one scene: add --target"),
])
def test_preview_options_are_checked(capsys, tmp_path: Path, args: list[str], message: str) -> None:
    code, _, err = labctl(capsys, "sim", "preview", *args, "-o", tmp_path / "p.png")
    assert code == 2 and message in err, err
    assert not (tmp_path / "p.png").exists()


def test_preview_camera_and_a_model_of_another_camera(capsys, tmp_path: Path) -> None:
    model = model_file(tmp_path, "", camera="flexx2")
    code, _, err = labctl(capsys, "sim", "preview", "--camera", "d455", "--model", model, "-o", tmp_path / "p.png")
    assert code == 2
    assert f'--camera d455 and --model {model} (camera = "flexx2") disagree' in err
    code, _, _ = labctl(capsys, "sim", "preview", "--camera", "flexx2", "--model", model, "--target", "wall",
                        "-o", tmp_path / "p.png")
    assert code == 0  # the same camera twice is no contradiction


# ---------------------------------------------------------------------- batch sweep
def sweep_dir(tmp_path: Path, sweep: str, backend: str = "blaze") -> Path:
    (tmp_path / "campaign.toml").write_text(campaign_text(backend=backend))
    (tmp_path / "sweep.toml").write_text(sweep)
    return tmp_path / "sweep.toml"


@pytest.mark.parametrize(("sweep", "message"), [
    ('[sweep]\ncampaign = "campaign.toml"\n[grid]\n"model.camera_overrides.width" = [160, 0]\n',
     "point p0001 (model.camera_overrides.width = 0): model is not a valid simulation model: "
     "camera_overrides.width: Input should be greater than or equal to 1 (got 0)"),
    ('[sweep]\ncampaign = "campaign.toml"\nfigures = ["z_accuracy_q90_mm", "z_acuracy_q90_mm"]\n',
     "[sweep] figures: unknown key figure(s) 'z_acuracy_q90_mm'; the names are those of docs/keyfigures.md"),
])
def test_a_bad_sweep_exits_2_before_any_task(capsys, tmp_path: Path, sweep: str, message: str) -> None:
    path = sweep_dir(tmp_path, sweep)
    code, _, err = labctl(capsys, "batch", "sweep", path, "-o", tmp_path / "out", "--workers", "1", "--quiet")
    assert code == 2 and message in err, err
    assert not (tmp_path / "out").exists()  # no cluster, no point started


def test_a_sweep_whose_model_is_of_another_camera(capsys, tmp_path: Path) -> None:
    path = sweep_dir(tmp_path, '[sweep]\ncampaign = "campaign.toml"\nmodel = "model.toml"\n', backend="flexx2")
    model_file(tmp_path, "")
    code, _, err = labctl(capsys, "batch", "sweep", path, "-o", tmp_path / "out", "--quiet")
    assert code == 2
    assert ("point p0000 (no grid): the model simulates camera 'blaze101', but the campaign's [devices.camera] "
            "backend = 'flexx2' is simulated as 'flexx2'; set [sweep] camera = \"blaze101\"") in err
    assert not (tmp_path / "out").exists()


# ---------------------------------------------------------------------- a file that is no model
def test_a_run_file_or_binary_data_given_as_the_model_is_named_for_what_it_is(capsys, tmp_path: Path) -> None:
    (tmp_path / "campaign.toml").write_text(campaign_text())
    run = tmp_path / "earlier.h5"
    with h5py.File(run, "w"):
        pass
    binary = tmp_path / "model.toml"
    binary.write_bytes(bytes([0xFF, 0xFE, 0x00, 0x01]) * 4)
    for model, kind in ((run, "an HDF5 file (a run file?)"), (binary, "not text")):
        code, _, err = labctl(capsys, "run", tmp_path / "campaign.toml", "--sim", "--model", model,
                              "-o", tmp_path / "run.h5", "--quiet")
        assert code == 2 and f"model file {model} is {kind}" in err and "a model file is TOML text" in err
        assert "codec" not in err and not (tmp_path / "run.h5").exists()
