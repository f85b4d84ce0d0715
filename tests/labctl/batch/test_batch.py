"""labctl batch on a Dask LocalCluster of 2 worker processes (given by --scheduler, and started by the command
itself): the same outputs as the serial commands, a corrupt run reported while the others complete; sweep files
expanded into their grid; run arguments expanded; cluster options checked."""

from __future__ import annotations

import json
import os
import queue
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import h5py
import numpy as np
import psutil
import pytest

from labctl.batch.calibration import null_calibration
from labctl.batch.inputs import expand_runs, run_names
from labctl.batch.sweep import load_sweep
from labctl.cli import main
from labctl.errors import InputError
from tests.conftest import REALTIME_GROUP

pytestmark = pytest.mark.xdist_group(REALTIME_GROUP)  # a local Dask cluster takes both cores: never beside a realtime test

SEEDS = [11, 12, 13, 14, 15, 16]
#: four steps of 5 frames: the offset position and a wall at 1, 2 and 3 m (reconcile needs two comparable steps)
PROCEDURES = """
[[procedure]]
kind = "offset_calibration"
frames = 5

[[procedure]]
kind = "depth_sweep"
start_mm = 1000
stop_mm = 3000
step_mm = 1000
frames = 5
"""


def _labctl(*args: str) -> int:
    """The command line in this process (as the user runs it, without a subprocess's start-up)."""
    with pytest.raises(SystemExit) as info:
        main([str(a) for a in args])
    return int(info.value.code)


def _without(doc: dict, *keys: str) -> dict:
    return {k: v for k, v in doc.items() if k not in keys}


