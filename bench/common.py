"""Shared helpers: timing, result lines, scratch directories."""

from __future__ import annotations

import os
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path


@dataclass(frozen=True)
class Result:
    name: str
    measured: str
    floor: str
    ratio: float
    budget: str
    ok: bool

    def line(self) -> str:
        verdict = "PASS" if self.ok else "FAIL"
        return f"{verdict}  {self.name}: {self.measured}; floor {self.floor}; ratio {self.ratio:.2f} (budget {self.budget})"


def best_of(repeats: int, action: Callable[[], object]) -> float:
    """Fastest wall time of ``repeats`` runs, seconds."""
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        action()
        times.append(time.perf_counter() - start)
    return min(times)


def scratch_dir() -> tempfile.TemporaryDirectory[str]:
    """A temporary directory on the disk the lab would record to (BENCH_DIR, default the system temp)."""
    base = os.environ.get("BENCH_DIR")
    if base:
        Path(base).mkdir(parents=True, exist_ok=True)
    return tempfile.TemporaryDirectory(prefix="labctl-bench-", dir=base)
