"""Simulation-based calibration of reconcile: does it recover what the library itself hides?

``python -m bench.reconcile_sbc [DRAWS] [--pairs N] [--seed S] [--only LABEL ...] [--campaigns test|examples]
[--scheduler ADDRESS] [--workers N] [--record FILE]``
draws, for every library effect of the reconcile tests (the cases of
tests/reconcile/test_reconcile_cli.py and tests/reconcile/test_library_effects.py,
each on its camera at the test size), DRAWS parameter sets at random within
the test ranges, and N random pairs of two effects of one camera; hides each in
a simulated run of the reconcile test campaign (tests/reconcile/runs.py, a
random seed; with ``--campaigns examples``, of one of its camera's example
campaigns, examples/*.toml, drawn at random, 10 frames a stack) and reconciles it from the camera's built-in model with the fixed
thresholds, one Dask task per run (Talts et al. 2018, simulation-based
calibration: a method that recovers what it is given names the right effects,
and its 95 % intervals cover the truth about 95 % of the time). Prints per
draw the outcome, then a table per effect and for the pairs: the share named
right and nothing else (target >= 90 %; a hidden effect the run cannot show, one
reconcile states not tested, is right unnamed, and those draws are counted; so are the draws reconcile calls
``ambiguous`` between a hidden effect and a competitor, which name nothing), the share of the stated 95 %
intervals covering the true parameter (target 85-99 %; the scalar parameters
of the effects named right; a drift's amplitude at the run's first frame is
not the hidden one and is left out), and the share whose gap after the named
effects (before any empirical correction) is within the floor (target
>= 90 %), then per fitted parameter the standardized errors (estimate - truth) /
standard error: mean 0 and deviation 1 when the intervals are calibrated, a
mean away from 0 for a bias, a deviation above 1 for intervals too narrow.
``--only`` runs part of the plan (some effects, or the pairs) with the very
draws and seeds the whole plan gives them. Not a budget benchmark.
"""

from __future__ import annotations

import argparse
import functools
import json
import math
import sys
import tempfile
import time
import tomllib
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import tomli_w

from labctl.batch.cluster import Cluster, open_client
from labctl.reconcile.observe import MAX_FRAMES
from labctl.reconcile.workflow import reconcile
from sim.effects import EFFECTS
from sim.profiles import get_profile
from tests.reconcile.runs import BACKENDS, simulated_run
from tests.reconcile.test_reconcile_cli import CASES

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
Draw = Callable[[np.random.Generator], dict[str, Any]]
#: the newer library effects at the test's value (tests/reconcile/test_library_effects.py), drawn around it
NEWER: dict[str, tuple[str, str, Draw]] = {
    "log_amplitude_error-blaze101": ("blaze101", "log_amplitude_error", lambda r: {
        "per_decade_mm": -float(r.uniform(1.5, 4.5)), "per_decade_squared_mm": float(r.uniform(1.0, 3.0))}),
    "diffuse_floor_multipath-blaze101": ("blaze101", "diffuse_floor_multipath", lambda r: {
        "plane": "floor", "distance_mm": float(r.uniform(250, 450)), "albedo": float(r.uniform(0.3, 0.7))}),
    "stereo_calibration_drift-d455": ("d455", "stereo_calibration_drift", lambda r: {
        "disparity_offset_px": float(r.choice([-1.0, 1.0]) * r.uniform(0.04, 0.12))}),
    "disparity_bias-d455": ("d455", "disparity_bias", lambda r: {
        "amplitude_px": float(r.uniform(0.03, 0.06)), "period_px": float(r.uniform(1.5, 2.5)),
        "phase_rad": float(r.uniform(-3, 3))}),
}
DRAWS: dict[str, tuple[str, str, Draw]] = {**CASES, **NEWER}
NOT_COMPARED = {"temperature_drift": {"delta_mm"}}  # fitted at the run's first frame, hidden at the run's start
#: parameters known modulo a period, by camera: a phase modulo a turn, a multipath's extra path modulo the ambiguity
#: interval c / (2 f_mod)
PERIODIC: dict[str, Callable[[str], float]] = {
    "phase_rad": lambda _: 2 * math.pi,
    "extra_path_mm": lambda camera: 299792458e3 / (2e6 * get_profile(camera).modulation_mhz)}


