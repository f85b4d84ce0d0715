"""kill -9 at 50 instants of a small simulated run: every file opens with `labctl info`, and `resume` completes
it with the key figures of the uninterrupted run.

Half the instants are random times after the run file exists, drawn over the time the uninterrupted run takes from
then; the other half land on a random write of the run (strace injects SIGKILL at the N-th pwrite64, N drawn over
all of a run's writes, which strace counts on a run of its own), so many fall in the middle of a flush: some of a
flush's metadata on disk, the rest not (without strace on the machine, every instant is a random time). A file that
`resume` finds damaged (a flush cut short) is continued with `resume --into NEW.h5`, as its message says; where the
cut flush was adding a step to the list of steps, that list cannot be read and the committed steps are carried over
through the step index. The runs are children forked from a fork server with labctl imported (no interpreter
start-up per instant), two at a time; info and resume then run in this process, and each resumed file is compared
with the uninterrupted run step by step, bit for bit, and by its key figures for the first five and every file
continued with --into. No committed step is lost: every step the run reported complete on stderr before the kill is
among the steps that `resume` (in place or --into) carries over. With strace, the run is also killed at each of its
last writes (the last step's commit and the status change to complete). ``CRASH_POINTS_SEED`` draws another set of
instants (default 21).
"""

from __future__ import annotations

import multiprocessing
import os
import random
import re
import shutil
import signal
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from datetime import UTC, datetime
from multiprocessing import forkserver
from pathlib import Path

import h5py
import numpy as np
import pytest

from labctl.cli import main
from labctl.evaluation.evaluate import evaluate_runs
from labctl.evaluation.keyfigures import clean

INSTANTS = 50
LAST_WRITES = 9  # with strace, a kill at each of the last 9 of them too (the last commit and status flushes)


def invoke(capsys, *args) -> tuple[int, str, str]:
    with pytest.raises(SystemExit) as info:
        main([str(a) for a in args])
    captured = capsys.readouterr()
    return info.value.code, captured.out, captured.err


def figures(run: Path) -> dict:
    """The key figures `labctl evaluate` writes to keyfigures.json (without drawing its report)."""
    return {name: clean(f.value) for name, f in evaluate_runs([run]).figures.items()}


def _run_in_child(args: list[str], stop_first: bool, log: Path) -> None:
    """The child: ``labctl run`` (its imports already loaded in the fork server: no interpreter start-up per
    instant), its progress messages line by line into ``log``."""
    sys.stderr = open(log, "w", buffering=1)  # noqa: SIM115 (the child's stderr until it is killed)
    if stop_first:  # wait, stopped, for strace to attach
        os.kill(os.getpid(), signal.SIGSTOP)
    main(args)


#: what ``labctl run --sim --model`` imports when it starts (labctl/cli/app.py, ``run``): the command line loads a
#: command's work only when the command runs
RUN_COMMAND_MODULES = ["labctl.run.campaign", "labctl.run.config", "labctl.run.lab", "labctl.run.progress",
                       "labctl.run.store", "sim.model"]


#: the runs are forked from a fork server, a fresh process with labctl imported: never from this process, whose
#: earlier tests may have started numba's OpenMP threads (a fork is then refused: "fork() called from a process
#: already using GNU OpenMP", and the child exits 1)
RUNS = multiprocessing.get_context("forkserver")


@pytest.fixture(scope="module")
def labctl_fork_server() -> None:
    """The fork server with labctl imported. A process has one fork server, which keeps the modules of whoever
    started it: one started by an earlier test of this process (the UR emulator's, sim/emulators/ur/process.py)
    is stopped first, or every run would import labctl itself (3 s of CPU time each)."""
    forkserver._forkserver._stop()  # the module's own stop, for its tests; nothing where none runs
    RUNS.set_forkserver_preload(["labctl.cli", *RUN_COMMAND_MODULES, __name__])


def start_run(campaign: Path, model: Path, out: Path, stop_first: bool = False) -> multiprocessing.Process:
    args = ["run", str(campaign), "--sim", "--model", str(model), "-o", str(out)]
    child = RUNS.Process(target=_run_in_child, args=(args, stop_first, log(out)))
    child.start()
    return child


def log(out: Path) -> Path:
    return out.with_suffix(".log")


def reported_complete(out: Path) -> set[str]:
    """The steps the run reported complete (after their commit returned) before it was killed."""
    return set(re.findall(r"^(\d{5}_\w+) complete", log(out).read_text(), re.MULTILINE))


def appeared(child: multiprocessing.Process, out: Path) -> float:
    """The moment the run's file appears under its name (polled every millisecond)."""
    deadline = time.monotonic() + 120
    while not out.exists() and child.is_alive():
        assert time.monotonic() < deadline, "the run file did not appear"
        time.sleep(0.001)
    return time.monotonic()


def kill_after(child: multiprocessing.Process, out: Path, delay_s: float) -> str:
    """SIGKILL the run ``delay_s`` after its file appears under its name."""
    appeared(child, out)
    time.sleep(delay_s)  # the instant itself is what is drawn at random; nothing waits on it
    child.kill()
    child.join(timeout=120)
    return f"kill -9 {delay_s:.3f} s after the file appeared"


def traced(child: multiprocessing.Process, *options: str) -> str:
    """Attach strace (tracing pwrite64, with ``options``) to the stopped run, let it go on until it ends; strace's
    output on stderr."""
    while open(f"/proc/{child.pid}/stat").read().split(")")[1].split()[0] != "T":
        time.sleep(0.001)
    strace = subprocess.Popen(["strace", "-p", str(child.pid), "-e", "trace=pwrite64", *options],
                              stderr=subprocess.PIPE, text=True)
    assert "attached" in strace.stderr.readline()
    os.kill(child.pid, signal.SIGCONT)
    child.join(timeout=300)
    return strace.communicate(timeout=60)[1]


