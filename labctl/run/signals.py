"""Ctrl-C, SIGTERM and SIGHUP during a run: a stop request honoured at the next safe point,
and a safe-state sequence that no further signal can cut short.

What each signal does (docs/bringup.md, "Long campaigns"):

* SIGINT (Ctrl-C) once, SIGTERM (``kill``, ``systemctl stop``) and SIGHUP (the terminal
  closed, e.g. a dropped SSH session): the run stops at the next frame or device
  operation, or at once while an operator prompt waits;
* SIGINT a second time: at once (KeyboardInterrupt);
* once the run is stopping, every further signal is only recorded: the safe-state
  sequence and marking the run file aborted always run to their end.
"""

from __future__ import annotations

import signal
import threading
from collections.abc import Callable, Iterator
from contextlib import AbstractContextManager, contextmanager
from typing import Any

from labctl.errors import Interrupted

STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)
"""The signals that stop a run cleanly (SIGKILL cannot be caught: ``resume`` redoes the unfinished step)."""

REASONS = {
    signal.SIGINT: "interrupted by the operator (Ctrl-C)",
    signal.SIGTERM: "terminated by SIGTERM",
    signal.SIGHUP: "terminated by SIGHUP (the terminal closed)",
}
"""The reason recorded in the run file and printed, per signal."""


def main_thread() -> bool:
    """Whether this is the main thread, the only one that may set signal handlers (Python's signal module)."""
    return threading.current_thread() is threading.main_thread()


class StopRequests:
    """Stop signals become a stop request that the runner honours at the next safe point.

    A KeyboardInterrupt raised at an arbitrary bytecode can land in a finalizer
    or callback, where Python ignores it; a flag checked between frames and
    device operations cannot be lost. A second Ctrl-C interrupts at once, and
    so does any stop signal while an operator prompt waits (:meth:`at_once`).
    Once a stop has been raised, or :meth:`hold` was called, signals are only
    recorded, so nothing interrupts the safe-state sequence that follows.
    """

    def __init__(self) -> None:
        self.reason: str | None = None
        self._waiting = False
        self._holding = False
        self._handling = False
        self._requested: str | None = None

    def _handle(self, signum: int, frame: Any) -> None:
        first = self.reason is None
        if first:
            self.reason = self._requested or REASONS.get(signum, f"stopped by signal {signum}")
        if self._holding:
            return
        if signum == signal.SIGINT and not first:
            self._holding = True
            raise KeyboardInterrupt
        if self._waiting:
            self._holding = True
            raise Interrupted(self.reason)

    def hold(self) -> None:
        """From now on a signal is only recorded: the safe-state sequence and the run file's status run to their end."""
        self._holding = True

    @contextmanager
    def at_once(self) -> Iterator[None]:
        """While a person is asked (a prompt waits for Enter), a stop request interrupts at once."""
        self.check()
        self._waiting = True
        try:
            yield
        finally:
            self._waiting = False

    def check(self) -> None:
        """Raise Interrupted if a stop was requested."""
        if self.reason is not None:
            self._holding = True
            raise Interrupted(self.reason)

    def request(self, reason: str) -> None:
        """A stop asked for from any thread (the live console's Stop): exactly a Ctrl-C, SIGINT sent to the
        main thread, recorded with ``reason``; a second request stops at once like a second Ctrl-C. Where the
        handlers are not installed (a run outside the main thread) the stop waits for the next safe point."""
        self._requested = self._requested or reason
        if self._handling:
            signal.pthread_kill(threading.main_thread().ident or 0, signal.SIGINT)
        elif self.reason is None:
            self.reason = reason

    @contextmanager
    def installed(self) -> Iterator[None]:
        """The handlers, in the main thread; a run in another thread (a Dask worker's task, labctl batch)
        leaves the signals to the process that owns that thread (Python delivers them to the main thread)."""
        with _handling_stop_signals(self._handle):
            self._handling = main_thread()
            try:
                yield
            finally:
                self._handling = False


def signals_ignored() -> AbstractContextManager[None]:
    """Ignore every stop signal (in the main thread) while devices are made safe; restore the handlers after."""
    return _handling_stop_signals(signal.SIG_IGN)


@contextmanager
def _handling_stop_signals(handler: Callable[[int, Any], None] | signal.Handlers) -> Iterator[None]:
    """``handler`` for every stop signal while the block runs, the previous handlers restored after; in any
    thread but the main one (which alone may set handlers) nothing changes."""
    if not main_thread():
        yield
        return
    previous = {sig: signal.signal(sig, handler) for sig in STOP_SIGNALS}
    try:
        yield
    finally:
        for sig, restored in previous.items():
            signal.signal(sig, restored)