@functools.cache
def example_campaigns(camera: str) -> list[str]:
    """The example campaigns (examples/*.toml) of ``camera``'s backend, by file name."""
    return sorted(path.name for path in EXAMPLES.glob("*.toml")
                  if tomllib.loads(path.read_text())["devices"]["camera"]["backend"] == BACKENDS[camera])


def example_campaign(name: str, seed: int) -> str:
    """An example campaign's text with the reconcile's frames per stack (``MAX_FRAMES``: it reads no more) and the
    draw's simulation seed."""
    campaign = tomllib.loads((EXAMPLES / name).read_text())
    for procedure in campaign["procedure"]:
        procedure["frames"] = MAX_FRAMES
    campaign["sim"] = {**campaign.get("sim", {}), "seed": seed}
    return tomli_w.dumps(campaign)


def one_draw(label: str, camera: str, hidden: dict[str, dict[str, Any]], seed: int,
             campaign: str | None = None) -> dict[str, Any]:
    """Simulate and reconcile one draw (a Dask task) on the test campaign or the example ``campaign``: what was
    named, fitted and covered, the verdict and gaps; a draw whose simulation or reconcile raises is an outcome too
    (verdict ``failed``, the error named), so that one failing draw neither stops the others nor drops out of the
    rates."""
    start = time.monotonic()
    try:
        with tempfile.TemporaryDirectory(prefix="labctl-sbc-") as tmp:
            text = example_campaign(campaign, seed) if campaign else None
            result = reconcile(simulated_run(Path(tmp), camera, hidden, seed=seed, campaign=text))
    except Exception as exc:  # noqa: BLE001 - any failure of a draw is reported with it, not raised
        return {"label": label, "seed": seed, "campaign": campaign, "hidden": sorted(hidden), "named": [],
                "verdict": "failed", "error": f"{type(exc).__name__}: {exc}", "parameters": hidden, "covered": [],
                "errors": [], "not_tested": [], "ambiguous": [], "within_floor": False,
                "seconds": time.monotonic() - start}
    named = {e.name: e for e in result.named}
    covered: list[bool] = []
    errors: list[tuple[str, float]] = []  # (effect.parameter, (estimate - truth) / standard error)
    for name, truth in hidden.items():
        effect = named.get(name)
        intervals = effect.evidence.determination.interval_95 if effect is not None and effect.evidence else None
        for key, value in truth.items():
            if not isinstance(value, float) or key in NOT_COMPARED.get(name, set()) or not intervals \
                    or key not in intervals:
                continue
            lo, hi = intervals[key]
            if key in PERIODIC:  # the truth's turn (or ambiguity interval) inside or above the interval
                value = lo + (value - lo) % PERIODIC[key](camera)
            covered.append(lo <= value <= hi)
            estimate, stderr = effect.parameters[key], effect.evidence.stderr.get(key, 0.0)
            if isinstance(estimate, float) and stderr > 0:
                if key in PERIODIC:  # the error to the nearest turn or ambiguity interval
                    estimate = value + math.remainder(estimate - value, PERIODIC[key](camera))
                errors.append((f"{name}.{key}", (estimate - value) / stderr))
    after = result.goodness_physical or result.goodness_after  # the named effects', before any empirical correction
    return {"label": label, "seed": seed, "campaign": campaign, "hidden": sorted(hidden), "parameters": hidden,
            "named": sorted(named),
            "verdict": result.verdict, "covered": covered, "errors": errors,
            "not_tested": sorted(set(hidden) & set(result.not_tested)),
            "ambiguous": sorted(result.ambiguity.between) if result.ambiguity is not None else [],
            "within_floor": bool(after is not None and result.rule.consistent(after)),
            "seconds": time.monotonic() - start}


#: one draw: its label (effect-camera, or pairs), the camera, the hidden effects' parameters, the run's seed and
#: its example campaign (None: the test campaign)
Task = tuple[str, str, dict[str, dict[str, Any]], int, str | None]


