"""Reconcile budgets (docs/benchmarks.md): a full campaign reconciles in under 15 s on the idle machine; its null
replicas run
on the machine's cores at least 1.3x as fast as one after the other.

The measured run is the blaze-101's complete campaign (examples/blaze101.toml:
offset calibration, 0.4-4 m depth sweep, slanted edge with its white sheets,
checkerboard, both Boehler stars, five material plates at 17 robot angles, the
face mask) simulated at full resolution with a hidden ``wiggling`` effect and
``/sim`` removed. The reconcile reads at most 10 frames of a stack, so the
stacks are simulated with 10 frames. The floor is just reading those frames'
z and intensity arrays from the file (the fixed thresholds: ``--null-runs 0``).

The null calibration: the reconcile test campaign (tests/reconcile/forward.py
``CAMPAIGN``: offset calibration, 0.4-4 m sweep in 200 mm steps, PTFE and
silicone plates on the robot, 10 frames, blaze-101 at 160 x 120, nothing
hidden) reconciled with the default 19 null replicas on a local Dask cluster of
one worker per core, against the same with one worker (serial).

The null replicas of the complete campaign (``reconcile_replica``): what each of
a reconcile's K null replicas of the measured run costs on average (simulated
from the reconcile's model as the run's campaign, observed as it is made,
compared), on one core as a cluster's worker runs them, within 20 s; the floor
is the same reading as above.
"""

from __future__ import annotations

import tomllib
from pathlib import Path

import h5py
import tomli_w

from bench.common import Result, best_of, scratch_dir
from labctl.batch.cluster import machine_workers
from labctl.blas import one_blas_thread
from labctl.cli import main as labctl_main
from labctl.kernel_threads import serial_kernels
from labctl.reconcile.false_positives import DEFAULT_NULL_RUNS
from labctl.reconcile.null import null_replica, replica_model, seeds_for
from labctl.reconcile.observe import MAX_FRAMES, observe_run
from labctl.reconcile.workflow import base_model, first_round, reconcile
from sim.effects import default_effects
from sim.profiles import get_profile
from sim.shared_renders import forget as forget_renders
from tests.reconcile.runs import simulated_run

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
BUDGET_S = 15.0
#: one null replica of the complete campaign on one core
REPLICA_BUDGET_S = 20.0
#: the null replicas on the cluster at least as much faster than serially as the batch budget asks of its runs
SPEED_UP = 1.3
HIDDEN = {"wiggling": {"amplitude_mm": 3.0, "period_mm": 1500.0, "phase_rad": 0.5}}


def _make_run(directory: Path) -> Path:
    campaign = tomllib.loads((EXAMPLES / "blaze101.toml").read_text())
    for procedure in campaign["procedure"]:
        procedure["frames"] = MAX_FRAMES
    model = {"camera": "blaze101", "effects": {**default_effects(get_profile("blaze101")), **HIDDEN}}
    (directory / "campaign.toml").write_text(tomli_w.dumps(campaign))
    (directory / "model.toml").write_text(tomli_w.dumps(model))
    run = directory / "measured.h5"
    try:
        labctl_main(["run", str(directory / "campaign.toml"), "--sim", "--model", str(directory / "model.toml"),
                     "-o", str(run), "--quiet"])
    except SystemExit as exc:
        if exc.code != 0:
            raise RuntimeError(f"simulating the measured campaign failed (exit {exc.code})") from None
    with h5py.File(run, "a") as f:
        del f["sim"]
    return run


def _read(run: Path) -> None:
    with h5py.File(run, "r") as f:
        for step in f["steps"].values():
            step["z"][:MAX_FRAMES]
            step["intensity"][:MAX_FRAMES]


def run_null() -> Result:
    """The test campaign with its null replicas: on one worker per core against one worker."""
    workers = machine_workers()
    with scratch_dir() as tmp:
        measured = simulated_run(Path(tmp), "blaze101")  # the test campaign, nothing hidden, /sim removed
        reconcile(measured)  # warm: the compiled kernels of this process
        outcome = {}
        for n in (1, workers):
            def once(n: int = n) -> None:
                outcome[n] = reconcile(measured, null_runs=DEFAULT_NULL_RUNS, workers=n)
            outcome[f"s{n}"] = best_of(1, once)
    serial, parallel = outcome["s1"], outcome[f"s{workers}"]
    result = outcome[workers]
    found = (result.minimum_detectable or {}).get("wiggling")
    wiggling = found.amplitude if found is not None else None
    replicas = result.rule.seconds
    return Result("reconcile_null", f"{parallel:.1f} s with {DEFAULT_NULL_RUNS} null replicas on {workers} workers "
                  f"({replicas:.1f} s of it the replicas; verdict {result.verdict}, minimum detectable wiggling "
                  f"{wiggling} mm)", f"serial {serial:.1f} s ({outcome[1].rule.seconds:.1f} s the replicas)",
                  serial / parallel, f">= {SPEED_UP}x faster than serial", serial / parallel >= SPEED_UP)


def run() -> list[Result]:
    with scratch_dir() as tmp:
        measured = _make_run(Path(tmp))
        floor = best_of(1, lambda: _read(measured))
        rows = [_full(measured, floor), _replica(measured, floor, Path(tmp))]
    return [*rows, run_null()]


def _full(measured: Path, floor: float) -> Result:
    """The complete campaign reconciled with the fixed thresholds."""
    outcome = {}

    def reconcile_once() -> None:
        outcome["result"] = reconcile(measured)

    seconds = best_of(1, reconcile_once)
    result = outcome["result"]
    named = ", ".join(f"{e.name} {e.parameters}" for e in result.named) or "nothing"
    steps = len(result.observations)
    return Result("reconcile", f"{seconds:.1f} s for {steps} steps (verdict {result.verdict}, named {named}; gap "
                  f"{result.gap_before:.2f} -> {result.gap_after:.2f} mm, floor "
                  f"{result.goodness_after.gap_floor_mm:.2f} mm)", f"reading {floor:.1f} s",
                  seconds / BUDGET_S, f"< {BUDGET_S:.0f} s", seconds < BUDGET_S)


@one_blas_thread
def _replica(measured: Path, floor: float, directory: Path) -> Result:
    """Null replicas of the complete campaign on one thread, as a worker of the replicas' cluster makes them
    (labctl/batch/cluster.py: one thread, numba on one): the first, then a second, which takes the first's
    noise-free step maps (sim/shared_renders.py). A worker's K-th replica costs the second's time, so the mean
    over a reconcile's default K replicas on one worker is (first + (K - 1) second) / K."""
    observations, info, _ = observe_run(measured)
    model_text = replica_model(base_model(info), info)
    step_ids = [o.scene.step_id for o in observations]
    try:
        with serial_kernels():
            first, second = (null_replica(info["campaign_toml"], model_text, seed, step_ids, info, str(directory),
                                          first_round) for seed in seeds_for(info["campaign_toml"], 2))
    finally:
        forget_renders()
    k = DEFAULT_NULL_RUNS
    mean = (first.seconds + (k - 1) * second.seconds) / k
    return Result("reconcile_replica", f"{mean:.1f} s per null replica of the {len(step_ids)} compared steps on one "
                  f"core, over {k} replicas (the first {first.seconds:.1f} s, each further one {second.seconds:.1f} s)",
                  f"reading {floor:.1f} s", mean / REPLICA_BUDGET_S, f"<= {REPLICA_BUDGET_S:.0f} s",
                  mean <= REPLICA_BUDGET_S)
