"""``labctl info``: a run file's header and every step with status, target, position and frames."""

from __future__ import annotations

import json

import numpy as np
import pytest

from drivers.protocols import CameraInfo, DeviceIdentity, Frame
from labctl.cli import main
from labctl.run.config import parse_campaign
from labctl.run.store import RunWriter
from tests.conftest import campaign_text

CAMERA = CameraInfo(width=8, height=6, fov_deg=(67.0, 51.0), pixel_pitch_um=10.0, frame_rate_hz=30.0,
                    wavelength_nm=940.0, confidence_dtype="uint16")


def invoke(*args) -> int:
    with pytest.raises(SystemExit) as info:
        main([str(a) for a in args])
    return info.value.code


@pytest.fixture
def interrupted_run(tmp_path):
    """A run of the test campaign (offset + depth sweep 1000..3000 mm step 500, 8 frames each) cut off
    during its second step: one complete step, one unfinished, four pending."""
    text = campaign_text()
    steps = parse_campaign(text).steps()
    path = tmp_path / "run.h5"
    run = RunWriter.create(path, campaign_toml=text, simulated=True,
                           devices={"camera": (DeviceIdentity("sim", "cam", "1", "1"), {})}, camera=CAMERA, steps=len(steps))
    a = np.full((6, 8), 1000.0, np.float32)
    writer = run.begin_step(steps[0], stage_position_mm=1234.5)
    for k in range(steps[0].frames):
        writer.write(k, Frame(a, a, a, a, np.ones((6, 8), np.uint16), k / 30))
    writer.commit({})
    run.begin_step(steps[1], stage_position_mm=1000.0)  # never committed
    run.set_status("aborted", "test stop")
    run.close()
    return path


def test_info_json_lists_every_step_with_status_and_the_header(interrupted_run, capsys):
    assert invoke("info", interrupted_run, "--json") == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["campaign"] == "test" and doc["status"] == "aborted" and doc["status_reason"] == "test stop"
    assert doc["simulated"] is True and doc["compression"] == "blosc-lz4" and doc["filters"] == "blosc (32001)"
    assert doc["size_bytes"] == interrupted_run.stat().st_size and doc["created"]
    statuses = [s["status"] for s in doc["steps"]]
    assert statuses == ["complete", "unfinished", "pending", "pending", "pending", "pending"]
    ids = [s["step_id"] for s in doc["steps"]]
    assert ids == ["00000_offset_calibration"] + [f"0000{i}_depth_sweep" for i in range(1, 6)]
    first, second = doc["steps"][:2]
    assert first["stage_position_mm"] == 1234.5 and first["robot_angle_deg"] is None and first["frames"] == 8
    assert second["stage_position_mm"] == 1000.0 and second["target"] == "wall"
    assert [s["distance_mm"] for s in doc["steps"][1:]] == [1000.0, 1500.0, 2000.0, 2500.0, 3000.0]
    assert (doc["steps_complete"], doc["steps_total"]) == (1, 6)
    assert (doc["frames_complete"], doc["frames_total"]) == (8, 48)


def test_info_text_has_one_line_per_step(interrupted_run, capsys):
    assert invoke("info", interrupted_run) == 0
    lines = capsys.readouterr().out.splitlines()
    assert "campaign test" in lines[0] and "status aborted (test stop)" in lines[0]
    assert "compression blosc-lz4" in lines[1] and "steps 1/6 complete, frames 8/48" in lines[2]
    rows = lines[4:]
    assert len(rows) == 6
    assert rows[0].split()[:3] == ["00000_offset_calibration", "complete", "wall"] and "stage 1234.5 mm" in rows[0]
    assert rows[1].split()[:2] == ["00001_depth_sweep", "unfinished"]


def test_info_of_a_missing_file_names_it(tmp_path, capsys):
    assert invoke("info", tmp_path / "nope.h5") == 2
    assert str(tmp_path / "nope.h5") in capsys.readouterr().err