@pytest.fixture(scope="module")
def serial(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Six runs made by ``labctl run --sim`` one after the other (48 x 36 blaze-101, seeds 11-16) in ``runs/``,
    with their campaign and model."""
    from tests.conftest import SMALL_MODEL, campaign_text

    base = tmp_path_factory.mktemp("batch")
    (base / "campaign.toml").write_text(campaign_text(procedures=PROCEDURES))
    (base / "model.toml").write_text(SMALL_MODEL.format(camera="blaze101", width=48, height=36))
    (base / "runs").mkdir()
    for seed in SEEDS:
        assert _labctl("run", base / "campaign.toml", "--sim", "--model", base / "model.toml", "--seed", seed,
                       "-o", base / "runs" / f"unit{seed}.h5", "--quiet") == 0
    return base


def test_batch_equals_the_serial_commands_and_a_corrupt_run_is_reported(serial: Path) -> None:
    runs = serial / "runs"
    data = (runs / "unit11.h5").read_bytes()
    (runs / "corrupt.h5").write_bytes(data[: len(data) // 3])  # a copy cut short
    from distributed import LocalCluster

    from labctl.batch.cluster import WORKER_ENVIRONMENT

    try:  # an existing cluster, as --scheduler finds one: a LocalCluster of 2 worker processes
        with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=":0",
                          env=WORKER_ENVIRONMENT) as cluster:
            assert _labctl("batch", "runs", runs, "-o", serial / "batch", "--reconcile", "--scheduler",
                           cluster.scheduler_address, "--quiet") == 1  # a run failed: exit 1, the others complete
    finally:
        (runs / "corrupt.h5").unlink()
    index = json.loads((serial / "batch" / "index.json").read_text())
    assert index["counts"] == {"runs": 7, "ok": 6, "failed": 1}
    failed = [r for r in index["runs"] if r["status"] == "failed"]
    assert [r["name"] for r in failed] == ["corrupt"]
    assert "corrupt.h5" in failed[0]["error"] and "Traceback" not in failed[0]["error"]
    done = [r for r in index["runs"] if r["status"] == "ok"]
    assert len(done) == 6
    for summary in done:
        out, mine = serial / "serial" / summary["name"], Path(summary["output"])
        assert _labctl("evaluate", summary["run"], "-o", out / "evaluation", "--quiet", "--no-pdf") == 0
        expected = json.loads((out / "evaluation" / "keyfigures.json").read_text())
        assert json.loads((mine / "evaluation" / "keyfigures.json").read_text()) == expected
        assert summary["evaluate"]["figures"] == {n: f["value"] for n, f in expected["figures"].items()}
        assert _labctl("reconcile", summary["run"], "-o", out / "reconcile", "--null-runs", "0", "--quiet") == 0
        expected = json.loads((out / "reconcile" / "reconcile.json").read_text())
        got = json.loads((mine / "reconcile" / "reconcile.json").read_text())
        assert _without(got, "model_toml") == _without(expected, "model_toml")
        assert (mine / "reconcile" / "model.toml").read_text() == (out / "reconcile" / "model.toml").read_text()
        assert summary["reconcile"]["verdict"] == expected["verdict"]
    rows = (serial / "batch" / "index.csv").read_text().splitlines()
    assert len(rows) == 8 and rows[0].startswith("name,run,status,error")
    assert "Key figures across the runs" in (serial / "batch" / "batch.html").read_text()


def test_sweep_points_are_the_runs_labctl_run_makes(serial: Path) -> None:
    (serial / "sweep.toml").write_text('[sweep]\ncampaign = "campaign.toml"\nmodel = "model.toml"\n'
                                       f"[grid]\nseed = {SEEDS[:2]}\n")
    out = serial / "sweep"
    assert _labctl("batch", "sweep", serial / "sweep.toml", "-o", out, "--workers", 2, "--quiet") == 0
    index = json.loads((out / "index.json").read_text())
    assert index["counts"] == {"runs": 2, "ok": 2, "failed": 0}
    for k, summary in enumerate(index["runs"]):
        assert summary["parameters"] == {"seed": SEEDS[k]} and summary["null"]  # nothing beyond the model
        with h5py.File(serial / "runs" / f"unit{SEEDS[k]}.h5") as a, h5py.File(summary["run"]) as b:
            assert sorted(a["steps"]) == sorted(b["steps"])
            for step in a["steps"]:
                for channel in ("z", "intensity"):
                    np.testing.assert_array_equal(a["steps"][step][channel][()], b["steps"][step][channel][()])
        figures = json.loads((Path(summary["output"]) / "evaluation" / "keyfigures.json").read_text())["figures"]
        assert summary["evaluate"]["figures"] == {n: f["value"] for n, f in figures.items()}
    html = (out / "batch.html").read_text()
    assert "Figures over the grid" in html and "z_accuracy_q90_mm mean" in html


def test_run_arguments_expand_to_files(tmp_path: Path) -> None:
    (tmp_path / "lot1").mkdir()
    (tmp_path / "lot2").mkdir()
    for path in ("lot1/a.h5", "lot1/b.hdf5", "lot2/a.h5", "lot2/notes.txt"):
        (tmp_path / path).write_bytes(b"\x89HDF\r\n\x1a\n")  # the HDF5 signature: what a run file starts with
    found = expand_runs([str(tmp_path), str(tmp_path / "lot1" / "*.h5"), str(tmp_path / "lot2" / "a.h5")])
    assert found == sorted((tmp_path / p).resolve() for p in ("lot1/a.h5", "lot1/b.hdf5", "lot2/a.h5"))
    assert run_names(found) == ["lot1__a", "lot1__b", "lot2__a"]
    (tmp_path / "empty.h5").write_bytes(b"")
    for bad, message in (("missing.h5", "does not exist"), ("*.nothing", "matches no file"),
                         ("lot2/notes.txt/..", "holds no run file"),
                         ("empty.h5", r"empty.h5 is empty \(0 bytes\), not a labctl run file")):
        with pytest.raises(InputError, match=message):
            expand_runs([str(tmp_path / bad)] if bad != "lot2/notes.txt/.." else [str(_empty_dir(tmp_path))])


def _empty_dir(tmp_path: Path) -> Path:
    (tmp_path / "empty").mkdir(exist_ok=True)
    return tmp_path / "empty"


def test_sweep_grid_is_every_combination(tmp_path: Path) -> None:
    from tests.conftest import campaign_text

    (tmp_path / "campaign.toml").write_text(campaign_text())
    (tmp_path / "sweep.toml").write_text("""
[sweep]
campaign = "campaign.toml"
reconcile = true
[grid]
seed = {start = 5, count = 3}
"camera,model.camera_overrides.width" = [["blaze101", 48], ["d455", 64]]
"model.effects.range_scale.scale" = [0.0, 0.01]
"campaign.procedure.1.step_mm" = [1000]
""")
    sweep = load_sweep(tmp_path / "sweep.toml")
    assert len(sweep.points) == 3 * 2 * 2 * 1
    point = next(p for p in sweep.points if p.parameters == {
        "seed": 6, "camera": "d455", "model.camera_overrides.width": 64, "model.effects.range_scale.scale": 0.01,
        "campaign.procedure.1.step_mm": 1000})
    assert point.seed == 6
    assert 'backend = "realsense"' in point.campaign_toml and "step_mm = 1000" in point.campaign_toml
    assert "width = 64" in point.model_toml and "scale = 0.01" in point.model_toml
    assert not point.null and point.reconcile_model_toml is None  # against the built-in model


@pytest.mark.parametrize(("sweep", "message"), [
    ('[sweep]\ncampaign = "campaign.toml"\n[grid]\nexposure = [1]\n', "grid axis 'exposure'"),
    ('[sweep]\ncampaign = "campaign.toml"\n[grid]\n"camera,seed" = [["d455"]]\n', "move together"),
    ('[sweep]\ncampaign = "campaign.toml"\ncolour = 1\n', "unknown key"),
    ('[sweep]\ncampaign = "nowhere.toml"\n', "nowhere.toml does not exist"),
    ('[sweep]\ncampaign = "campaign.toml"\n[grid]\n"model.effects.no_such_effect.size" = [2.0]\n', "p0000"),
])
def test_bad_sweep_files_are_named(tmp_path: Path, sweep: str, message: str) -> None:
    from tests.conftest import campaign_text

    (tmp_path / "campaign.toml").write_text(campaign_text())
    (tmp_path / "sweep.toml").write_text(sweep)
    with pytest.raises(InputError, match=message):
        load_sweep(tmp_path / "sweep.toml")


def test_null_calibration_counts_named_effects_and_unexplained() -> None:
    def run(verdict: str, named: list[str], camera: str, null: bool = True) -> dict:
        return {"null": null, "parameters": {"camera": camera}, "reconcile": {
            "verdict": verdict, "named": named, "best_candidate_dbic": 3.0, "worst_step_ratio": 1.5}}

    summaries = [run("none", [], "d455")] * 7 + [run("effect_found", ["wiggling"], "d455"),
                                                 run("unexplained", [], "amt100"),
                                                 run("effect_found", ["wiggling"], "amt100", null=False)]
    rates = null_calibration(summaries)
    assert rates is not None and rates.overall.runs == 9
    assert (rates.overall.false_positive, rates.overall.false_unexplained) == (1, 1)
    assert rates.overall.false_positive_rate == pytest.approx(1 / 9)
    assert rates.by_camera["amt100"].runs == 1 and rates.overall.named == {"wiggling": 1}


def test_cluster_options_are_checked(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from labctl.batch import cluster

    run = tmp_path / "unit.h5"
    run.write_bytes(b"\x89HDF\r\n\x1a\n")  # taken for a run file: the options are what is refused
    assert _labctl("batch", "runs", run, "-o", tmp_path / "a", "--scheduler", "tcp://127.0.0.1:1",
                   "--workers", 2) == 2
    monkeypatch.setattr(cluster, "CONNECT_TIMEOUT_S", 1.0)
    with pytest.raises(Exception, match="cannot reach the Dask scheduler at tcp://127.0.0.1:1"):
        with cluster.open_client(cluster.Cluster("tcp://127.0.0.1:1")):
            pass


def _workers(pid: int) -> list[psutil.Process]:
    """The local cluster's worker processes of the command ``pid`` (multiprocessing's spawned children; its
    resource tracker is not one)."""
    try:
        children = psutil.Process(pid).children(recursive=True)
    except psutil.NoSuchProcess:
        return []
    workers = []
    for child in children:
        try:
            if any("spawn_main" in arg for arg in child.cmdline()):
                workers.append(child)
        except psutil.Error:  # gone meanwhile
            pass
    return workers


def _reads_a_run(workers: list[psutil.Process]) -> bool:
    for worker in workers:
        try:
            if any(f.path.endswith(".h5") for f in worker.open_files()):
                return True
        except psutil.Error:
            pass
    return False


def _default_sigint() -> None:
    signal.signal(signal.SIGINT, signal.SIG_DFL)


#: the moment of the Ctrl-C: (what the command is doing, whether it has happened yet, given the stderr lines so
#: far and the command's pid)
PHASES = {
    "the cluster starts": lambda lines, pid: bool(_workers(pid)) and not lines,
    "the tasks are submitted": lambda lines, pid: any(" runs on 1 Dask worker(s) at " in line for line in lines),
    "a task runs": lambda lines, pid: _reads_a_run(_workers(pid)) and not any(" done in " in line for line in lines),
    "results are gathered": lambda lines, pid: any(line.startswith(f"1/{len(SEEDS)} ") for line in lines),
}


@pytest.mark.parametrize("attempt", [1, 2])
@pytest.mark.parametrize("phase", list(PHASES))
def test_ctrl_c_cancels_the_pending_runs_and_stops_the_cluster(serial: Path, tmp_path: Path, phase: str,
                                                                attempt: int) -> None:
    """Ctrl-C at the terminal (SIGINT to the command's whole process group, the cluster's worker processes
    included) while the cluster starts, as the tasks are submitted, while the first runs and once it is done:
    exit 130 with one line and no traceback, the runs still pending never evaluated, and no process of the
    group left behind. The moment is an event seen from outside (a worker process started, a line on stderr,
    a worker reading a run file), each phase twice."""
    out = tmp_path / "interrupted"
    root = Path(__file__).resolve().parents[3]
    proc = subprocess.Popen([sys.executable, "-m", "labctl", "batch", "runs", str(serial / "runs"), "-o", str(out),
                             "--workers", "1"], cwd=root, start_new_session=True,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            preexec_fn=_default_sigint)  # pytest started in the background ignores SIGINT,
    # and so would the command: a terminal's Ctrl-C reaches a foreground command, which has its default handler
    lines: queue.SimpleQueue[str] = queue.SimpleQueue()
    reader = threading.Thread(target=lambda: [lines.put(line.rstrip("\n")) for line in proc.stderr], daemon=True)
    reader.start()
    before: list[str] = []
    try:
        deadline = time.monotonic() + 300
        while not PHASES[phase](before, proc.pid):
            assert proc.poll() is None, f"the batch ended before {phase}: {before}"
            assert time.monotonic() < deadline, f"not seen within 300 s: {phase}"
            try:
                before.append(lines.get(timeout=0.05))
            except queue.Empty:
                pass
        os.killpg(proc.pid, signal.SIGINT)
        stdout = proc.stdout.read()
        proc.wait(timeout=120)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    reader.join(timeout=30)
    after = []
    while not lines.empty():
        after.append(lines.get())
    stderr = "\n".join(before + ["--- SIGINT ---"] + after)
    assert proc.returncode == 130, stderr
    # after the Ctrl-C: a run that finished meanwhile may still be counted, then the one line
    assert [line for line in after if line.strip() and " done in " not in line] == ["labctl: aborted"], stderr
    assert stdout == ""
    assert len(list(out.glob("runs/*/evaluation/keyfigures.json"))) < len(SEEDS)
    deadline = time.monotonic() + 30
    while True:  # the cluster's processes end with the command
        try:
            os.killpg(proc.pid, 0)
        except ProcessLookupError:
            break
        assert time.monotonic() < deadline, "processes of the batch's group are still running"
        time.sleep(0.5)