def plan(draws: int, pairs: int, seed: int, examples: bool = False) -> list[Task]:
    """The draws: ``draws`` per effect and ``pairs`` random pairs of two effects one camera can show; with
    ``examples``, each on one of its camera's example campaigns drawn at random (by a generator of its own, so
    that the parameters and seeds are those of the test campaign's plan)."""
    tasks = _plan(draws, pairs, seed)
    if not examples:
        return [(*task, None) for task in tasks]
    choose = np.random.default_rng([seed, 1])
    return [(*task, str(choose.choice(example_campaigns(task[1])))) for task in tasks]


def _plan(draws: int, pairs: int, seed: int) -> list[tuple[str, str, dict[str, dict[str, Any]], int]]:
    rng = np.random.default_rng(seed)
    tasks = []
    for label, (camera, effect, draw) in sorted(DRAWS.items()):
        for _ in range(draws):
            tasks.append((label, camera, {effect: draw(rng)}, int(rng.integers(1000, 100000))))
    keys = sorted(DRAWS)
    for _ in range(pairs):
        first = DRAWS[keys[int(rng.integers(len(keys)))]]
        camera, effect, draw = first
        technology = get_profile(camera).technology
        others = [k for k in keys if DRAWS[k][1] != effect and technology in EFFECTS[DRAWS[k][1]].technologies]
        other = DRAWS[others[int(rng.integers(len(others)))]]
        tasks.append(("pairs", camera, {effect: draw(rng), other[1]: other[2](rng)}, int(rng.integers(1000, 100000))))
    return tasks


def _share(hits: int, n: int) -> str:
    return f"{hits}/{n} ({hits / n:.0%})" if n else "-"


def named_right(o: dict[str, Any]) -> bool:
    """The draw's hidden effects named and nothing else; a hidden effect the run cannot show (it changes no
    compared bin, or the run lacks the steps that show it) is right unnamed when reconcile states it not tested."""
    return o["named"] == sorted(set(o["hidden"]) - set(o.get("not_tested", [])))


def ambiguous_with_hidden(o: dict[str, Any]) -> bool:
    """The draw's verdict ``ambiguous`` between candidates one of which is a hidden effect: what reconcile answers
    where the run cannot tell that effect from a competitor (``labctl plan`` states such pairs of a campaign)."""
    return o["verdict"] == "ambiguous" and bool(set(o.get("ambiguous", [])) & set(o["hidden"]))


def table(outcomes: list[dict[str, Any]]) -> str:
    """Per effect (and the pairs): named right and nothing else, interval coverage, gap after within the floor,
    the draws with a hidden effect stated not tested and those ``ambiguous`` with a hidden effect among the
    candidates it could not tell apart."""
    lines = ["| hidden | draws | named right, nothing else | 95 % intervals covering | gap after within floor "
             "| a hidden effect stated not tested | ambiguous, a hidden effect among the candidates | failed |",
             "|---|---|---|---|---|---|---|---|"]
    for label in sorted({o["label"] for o in outcomes}):
        rows = [o for o in outcomes if o["label"] == label]
        right = sum(named_right(o) for o in rows)
        covered = [c for o in rows for c in o["covered"]]
        within = sum(o["within_floor"] for o in rows)
        untested = sum(bool(o.get("not_tested")) for o in rows)
        ambiguous = sum(ambiguous_with_hidden(o) for o in rows)
        failed = sum(o["verdict"] == "failed" for o in rows)
        lines.append(f"| {label} | {len(rows)} | {_share(right, len(rows))} | {_share(sum(covered), len(covered))} "
                     f"| {_share(within, len(rows))} | {untested} | {ambiguous} | {failed} |")
    return "\n".join(lines)


def error_table(outcomes: list[dict[str, Any]]) -> str:
    """Per fitted parameter: the standardized errors (estimate - truth) / standard error. A calibrated fit gives
    mean 0 and standard deviation 1; a mean away from 0 is a bias, a deviation above 1 too narrow an interval."""
    errors: dict[str, list[float]] = {}
    for o in outcomes:
        for key, z in o["errors"]:
            errors.setdefault(key, []).append(z)
    lines = ["| parameter | fits | mean z | sd z | largest abs z |", "|---|---|---|---|---|"]
    for key, zs in sorted(errors.items()):
        z = np.array(zs)
        lines.append(f"| {key} | {len(z)} | {z.mean():.2f} | {z.std(ddof=1) if len(z) > 1 else math.nan:.2f} "
                     f"| {np.abs(z).max():.1f} |")
    return "\n".join(lines)