def kill_at_write(child: multiprocessing.Process, n: int) -> str:
    """strace delivers SIGKILL to the stopped run at the entry of its n-th pwrite64."""
    traced(child, "-o", "/dev/null", "-e", f"inject=pwrite64:signal=SIGKILL:when={n}")
    return f"kill -9 at pwrite64 #{n}"


def count_writes(child: multiprocessing.Process) -> int:
    """The pwrite64 calls of the stopped run until it ends, counted by ``strace -c`` as ``kill_at_write`` counts."""
    summary = traced(child, "-c")
    return int(next(line.split()[3] for line in summary.splitlines() if line.endswith("pwrite64")))


def assert_same_steps(run: Path, reference: Path, instant: str) -> None:
    """The same steps with the same data and attributes, bit for bit, all but the conditions of the moment: the
    wall-clock times and the camera's temperatures (a resumed session restarts the camera, which warms up again).
    The key figures, a function of the rest, are then identical too."""
    with h5py.File(run, "r") as f, h5py.File(reference, "r") as g:
        assert f.attrs["status"] == "complete", instant
        assert sorted(f["steps"]) == sorted(g["steps"]), instant
        for step_id, step in g["steps"].items():
            mine = f["steps"][step_id]
            for name, dataset in step.items():
                assert np.array_equal(mine[name][()], dataset[()], equal_nan=True), f"{instant}: {step_id}/{name}"
            times = ("started", "finished", "camera_temperatures_json")
            assert ({k: str(v) for k, v in mine.attrs.items() if k not in times}
                    == {k: str(v) for k, v in step.attrs.items() if k not in times}), f"{instant}: {step_id}"


@pytest.mark.slow
def test_kill_9_at_50_instants_every_file_opens_and_resumes_to_the_same_figures(
    tmp_path, write_campaign, small_model, capsys, labctl_fork_server
):
    campaign, model = write_campaign(), small_model()
    reference = tmp_path / "reference.h5"
    child = start_run(campaign, model, reference)
    started = appeared(child, reference)
    child.join(timeout=300)
    assert child.exitcode == 0
    run_s = time.monotonic() - started  # the instants are drawn over the run's life after its file appears

    rng = random.Random(int(os.environ.get("CRASH_POINTS_SEED", "21")))
    targeted = shutil.which("strace") is not None
    # the run's writes, targets are drawn up to them
    writes = count_writes(start_run(campaign, model, tmp_path / "counted.h5", stop_first=True)) if targeted else 0
    instants = []
    for i in range(INSTANTS):
        out = tmp_path / f"killed{i:02d}.h5"
        if targeted and i % 2:
            instants.append((out, rng.randint(1, writes), None))
        else:
            instants.append((out, None, rng.uniform(0, run_s)))
    if targeted:  # and each write of the last flushes: the last step's commit, the status change to complete
        instants += [(tmp_path / f"last{n}.h5", n, None) for n in range(writes - LAST_WRITES + 1, writes + 1)]

    def kill(instant: tuple[Path, int | None, float | None]) -> tuple[Path, str, datetime]:
        out, write, delay = instant
        if write is not None:
            what = kill_at_write(start_run(campaign, model, out, stop_first=True), write)
        else:
            what = kill_after(start_run(campaign, model, out), out, delay)
        return out, what, datetime.now(UTC)  # the run is dead: every step it finished, it finished before this

    # two runs at a time
    with ThreadPoolExecutor(2) as pool:
        plans = list(pool.map(kill, instants))
    expected = figures(reference)
    assert expected["z_precision_q90_mm"] is not None

    into, index_lost, checked_figures, cut, lost = 0, 0, 0, 0, {}
    for out, instant, killed in plans:
        if not out.exists():  # killed while it was created under a temporary name: the path holds nothing
            continue
        code, stdout, err = invoke(capsys, "info", out)
        assert code == 0 and "Traceback" not in err, f"{instant}: labctl info {out}: {err}"
        index_lost += "its list of steps cannot be read" in stdout
        cut += "status complete" not in stdout.partition("\n")[0]  # killed before the run ended
        code, _, err = invoke(capsys, "resume", out, "--quiet")
        target = out
        if code == 2 and "--into NEW.h5" in err:  # damaged by a flush cut short: continue in a new file
            into += 1
            target = out.with_name(f"{out.stem}-into.h5")
            code, _, err = invoke(capsys, "resume", out, "--into", target, "--quiet")
        assert code == 0, f"{instant}: labctl resume {out}: {err}"
        assert_same_steps(target, reference, instant)
        with h5py.File(target, "r") as f:  # a step run again after the kill finished after it
            rerun = {s for s in reported_complete(out) if datetime.fromisoformat(f["steps"][s].attrs["finished"]) > killed}
        if rerun:
            lost[instant] = sorted(rerun)
        if target != out or checked_figures < 5:  # the key figures themselves for the first and every --into run
            checked_figures += 1
            assert figures(target) == expected, instant
    files = sum(1 for out, _, _ in plans if out.exists())
    print(f"{len(instants)} instants, {files} files, {cut} cut short, {into} continued --into ({index_lost} with the "
          f"list of steps lost), {len(lost)} losing committed steps")
    assert not lost, f"committed steps lost: {lost}"

