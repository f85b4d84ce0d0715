"""A console for the length of one run: the state, the answers pipe and the server, printed URL included."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass

from labctl.console.server import LOCALHOST, ConsoleServer
from labctl.console.state import ConsoleState
from labctl.run.operator import RemoteAnswers


@dataclass(frozen=True)
class Console:
    """What a run needs to be watched and answered from the console (``run_campaign(observer=, remote=)``)."""

    state: ConsoleState
    remote: RemoteAnswers
    server: ConsoleServer


@contextmanager
def open_console(host: str = LOCALHOST, port: int = 0, announce: Callable[[str], None] = print) -> Iterator[Console]:
    """Serve a console on ``host``:``port`` and ``announce`` its URL (with the token off 127.0.0.1) while the
    block runs; the server, the encoder and the pipe are closed after it. InputError when the port is taken."""
    remote = RemoteAnswers()
    state = ConsoleState(remote)
    try:
        server = ConsoleServer(state, host, port)
    except BaseException:
        state.close()
        remote.close()
        raise
    announce(f"console: {server.url}")
    try:
        yield Console(state, remote, server)
    finally:
        server.close()
        state.close()
        remote.close()
