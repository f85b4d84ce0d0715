"""kill -9 in the middle of a simulated run, then resume: every step once, same key figures."""

import json
import os
import signal
import subprocess
import sys

import h5py

from tests.conftest import run_labctl

PROCEDURES = """
[[procedure]]
kind = "offset_calibration"
frames = 120

[[procedure]]
kind = "depth_sweep"
start_mm = 1000
stop_mm = 3000
step_mm = 250
frames = 120
"""


def start_run(campaign, model, out):
    return subprocess.Popen(
        [sys.executable, "-m", "labctl", "run", str(campaign), "--sim", "--model", str(model), "-o", str(out)],
        stderr=subprocess.PIPE, stdout=subprocess.DEVNULL, text=True,
    )


def wait_for_line(proc, text):
    for line in proc.stderr:
        if text in line:
            return
    raise AssertionError(f"run ended before printing {text!r}")


def figures(outdir):
    doc = json.loads((outdir / "keyfigures.json").read_text())
    return {name: f["value"] for name, f in doc["figures"].items()}


def test_kill_9_then_resume_gives_identical_key_figures(tmp_path, write_campaign, small_model):
    campaign, model = write_campaign(procedures=PROCEDURES), small_model(width=160, height=120)
    killed = tmp_path / "killed.h5"
    proc = start_run(campaign, model, killed)
    wait_for_line(proc, "00002_depth_sweep complete")
    proc.send_signal(signal.SIGKILL)
    proc.wait(timeout=30)
    with h5py.File(killed, "r") as f:
        assert f.attrs["status"] == "running"
        complete = [k for k, g in f["steps"].items() if g.attrs["complete"]]
    assert 3 <= len(complete) < 10, complete

    resumed = run_labctl("resume", killed)
    assert resumed.returncode == 0, resumed.stderr
    reference = tmp_path / "reference.h5"
    assert run_labctl("run", campaign, "--sim", "--model", model, "-o", reference).returncode == 0

    with h5py.File(killed, "r") as f:
        ids = sorted(f["steps"].keys())
        assert all(f["steps"][k].attrs["complete"] for k in ids)
        assert f.attrs["status"] == "complete"
    assert ids == [f"{i:05d}_{'offset_calibration' if i == 0 else 'depth_sweep'}" for i in range(10)]

    for run, out in ((killed, tmp_path / "k"), (reference, tmp_path / "r")):
        result = run_labctl("evaluate", run, "-o", out, "--no-pdf")
        assert result.returncode == 0, result.stderr
    assert figures(tmp_path / "k") == figures(tmp_path / "r")
    assert figures(tmp_path / "k")["z_precision_q90_mm"] is not None


def test_sigint_marks_run_aborted_and_exits_130(tmp_path, write_campaign, small_model):
    campaign, model = write_campaign(procedures=PROCEDURES), small_model(width=160, height=120)
    out = tmp_path / "r.h5"
    proc = start_run(campaign, model, out)
    wait_for_line(proc, "00001_depth_sweep complete")
    os.kill(proc.pid, signal.SIGINT)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 130, err
    assert "labctl resume" in err and "Traceback" not in err
    with h5py.File(out, "r") as f:
        assert f.attrs["status"] == "aborted"
    assert run_labctl("resume", out).returncode == 0
