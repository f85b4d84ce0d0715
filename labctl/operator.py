"""Operator prompts (target swaps, recovery after a protective stop)."""

from __future__ import annotations

import sys
from collections.abc import Callable


class Operator:
    """Asks a person to act and waits for confirmation on the terminal.

    ``automatic`` operators (simulated runs) confirm at once; every prompt is
    still reported so a dry run shows where a person will be needed.
    """

    def __init__(self, automatic: bool, report: Callable[[str], None]) -> None:
        self.automatic = automatic
        self.report = report

    def confirm(self, message: str) -> None:
        if self.automatic:
            self.report(f"operator (simulated): {message} -- done")
            return
        if not sys.stdin.isatty():
            raise RuntimeError(f"operator action needed but no terminal to ask: {message}")
        self.report(f"OPERATOR: {message}")
        input("Press Enter when done (Ctrl-C aborts safely) ")