def interleaved(tasks: list[Task]) -> list[Task]:
    """The plan's tasks in the order they are run: the first draw of every label (effect, or the pairs), then the
    second of each, ..., so that a look stopped early has about as many draws of every label."""
    rank: dict[str, int] = {}
    ranked = []
    for task in tasks:
        rank[task[0]] = rank.get(task[0], -1) + 1
        ranked.append((rank[task[0]], task))
    return [task for _, task in sorted(ranked, key=lambda rt: rt[0])]  # stable: the labels in the plan's order


def _line(o: dict[str, Any]) -> str:
    where = f"{o['label']} seed {o['seed']}" + (f" on {o['campaign']}" if o.get("campaign") else "")
    if o["verdict"] == "failed":
        return f"{where}: FAILED {o['error']} (hidden {o['parameters']})"
    return (f"{where}: verdict {o['verdict']}, named {o['named'] or 'nothing'} "
            f"(hidden {o['hidden']}{', not tested ' + str(o['not_tested']) if o.get('not_tested') else ''}), "
            f"intervals covering {sum(o['covered'])}/{len(o['covered'])}, "
            f"gap after {'within' if o['within_floor'] else 'above'} the floor, {o['seconds']:.0f} s")


def main(draws: int, pairs: int, seed: int, cluster: Cluster, only: list[str] | None = None,
         record: Path | None = None, examples: bool = False) -> int:
    tasks = interleaved([t for t in plan(draws, pairs, seed, examples) if not only or t[0] in only])
    start = time.monotonic()
    outcomes = []
    with open_client(cluster) as client:
        from distributed import as_completed

        workers = len(client.scheduler_info()["workers"])
        futures = [client.submit(one_draw, *task, pure=False) for task in tasks]
        for future in as_completed(futures):
            o = future.result()
            outcomes.append(o)
            print(_line(o), flush=True)
            if record is not None:
                with record.open("a") as f:
                    f.write(json.dumps(o) + "\n")
    print(table(outcomes), error_table(outcomes), sep="\n\n")  # two Markdown tables: a blank line between
    print(f"{len(outcomes)} draws on {workers} workers in {time.monotonic() - start:.0f} s (seed {seed})")
    return 0


def tables_of(record: Path) -> int:
    """The tables of the outcomes a look (``--record``) has written so far, finished or not."""
    outcomes = [json.loads(line) for line in record.read_text().splitlines() if line.strip()]
    print(table(outcomes), error_table(outcomes), sep="\n\n")
    print(f"{len(outcomes)} draws recorded in {record}")
    return 0


if __name__ == "__main__":
    parser = argparse.ArgumentParser(prog="python -m bench.reconcile_sbc", description=__doc__.split("\n\n")[0])
    parser.add_argument("draws", nargs="?", type=int, default=40, help="draws per effect (default 40)")
    parser.add_argument("--pairs", type=int, default=40, help="draws of two effects together (default 40)")
    parser.add_argument("--seed", type=int, default=1, help="seed of the draws (default 1)")
    parser.add_argument("--only", nargs="+", choices=[*sorted(DRAWS), "pairs"], metavar="LABEL",
                        help="run only these labels of the plan (effect-camera, or pairs), drawn as in the whole plan")
    parser.add_argument("--scheduler", help="address of an existing Dask scheduler (default: a local cluster)")
    parser.add_argument("--workers", type=int, help="worker processes of the local cluster (default: one per core)")
    parser.add_argument("--campaigns", choices=["test", "examples"], default="test",
                        help="the reconcile test campaign (default), or for each draw one of its camera's example "
                             "campaigns (examples/*.toml) at random, at the test size")
    parser.add_argument("--record", type=Path, help="append each draw's outcome to this file (JSON lines)")
    parser.add_argument("--tables-of", type=Path, metavar="RECORD",
                        help="print the tables of a record (finished or not) and exit")
    args = parser.parse_args()
    if args.tables_of is not None:
        sys.exit(tables_of(args.tables_of))
    sys.exit(main(args.draws, args.pairs, args.seed, Cluster(args.scheduler, args.workers), args.only, args.record,
                  args.campaigns == "examples"))
