"""Check the minimum detectable effect: 1.5x the stated amplitude of an effect is named in at least 9 of 10 seeds.

``python -m bench.reconcile_power [SEEDS] [--effect NAME ...] [--factor F]``
reconciles a null run of the reconcile test campaign
(tests/reconcile/forward.py ``CAMPAIGN``, blaze-101 at 160 x 120) with the
default 19 null replicas, reads the stated minimum detectable amplitude of
each ``--effect`` (default ``wiggling``; ``all``: every effect it states one
for) and the parameters of its median grid point, then hides ``--factor``
(default 1.5) times that amplitude, in a
direction drawn per seed (a random phase where the effect has one, else a
random sign: the figure averages over them), in SEEDS (default 10) simulated
runs of the same campaign (seeds 201, 202, ...) and reconciles each against
the same null replicas (they depend only on the campaign and the model).
Prints per seed whether the effect was named, and per effect the count against
the 90 % the figure promises. Not a budget benchmark.
"""

from __future__ import annotations

import argparse
import math
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from labctl.reconcile.false_positives import DEFAULT_NULL_RUNS
from labctl.reconcile.workflow import reconcile
from sim.effects import EFFECTS, valid_range
from tests.reconcile.runs import simulated_run


def direction(effect: str, at: dict[str, Any], parameter: str, amplitude: float, seed: int) -> dict[str, Any]:
    """The hidden ``effect``'s parameters: ``amplitude`` with a sign where its parameter may take both, and a phase
    where it has one, drawn from ``seed`` (the minimum detectable amplitude is the average over them,
    labctl/reconcile/power.py)."""
    rng = np.random.default_rng(seed)
    params = {**at, parameter: amplitude}
    if "phase_rad" in params:
        params["phase_rad"] = float(rng.uniform(-math.pi, math.pi))
    elif valid_range(EFFECTS[effect].params, parameter)[0] < 0:  # a parameter bounded at 0 has one direction
        params[parameter] = float(rng.choice([-1.0, 1.0])) * amplitude
    return params


def main(seeds: int, effects: list[str], factor: float) -> int:
    with tempfile.TemporaryDirectory(prefix="labctl-power-") as tmp:
        start = time.monotonic()
        null_run = simulated_run(Path(tmp) / "null", "blaze101", {}, seed=200)
        base = reconcile(null_run, null_runs=DEFAULT_NULL_RUNS)
        stated = {name: d for name, d in (base.minimum_detectable or {}).items() if d.amplitude is not None}
        print(f"null run: verdict {base.verdict}; replicas {base.rule.seconds:.0f} s", flush=True)
        missing = [name for name in effects if name != "all" and name not in stated]
        if missing:
            print(f"no minimum detectable amplitude stated for {', '.join(missing)}")
            return 1
        summary = []
        for effect in sorted(stated) if "all" in effects else effects:
            detail = stated[effect]
            print(f"{effect}: {detail.parameter} {detail.amplitude} at {detail.at} "
                  f"(grid {detail.grid_min} ... {detail.grid_max})", flush=True)
            named = 0
            for seed in range(201, 201 + seeds):
                hidden = {effect: direction(effect, detail.at, detail.parameter, factor * detail.amplitude, seed)}
                run = simulated_run(Path(tmp) / f"{effect}-{seed}", "blaze101", hidden, seed=seed)
                result = reconcile(run, null=base.rule)
                hit = effect in [e.name for e in result.named]
                named += hit
                between = f" between {' and '.join(result.ambiguity.between)}" if result.ambiguity else ""
                print(f"  seed {seed}: {hidden[effect]}: verdict {result.verdict}{between}, named "
                      f"{[e.name for e in result.named] or 'nothing'}{' (hit)' if hit else ''}", flush=True)
                run.unlink()
            summary.append(f"{effect} at {factor:g} x its minimum detectable {detail.parameter} "
                           f"({factor * detail.amplitude:.4g}): named in {named} of {seeds} seeds")
            print(summary[-1], flush=True)
        print(f"the figure promises 90 % at 1x; {time.monotonic() - start:.0f} s", *summary, sep="\n")
    return 0


if __name__ == "__main__":
    parser = argparse.ArgumentParser(prog="python -m bench.reconcile_power", description=__doc__.split("\n\n")[0])
    parser.add_argument("seeds", nargs="?", type=int, default=10, help="seeds with the effect hidden (default 10)")
    parser.add_argument("--effect", nargs="+", default=["wiggling"],
                        help="the library effects to hide, one after the other (default wiggling; all: every effect "
                             "with a stated minimum detectable amplitude)")
    parser.add_argument("--factor", type=float, default=1.5, help="times its minimum detectable amplitude")
    args = parser.parse_args()
    sys.exit(main(args.seeds, args.effect, args.factor))
