"""Run the benchmarks: ``python -m bench [name ...]``; exit 1 if a budget is missed."""

from __future__ import annotations

import signal
import sys
from types import FrameType

from bench import batch, evaluation, reconcile, recording, sim_capture

BENCHMARKS = {"recording": recording.run, "evaluation": evaluation.run, "sim_capture": sim_capture.run,
              "reconcile": reconcile.run, "batch": batch.run}


def _exit_on_term(signum: int, _frame: FrameType | None) -> None:
    """SIGTERM (a timeout, a closed session) ends like Ctrl-C: the scratch directories (a full campaign is
    gigabytes) are removed on the way out."""
    raise SystemExit(128 + signum)


def main(names: list[str]) -> int:
    signal.signal(signal.SIGTERM, _exit_on_term)
    unknown = [n for n in names if n not in BENCHMARKS]
    if unknown:
        print(f"unknown benchmark(s) {', '.join(unknown)}; available: {', '.join(BENCHMARKS)}", file=sys.stderr)
        return 2
    results = []
    for name in names or BENCHMARKS:
        outcome = BENCHMARKS[name]()
        results.extend(outcome if isinstance(outcome, list) else [outcome])
    for result in results:
        print(result.line(), flush=True)
    return 0 if all(r.ok for r in results) else 1


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
