"""The controller emulator in a process of its own.

ur-rtde's Python bindings keep the interpreter lock while they wait for the controller
(the ``RTDEReceiveInterface`` constructor waits for the first data package), so an
emulator served by threads of the same interpreter would never answer. Tests therefore
run :class:`~sim.emulators.ur.server.URControllerEmulator` in a child process and reach
its :class:`~sim.emulators.ur.controller.URController` through :meth:`URControllerProcess.call`.
"""

from __future__ import annotations

import multiprocessing
import os
import signal
from multiprocessing.connection import Connection
from types import TracebackType
from typing import Any


def _serve(pipe: Connection, q: list[float], options: dict[str, Any]) -> None:
    from sim.emulators.ur.server import URControllerEmulator

    with URControllerEmulator(q, **options) as emulator:
        pipe.send(emulator.host)
        while True:
            request = pipe.recv()
            if request is None:
                return
            name, args = request
            try:
                with emulator.robot.lock:
                    member = getattr(emulator.robot, name)
                    result = member(*args) if callable(member) else member
                pipe.send((True, result))
            except Exception as exc:  # handed to the caller
                pipe.send((False, exc))


class URControllerProcess:
    """A :class:`~sim.emulators.ur.server.URControllerEmulator` (same arguments) in a child
    process. ``host`` is its loopback address; :meth:`call` runs a method of its controller
    (or reads an attribute) and returns the result. Use as a context manager."""

    def __init__(self, q: list[float], *, start_timeout_s: float = 20.0, **options: Any) -> None:
        context = multiprocessing.get_context("forkserver")  # forks of a clean, single-threaded server
        context.set_forkserver_preload(["sim.emulators.ur.server"])
        self._pipe, child = context.Pipe()
        self._process = context.Process(target=_serve, args=(child, list(q), options), daemon=True, name="ur-emulator")
        self._process.start()
        child.close()
        if not self._pipe.poll(start_timeout_s):
            self.close()
            raise TimeoutError(f"the UR controller emulator did not start within {start_timeout_s} s")
        self.host: str = self._pipe.recv()

    def call(self, name: str, *args: Any, timeout_s: float = 10.0) -> Any:
        """``robot.name(*args)`` in the emulator (or the attribute ``robot.name``)."""
        self._pipe.send((name, args))
        if not self._pipe.poll(timeout_s):
            raise TimeoutError(f"the UR controller emulator did not answer {name!r} within {timeout_s} s")
        ok, result = self._pipe.recv()
        if not ok:
            raise result
        return result

    def go_silent(self) -> None:
        """Freeze the emulator's process (SIGSTOP): its connections stay open but carry nothing more, as over a
        pulled network cable, where no FIN or RST reaches the clients. :meth:`close` ends it."""
        os.kill(self._process.pid, signal.SIGSTOP)

    def close(self) -> None:
        """Stop the emulator (its servers and threads) and the process."""
        if self._process.is_alive():
            os.kill(self._process.pid, signal.SIGCONT)  # frozen by go_silent
            try:
                self._pipe.send(None)
            except OSError:
                pass
            self._process.join(timeout=5.0)
        if self._process.is_alive():
            self._process.kill()
            self._process.join(timeout=5.0)
        self._pipe.close()

    def __enter__(self) -> URControllerProcess:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()
