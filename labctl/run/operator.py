"""Operator prompts (target swaps, recovery after a protective stop)."""

from __future__ import annotations

import os
import select
import signal
import sys
from collections.abc import Callable


def read_answer(prompt: str) -> str:
    """Print ``prompt`` and wait for one line from the terminal.

    A signal (Ctrl-C) may be delivered to any thread of the process (device
    libraries start their own), and then a plain ``input()`` in the main thread
    keeps waiting and the handler runs only after the next Enter. Here the
    wait also watches the signal wake-up descriptor, so the handler runs at once
    and can stop the wait by raising.
    """
    sys.stdout.write(prompt)
    sys.stdout.flush()
    wake_r, wake_w = os.pipe()
    os.set_blocking(wake_w, False)
    previous = signal.set_wakeup_fd(wake_w, warn_on_full_buffer=False)
    try:
        stdin = sys.stdin.fileno()
        while True:
            ready, _, _ = select.select([stdin, wake_r], [], [])
            if wake_r in ready:
                os.read(wake_r, 512)  # a signal arrived: its handler runs before the next statement
                continue
            line = os.read(stdin, 4096)
            if not line:
                raise RuntimeError(f"the terminal closed while waiting for the operator: {prompt.strip()}")
            return line.decode(errors="replace").strip()
    except BaseException:
        sys.stdout.write("\n")  # the message that follows starts on its own line, not after the prompt
        sys.stdout.flush()
        raise
    finally:
        signal.set_wakeup_fd(previous)
        os.close(wake_r)
        os.close(wake_w)


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
        read_answer("Press Enter when done (Ctrl-C aborts safely) ")

    def choose(self, question: str, options: list[str]) -> str:
        """Ask the operator to pick one of ``options`` (a simulated operator takes the first)."""
        if self.automatic:
            self.report(f"operator (simulated): {question} -- {options[0]}")
            return options[0]
        if not sys.stdin.isatty():
            raise RuntimeError(f"operator decision needed but no terminal to ask: {question}")
        menu = ", ".join(f"{i + 1} = {o}" for i, o in enumerate(options))
        while True:
            answer = read_answer(f"OPERATOR: {question} [{menu}] ")
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
