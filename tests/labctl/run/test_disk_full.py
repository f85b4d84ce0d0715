"""The disk fills up during a step, on a real file system: another process takes the free space while the
run writes a step's frames. The run ends like any other fault (exit 1, no crash, a message naming the mount
point and the space needed, the file marked aborted); after the space is freed, resume completes it with the
key figures of an uninterrupted run.

Before the run file reserved each step's space, HDF5 hit "No space left on device" inside the step and the
process died of SIGSEGV (exit 139 / -11 from Popen) with the file left `running` and unresumable.

The last test fails the disk itself: the run file's ext4 lies on a loop device whose store is full, so the
device answers writes with errors (I/O errors in the kernel log) while the file system still shows free space.
"""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time

import h5py
import pytest

from tests.conftest import SMALL_MODEL, campaign_text, run_labctl
from tests.labctl.run.small_fs import failing_disk, fill, small_fs

# 6 steps of 30 frames of 160 x 120: 10.4 MB raw each, about 6 MB stored
PROCEDURES = """
[[procedure]]
kind = "offset_calibration"
frames = 30

[[procedure]]
kind = "depth_sweep"
start_mm = 1000
stop_mm = 2000
step_mm = 250
frames = 30
"""
STEPS = 6
LEFT_FREE = 3 * 2**20


@pytest.fixture(scope="module")
def sweep(tmp_path_factory):
    """The campaign, the model, and the key figures of its uninterrupted run (one run for every test here)."""
    root = tmp_path_factory.mktemp("sweep")
    campaign, model = root / "campaign.toml", root / "model.toml"
    campaign.write_text(campaign_text(procedures=PROCEDURES))
    model.write_text(SMALL_MODEL.format(camera="blaze101", width=160, height=120))
    reference = root / "reference.h5"
    result = run_labctl("run", campaign, "--sim", "--model", model, "-o", reference)
    assert result.returncode == 0, result.stderr
    expected = figures(reference, root / "reference")
    assert expected["z_precision_q90_mm"] is not None
    return campaign, model, expected


def figures(run, out) -> dict:
    result = run_labctl("evaluate", run, "-o", out, "--no-pdf")
    assert result.returncode == 0, result.stderr
    doc = json.loads((out / "keyfigures.json").read_text())
    return {name: f["value"] for name, f in doc["figures"].items()}


