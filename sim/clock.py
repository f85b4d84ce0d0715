"""Virtual clock: a simulated dry run never sleeps through lab time."""

from __future__ import annotations


class VirtualClock:
    """A clock whose ``sleep`` only advances a counter (seconds)."""

    def __init__(self, start: float = 0.0) -> None:
        self._now = float(start)

    def now(self) -> float:
        return self._now

    def sleep(self, seconds: float) -> None:
        if seconds > 0:
            self._now += seconds

    def set(self, t: float) -> None:
        """Jump to lab time ``t`` (used to place a step at its planned start)."""
        self._now = float(t)
