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

    def choose(self, question: str, options: list[str]) -> str:
        """Ask the operator to pick one of ``options`` (a simulated operator takes the first)."""
        if self.automatic:
            self.report(f"operator (simulated): {question} -- {options[0]}")
            return options[0]
        if not sys.stdin.isatty():
            raise RuntimeError(f"operator decision needed but no terminal to ask: {question}")
        menu = ", ".join(f"{i + 1} = {o}" for i, o in enumerate(options))
        while True:
            answer = input(f"OPERATOR: {question} [{menu}] ").strip()
            if answer in {str(i + 1) for i in range(len(options))}:
                return options[int(answer) - 1]
            if answer in options:
                return answer


def unlock_confirmation(operator: Operator) -> Callable[[str], bool]:
    """A Grbl ``confirm_unlock`` callback: the operator decides whether an alarm may be
    unlocked (``$X``); a simulated operator and one without a terminal keep it locked."""

    def confirm(message: str) -> bool:
        try:
            return operator.choose(message, ["keep locked", "unlock"]) == "unlock"
        except RuntimeError as exc:  # no terminal to ask: the alarm stays, moves are refused
            operator.report(f"warning: {exc}; the stage stays locked")
            return False

    return confirm