def run_filling_the_disk_during(step_id: str, campaign, model, out, mnt) -> tuple[int, str]:
    """``labctl run`` into ``out``; once ``step_id`` has started writing (the line of the step before it says
    complete, then the file grows), the process is stopped, the file system filled but LEFT_FREE, and
    the process continued. Returns the exit code and stderr."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "labctl", "run", str(campaign), "--sim", "--model", str(model), "-o", str(out)],
        stderr=subprocess.PIPE, stdout=subprocess.DEVNULL, text=True,
    )
    lines = []
    previous = f"{int(step_id[:5]) - 1:05d}_"
    try:
        for line in proc.stderr:
            lines.append(line)
            if line.startswith(previous) and line.rstrip().endswith("complete"):
                size = out.stat().st_size
                deadline = time.monotonic() + 60
                while out.stat().st_size == size and proc.poll() is None:  # begin_step's flush: the step has started
                    assert time.monotonic() < deadline, "the run file did not grow after the step started"
                    time.sleep(0.001)
                proc.send_signal(signal.SIGSTOP)
                fill(mnt, LEFT_FREE)
                proc.send_signal(signal.SIGCONT)
                break
        lines.append(proc.stderr.read())
        return proc.wait(timeout=120), "".join(lines)
    finally:  # a failure on the way leaves no run holding its file on the small file system, which must unmount
        if proc.poll() is None:
            proc.send_signal(signal.SIGCONT)
            proc.kill()
            proc.wait()
        proc.stderr.close()


@pytest.mark.slow
@pytest.mark.parametrize("kind", ["ext4", "tmpfs"])
def test_disk_filling_inside_a_step_aborts_cleanly_and_resume_completes(kind, tmp_path, sweep):
    campaign, model, expected = sweep
    with small_fs(kind, tmp_path, 128) as mnt:
        out = mnt / "run.h5"
        code, err = run_filling_the_disk_during("00002_depth_sweep", campaign, model, out, mnt)
        assert code == 1, err
        assert "Traceback" not in err and "Fatal Python error" not in err
        assert f"free space in {mnt}" in err or f"file system mounted at {mnt}" in err, err
        assert "needs" in err and "MB" in err and f"labctl resume {out}" in err
        assert "could not mark the run aborted" not in err
        info = run_labctl("info", out, "--json")
        assert info.returncode == 0, info.stderr
        doc = json.loads(info.stdout)
        assert doc["status"] == "aborted"
        done = [s["step_id"] for s in doc["steps"] if s["status"] == "complete"]
        # the step that was writing when the disk filled had its space reserved: it completes
        assert done[:3] == ["00000_offset_calibration", "00001_depth_sweep", "00002_depth_sweep"], done
        assert len(done) < STEPS

        (mnt / "filler").unlink()
        resumed = run_labctl("resume", out)
        assert resumed.returncode == 0, resumed.stderr
        with h5py.File(out, "r") as f:
            assert f.attrs["status"] == "complete"
            assert sorted(f["steps"]) == [f"{i:05d}_{'offset_calibration' if i == 0 else 'depth_sweep'}"
                                          for i in range(STEPS)]
        assert figures(out, tmp_path / "resumed") == expected


@pytest.mark.slow
def test_a_write_failing_inside_hdf5_ends_the_run_without_a_crash_and_the_run_completes(tmp_path, sweep):
    """ext4 without extents has no fallocate, so nothing is reserved and the full disk fails HDF5's own writes
    (the path an I/O error takes): exit 1 and a message instead of SIGSEGV; the file keeps its complete steps,
    and resume (in place, or --into a new file when the failed flush left it damaged) completes the run."""
    campaign, model, expected = sweep
    with small_fs("ext4-noextents", tmp_path, 128) as mnt:
        out = mnt / "run.h5"
        code, err = run_filling_the_disk_during("00002_depth_sweep", campaign, model, out, mnt)
        assert code == 1, err
        assert "Traceback" not in err and "Fatal Python error" not in err
        assert f"on the file system mounted at {mnt}" in err and "No space left on device" in err, err
        info = run_labctl("info", out)
        assert info.returncode in (0, 2) and "Traceback" not in info.stderr, info.stderr
        (mnt / "filler").unlink()
        resumed, target = run_labctl("resume", out), out
        if resumed.returncode == 2 and "--into NEW.h5" in resumed.stderr:
            assert "00000_offset_calibration .. 00001_depth_sweep" in resumed.stderr, resumed.stderr
            target = tmp_path / "into.h5"
            resumed = run_labctl("resume", out, "--into", target)
        assert resumed.returncode == 0, resumed.stderr
        assert figures(target, tmp_path / "resumed") == expected


@pytest.mark.slow
def test_a_disk_failing_its_writes_ends_the_run_without_a_crash_and_the_run_completes(tmp_path, sweep):
    """The device under the file system fails (its store is full: "Buffer I/O error", ext4 aborts its
    journal): the run ends with exit 1 and a message naming the file system, never a crash. After the disk is
    repaired, resume continues in place or, when the failed writes damaged the file, ``--into`` a new file
    with the complete steps carried over; the completed run has the key figures of an uninterrupted one."""
    campaign, model, expected = sweep
    # about 6 MB stored per step: the 24 MB store fills after three or four steps (ext4's own metadata takes some)
    with failing_disk(tmp_path, size_mb=256, backing_mb=24) as disk:
        out = disk.mnt / "run.h5"
        result = run_labctl("run", campaign, "--sim", "--model", model, "-o", out)
        err = result.stderr
        assert result.returncode == 1, err
        assert "Traceback" not in err and "Fatal Python error" not in err
        assert f"on the file system mounted at {disk.mnt}" in err, err
        assert "Input/output error" in err or "No space left on device" in err, err
        assert f"labctl resume {out}" in err, err

        disk.repair()
        info = run_labctl("info", out)
        assert info.returncode in (0, 2) and "Traceback" not in info.stderr, info.stderr
        resumed, target = run_labctl("resume", out), out
        if resumed.returncode == 2 and "--into NEW.h5" in resumed.stderr:
            assert "complete step(s) can be recovered (00000_offset_calibration .." in resumed.stderr, resumed.stderr
            target = disk.mnt / "into.h5"
            resumed = run_labctl("resume", out, "--into", target)
        assert resumed.returncode == 0, resumed.stderr
        with h5py.File(target, "r") as f:
            assert f.attrs["status"] == "complete"
        assert figures(target, tmp_path / "resumed") == expected
