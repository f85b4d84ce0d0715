"""Disk space: plan states the run file's size, run/resume refuse to start without room, and a disk that
fills during a run stops it safely before the next step (file valid, devices safe, resumable)."""

from __future__ import annotations

import json

import h5py
import pytest

from labctl.cli import main
from labctl.run import diskspace
from labctl.run.diskspace import MARGIN_BYTES

W, H = 48, 36
FRAME_BYTES = W * H * (4 * 4 + 2)  # x, y, z, intensity float32 + uint16 confidence (docs/runfile.md)
STEP_FRAMES = 8
STEPS = 6  # offset calibration + depth sweep 1000..3000 mm in 500 mm steps (tests/conftest.py)


def invoke(*args) -> int:
    with pytest.raises(SystemExit) as info:
        main([str(a) for a in args])
    return info.value.code


class FillingDisk:
    """free_bytes of a disk with ``capacity`` that the run file and another writer (``rate`` bytes per
    free-space query, i.e. per step) fill."""

    def __init__(self, run_file, capacity: int, rate: int = 0) -> None:
        self.run_file, self.capacity, self.rate, self.queries = run_file, capacity, rate, 0

    def __call__(self, path) -> int:
        self.queries += 1
        used = self.run_file.stat().st_size if self.run_file.exists() else 0
        return max(0, self.capacity - used - self.rate * self.queries)


def complete_steps(path):
    with h5py.File(path, "r") as f:
        return f.attrs["status"], {k: bool(g.attrs["complete"]) for k, g in f["steps"].items()}


def test_plan_states_lab_time_and_file_size(write_campaign, capsys):
    campaign = write_campaign()
    assert invoke("plan", campaign, "--compression", "none") == 0
    header = capsys.readouterr().out.splitlines()[0]
    # blaze101 profile: 640 x 480, uint16 confidence; 6 steps x 8 frames, uncompressed
    assert f"run file about {48 * 640 * 480 * 18 / 1e6:.2f} MB" in header and "estimated lab time" in header
    assert invoke("plan", campaign, "--json") == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["uncompressed_bytes"] == 48 * 640 * 480 * 18
    assert doc["compression"] == "blosc-lz4" and doc["expected_file_bytes"] < doc["uncompressed_bytes"]


def test_run_refuses_to_start_without_room(tmp_path, write_campaign, small_model, monkeypatch, capsys):
    out = tmp_path / "run.h5"
    monkeypatch.setattr(diskspace, "free_bytes", FillingDisk(out, MARGIN_BYTES + FRAME_BYTES * 10))
    code = invoke("run", write_campaign(), "--sim", "--model", small_model(width=W, height=H), "-o", out,
                  "--compression", "none", "--quiet")
    assert code == 1
    err = capsys.readouterr().err
    assert "not enough free space in" in err and str(tmp_path) in err and "remaining step(s)" in err
    assert not out.exists() and list(tmp_path.glob(".run.h5*")) == []


def test_disk_filling_during_a_run_stops_it_safely_and_resume_completes(
    tmp_path, write_campaign, small_model, monkeypatch, capsys
):
    out = tmp_path / "run.h5"
    raw_run = STEPS * STEP_FRAMES * FRAME_BYTES
    # room for the whole run at the start; another writer then takes a run's worth every 3 steps
    disk = FillingDisk(out, MARGIN_BYTES + 2 * raw_run, rate=raw_run // 3)
    monkeypatch.setattr(diskspace, "free_bytes", disk)
    campaign, model = write_campaign(), small_model(width=W, height=H)
    assert invoke("run", campaign, "--sim", "--model", model, "-o", out, "--compression", "none") == 1
    err = capsys.readouterr().err
    assert "not enough free space" in err and "Devices are in their safe state" in err and f"labctl resume {out}" in err
    status, steps = complete_steps(out)  # the file opens: valid HDF5
    assert status == "aborted"
    assert 1 <= len(steps) < STEPS and all(steps.values())  # stopped before writing the step it had no room for
    with h5py.File(out, "r") as f:
        for g in f["steps"].values():
            assert g["z"].shape == (STEP_FRAMES, H, W)

    monkeypatch.setattr(diskspace, "free_bytes", FillingDisk(out, MARGIN_BYTES + 4 * raw_run))  # space freed
    assert invoke("resume", out, "--quiet") == 0
    status, steps = complete_steps(out)
    assert status == "complete" and len(steps) == STEPS and all(steps.values())
