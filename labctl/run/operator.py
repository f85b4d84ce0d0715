"""Operator prompts (target swaps, recovery after a protective stop)."""

from __future__ import annotations

import os
import select
import signal
import sys
from collections.abc import Callable

from labctl.run.observer import RunObserver


class RemoteAnswers:
    """Answers from outside the terminal (the live console in a browser): a pipe that :func:`read_answer`
    watches beside the terminal, so whichever answers first is taken."""

    def __init__(self) -> None:
        self._read, self._write = os.pipe()
        os.set_blocking(self._read, False)
        os.set_blocking(self._write, False)

    def fileno(self) -> int:
        """The descriptor that becomes readable when an answer was posted."""
        return self._read

    def post(self, answer: str) -> None:
        """Hand one answer (a line) to the waiting prompt; dropped if the pipe is full (nobody is reading)."""
        try:
            os.write(self._write, answer.replace("\n", " ").encode() + b"\n")
        except BlockingIOError:
            pass

    def take(self) -> str | None:
        """The first posted answer, or None; every answer posted with it is discarded (one answer per prompt)."""
        try:
            data = os.read(self._read, 65536)
        except BlockingIOError:
            return None
        return data.decode(errors="replace").split("\n", 1)[0].strip()

    def discard(self) -> None:
        """Drop answers posted for a prompt that is already answered."""
        while self.take() is not None:
            pass

    def close(self) -> None:
        """Close both ends of the pipe."""
        os.close(self._read)
        os.close(self._write)


def read_answer(prompt: str, remote: RemoteAnswers | None = None, idle: Callable[[], None] | None = None,
                idle_s: float = 0.2) -> str:
    """Print ``prompt`` and wait for one line from the terminal, or an answer from ``remote``, whichever
    comes first; ``idle`` is called about every ``idle_s`` seconds while nothing arrives (the live preview).
    Without a terminal on stdin only ``remote`` is watched.

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
        stdin = sys.stdin.fileno() if sys.stdin.isatty() else None
        watched = [fd for fd in (stdin, wake_r, remote.fileno() if remote else None) if fd is not None]
        while True:
            ready, _, _ = select.select(watched, [], [], idle_s if idle is not None else None)
            if wake_r in ready:
                os.read(wake_r, 512)  # a signal arrived: its handler runs before the next statement
                continue
            if remote is not None and remote.fileno() in ready:
                answer = remote.take()
                if answer is not None:
                    sys.stdout.write(f"{answer} (answered in the console)\n")
                    sys.stdout.flush()
                    return answer
                continue
            if stdin is None or stdin not in ready:
                if idle is not None:
                    idle()
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
    still reported so a dry run shows where a person will be needed. ``remote``
    answers (the live console) are taken as well as the terminal's, and
    ``observer`` is told of every prompt that waits and of its answer.
    """

    def __init__(self, automatic: bool, report: Callable[[str], None], remote: RemoteAnswers | None = None,
                 observer: RunObserver | None = None) -> None:
        self.automatic = automatic
        self.report = report
        self.remote = remote
        self.observer = observer or RunObserver()

    def _can_ask(self) -> bool:
        return sys.stdin.isatty() or self.remote is not None

    def _publish(self, question: str, options: list[str]) -> None:
        """Tell the observer of the prompt, after dropping remote answers left from an earlier one."""
        if self.remote is not None:
            self.remote.discard()
        self.observer.prompt(question, options)

    def confirm(self, message: str) -> None:
        """Wait until the operator confirms ``message`` (a simulated operator confirms at once)."""
        if self.automatic:
            self.report(f"operator (simulated): {message} -- done")
            return
        if not self._can_ask():
            raise RuntimeError(f"operator action needed but no terminal to ask: {message}")
        self.report(f"OPERATOR: {message}")
        self._publish(message, ["done"])
        try:
            read_answer("Press Enter when done (Ctrl-C aborts safely) ", self.remote)
        finally:
            self.observer.prompt_closed()

    def choose(self, question: str, options: list[str], idle: Callable[[], None] | None = None) -> str:
        """Ask the operator to pick one of ``options`` (a simulated operator takes the first); ``idle`` runs
        between polls while the question waits."""
        if self.automatic:
            self.report(f"operator (simulated): {question} -- {options[0]}")
            return options[0]
        if not self._can_ask():
            raise RuntimeError(f"operator decision needed but no terminal to ask: {question}")
        menu = ", ".join(f"{i + 1} = {o}" for i, o in enumerate(options))
        self._publish(question, options)
        try:
            while True:
                answer = read_answer(f"OPERATOR: {question} [{menu}] ", self.remote, idle)
                if answer in {str(i + 1) for i in range(len(options))}:
                    return options[int(answer) - 1]
                if answer in options:
                    return answer
        finally:
            self.observer.prompt_closed()


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
