"""Fault injection for simulated devices (docs/campaign.md, ``[sim.faults]``).

A rate is the probability that a fault kind strikes once during a step. When
it does, the schedule (drawn from the step's own random stream) picks which
opportunity fails: one of the first serial exchanges, one frame of the stack,
the robot's move. A retried operation is a new opportunity, so every fault
strikes at most once per step and the data never depend on it.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Mapping

from sim.seeding import stream

FAULT_KINDS = (
    "serial_timeout",
    "serial_garbage",
    "camera_disconnect",
    "dropped_frame",
    "robot_protective_stop",
)
_SERIAL_SLOTS = 2


class FaultInjector:
    """Decides, deterministically per (seed, step), which operations fail."""

    def __init__(self, rates: Mapping[str, float], seed: int) -> None:
        unknown = set(rates) - set(FAULT_KINDS)
        if unknown:
            raise KeyError(f"unknown fault kinds: {', '.join(sorted(unknown))}")
        self.rates = {kind: float(rates.get(kind, 0.0)) for kind in FAULT_KINDS}
        self.seed = seed
        self._schedule: dict[str, int] = {}
        self._counters: Counter[str] = Counter()

    def begin_step(self, step_index: int, frames: int) -> None:
        """Draw this step's schedule."""
        rng = stream(self.seed, step_index, "faults")
        slots = {
            "serial_timeout": _SERIAL_SLOTS,
            "serial_garbage": _SERIAL_SLOTS,
            "camera_disconnect": max(frames, 1),
            "dropped_frame": max(frames, 1),
            "robot_protective_stop": 1,
        }
        self._schedule = {}
        for kind in FAULT_KINDS:
            hit, slot = rng.random(), int(rng.integers(0, slots[kind]))
            if hit < self.rates[kind]:
                self._schedule[kind] = slot
        self._counters = Counter()

    def strike(self, kind: str) -> bool:
        """Register one opportunity of ``kind``; True if it must fail."""
        n = self._counters[kind]
        self._counters[kind] += 1
        return self._schedule.get(kind) == n
