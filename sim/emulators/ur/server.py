"""An emulated UR e-Series controller on a loopback address: dashboard server (29999),
script ports (30002 secondary, 30003 real-time: URScript programs) and RTDE (30004).

ur-rtde connects to fixed port numbers, so each emulator takes a loopback address of its
own (``127.a.b.c``); parallel tests never compete for the ports.
"""

from __future__ import annotations

import contextlib
import random
import socket
import threading
from collections.abc import Callable
from types import TracebackType

from sim.emulators.ur import dashboard
from sim.emulators.ur.controller import URController
from sim.emulators.ur.rtde import InputClaims, RTDESession

DASHBOARD_PORT, SECONDARY_PORT, REALTIME_PORT, RTDE_PORT = 29999, 30002, 30003, 30004


class URControllerEmulator:
    """Servers of one emulated UR5e around a :class:`URController` (``robot``), keyword
    arguments as for :class:`URController`. ``max_rate_hz`` caps the RTDE output rate below
    the requested frequency (the controller also skips packages when busy). Use as a
    context manager; :meth:`close` ends every server, connection and thread.
    """

    def __init__(self, q: list[float], *, host: str | None = None, max_rate_hz: float = 125.0, **options: object) -> None:
        self.robot = URController(q, **options)  # type: ignore[arg-type]
        self.max_rate_hz = max_rate_hz
        self._claims = InputClaims()
        self._lock = threading.Lock()
        self._clients: list[socket.socket] = []
        self._threads: list[threading.Thread] = []
        self._listeners: list[socket.socket] = []
        self.host = self._bind(host)
        handlers: dict[int, Callable[[socket.socket], None]] = {
            DASHBOARD_PORT: self._dashboard, SECONDARY_PORT: self._script, REALTIME_PORT: self._script, RTDE_PORT: self._rtde,
        }
        for listener in self._listeners:
            self._spawn(self._accept, listener, handlers[listener.getsockname()[1]])

    def _bind(self, host: str | None) -> str:
        for _ in range(50):
            address = host or f"127.{random.randint(1, 254)}.{random.randint(1, 254)}.{random.randint(2, 254)}"
            try:
                for port in (DASHBOARD_PORT, SECONDARY_PORT, REALTIME_PORT, RTDE_PORT):
                    self._listeners.append(socket.create_server((address, port)))
                return address
            except OSError:
                for listener in self._listeners:
                    listener.close()
                self._listeners.clear()
                if host is not None:
                    raise
        raise OSError("no free loopback address for the UR controller emulator")

    def _spawn(self, target: Callable[..., None], *args: object) -> None:
        thread = threading.Thread(target=target, args=args, daemon=True, name=f"ur-{target.__name__}")
        self._threads.append(thread)
        thread.start()

    def _accept(self, listener: socket.socket, handler: Callable[[socket.socket], None]) -> None:
        while True:
            try:
                client, _ = listener.accept()
            except OSError:
                return
            client.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            with self._lock:
                self._clients.append(client)
            self._spawn(self._serve, handler, client)

    def _serve(self, handler: Callable[[socket.socket], None], client: socket.socket) -> None:
        with contextlib.suppress(OSError):
            handler(client)
        client.close()

    def _dashboard(self, client: socket.socket) -> None:
        client.sendall((dashboard.GREETING + "\n").encode())
        for raw in client.makefile("rb"):
            line = raw.decode("ascii", "replace").rstrip("\r\n")
            client.sendall((dashboard.reply(self.robot, line) + "\n").encode())
            if line.strip().lower() == "quit":
                return

    def _script(self, client: socket.socket) -> None:
        """URScript programs: ``def name():`` ... ``end`` at the start of a line; each complete
        program replaces the running one."""
        program: list[str] = []
        for raw in client.makefile("rb"):
            line = raw.decode("utf-8", "replace")
            if not program and not line.startswith(("def ", "sec ")):
                continue  # single script lines are not emulated
            program.append(line)
            if line.rstrip("\r\n") == "end":
                self.robot.run_script("".join(program))
                program = []

    def _rtde(self, client: socket.socket) -> None:
        RTDESession(client, self.robot, self._claims, self.max_rate_hz).serve()

    def close(self) -> None:
        """Close listeners and connections, stop the program and join every thread."""
        for listener in self._listeners:
            with contextlib.suppress(OSError):
                listener.shutdown(socket.SHUT_RDWR)  # wakes the thread blocked in accept()
            listener.close()
        with self._lock:
            clients = list(self._clients)
        for client in clients:
            with contextlib.suppress(OSError):
                client.shutdown(socket.SHUT_RDWR)
            client.close()
        self.robot.close()
        for thread in self._threads:
            thread.join(timeout=2.0)

    def __enter__(self) -> URControllerEmulator:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()
