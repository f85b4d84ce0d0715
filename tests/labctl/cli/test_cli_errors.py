"""Bad input exits 2 with one clear message, no traceback and no run file (README.md, Command line)."""

import pytest

from tests.conftest import campaign_text

BROKEN = {
    "malformed_toml": ("[campaign\nname=", "not valid TOML"),
    "unknown_key": (campaign_text().replace("[sim]", "[sim]\nspeed = 3"), "unknown key 'speed' in [sim]"),
    "beyond_travel": (campaign_text().replace("stop_mm = 3000", "stop_mm = 9000"), "outside devices.stage.travel_mm"),
    "zero_frames": (campaign_text().replace("frames = 8\n\n", "frames = 0\n\n", 1), "procedure[0].frames"),
    "unknown_backend": (campaign_text(backend="kinect"), "devices.camera.backend"),
}


@pytest.mark.parametrize("case", sorted(BROKEN))
def test_broken_campaign_exits_2_without_traceback_or_run_file(case, tmp_path, labctl):
    text, expected = BROKEN[case]
    campaign = tmp_path / "c.toml"
    campaign.write_text(text)
    run_file = tmp_path / "run.h5"
    for args in (["plan", campaign], ["run", campaign, "--sim", "-o", run_file]):
        result = labctl(*args)
        assert result.returncode == 2, result.stderr
        assert expected in result.stderr
        assert "Traceback" not in result.stderr
        assert result.stdout == ""
    assert list(tmp_path.iterdir()) == [campaign]


def test_missing_campaign_file(tmp_path, labctl):
    result = labctl("plan", tmp_path / "nope.toml")
    assert result.returncode == 2 and f"campaign file {tmp_path / 'nope.toml'} does not exist" in result.stderr


def test_bad_arguments_exit_2(labctl):
    result = labctl("run")
    assert result.returncode == 2 and "Missing argument" in result.stderr


def test_model_without_sim_is_refused(tmp_path, write_campaign, small_model, labctl):
    result = labctl("run", write_campaign(), "-o", tmp_path / "r.h5", "--model", small_model())
    assert result.returncode == 2 and "--sim" in result.stderr
    assert not (tmp_path / "r.h5").exists()


def test_broken_model_file(tmp_path, write_campaign, labctl):
    model = tmp_path / "m.toml"
    model.write_text('camera = "blaze101"\n[effects.sparkle]\nlevel = 3\n')
    result = labctl("run", write_campaign(), "--sim", "--model", model, "-o", tmp_path / "r.h5")
    assert result.returncode == 2 and "unknown effect 'sparkle'" in result.stderr
    assert not (tmp_path / "r.h5").exists()


def test_existing_output_is_never_overwritten(tmp_path, write_campaign, labctl):
    out = tmp_path / "r.h5"
    out.write_bytes(b"precious")
    result = labctl("run", write_campaign(), "--sim", "-o", out)
    assert result.returncode == 2 and "already exists" in result.stderr
    assert out.read_bytes() == b"precious"


def test_foreign_file_for_evaluate_and_resume(tmp_path, labctl):
    import h5py

    foreign = tmp_path / "other.h5"
    with h5py.File(foreign, "w") as f:
        f.attrs["format"] = "something-else"
    text_file = tmp_path / "notes.h5"
    text_file.write_text("not hdf5")
    for path in (foreign, text_file):
        for args in (["evaluate", path, "-o", tmp_path / "out"], ["resume", path]):
            result = labctl(*args)
            assert result.returncode == 2, (args, result.stderr)
            assert str(path) in result.stderr and "Traceback" not in result.stderr


def test_help_for_every_command(labctl):
    for command in ("plan", "run", "resume", "evaluate"):
        result = labctl(command, "--help")
        assert result.returncode == 0 and "Usage" in result.stdout
