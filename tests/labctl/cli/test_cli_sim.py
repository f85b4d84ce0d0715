"""labctl sim preview / profiles."""

import json

import pytest

from labctl.cli import main


def invoke(*args) -> int:
    with pytest.raises(SystemExit) as info:
        main([str(a) for a in args])
    return info.value.code


def test_preview_writes_a_png(tmp_path):
    out = tmp_path / "p.png"
    assert invoke("sim", "preview", "--camera", "flexx2", "--target", "boehler_star", "--param", "segments=24",
                  "--distance-mm", "900", "-o", out) == 0
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_preview_with_a_model_file(tmp_path):
    model = tmp_path / "m.toml"
    model.write_text('camera = "d455"\n[camera_overrides]\nwidth = 64\nheight = 48\n')
    out = tmp_path / "p.png"
    assert invoke("sim", "preview", "--model", model, "--target", "silicone", "--angle-deg", "40", "-o", out) == 0
    assert out.stat().st_size > 1000


def test_preview_needs_a_camera(tmp_path, capsys):
    assert invoke("sim", "preview", "-o", tmp_path / "p.png") == 2
    assert "--camera" in capsys.readouterr().err


def test_profiles_json_lists_sources(capsys):
    assert invoke("sim", "profiles", "--json") == 0
    doc = json.loads(capsys.readouterr().out)
    assert set(doc) == {"blaze101", "amt100", "flexx2", "d455"}
    assert doc["d455"]["parameters"]["technology"] == "stereo"
    assert "Table 6-1" in " ".join(doc["blaze101"]["sources"].values())
