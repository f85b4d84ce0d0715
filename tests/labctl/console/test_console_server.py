"""The console's server without a browser: the token off 127.0.0.1, the POST header, a port already taken."""

from __future__ import annotations

import json
import socket
import urllib.error
import urllib.request
from collections.abc import Iterator

import pytest

from labctl.console.server import ConsoleServer
from labctl.console.state import ConsoleState
from labctl.errors import InputError
from labctl.run.operator import RemoteAnswers


@pytest.fixture
def state() -> Iterator[ConsoleState]:
    """A console state with no run behind it."""
    remote = RemoteAnswers()
    console = ConsoleState(remote)
    yield console
    console.close()
    remote.close()


def status_of(url: str, data: bytes | None = None, headers: dict[str, str] | None = None) -> int:
    """The HTTP status of a GET (or a POST of ``data``)."""
    try:
        with urllib.request.urlopen(urllib.request.Request(url, data=data, headers=headers or {}), timeout=30) as r:
            return r.status
    except urllib.error.HTTPError as exc:
        return exc.code


def test_another_address_than_localhost_needs_the_token(state: ConsoleState) -> None:
    server = ConsoleServer(state, host="127.0.0.2", port=0)  # not 127.0.0.1: served with a token
    try:
        assert server.token and server.url == f"http://127.0.0.2:{server.port}/?token={server.token}"
        base = f"http://127.0.0.2:{server.port}"
        assert status_of(f"{base}/") == 403
        assert status_of(f"{base}/state.json") == 403
        assert status_of(f"{base}/state.json?token=wrong") == 403
        assert status_of(f"{base}/stop", b"{}", {"X-Labctl": "1"}) == 403
        assert status_of(server.url) == 200
        with urllib.request.urlopen(f"{base}/state.json?token={server.token}", timeout=30) as response:
            assert json.load(response)["status"] == "starting"
    finally:
        server.close()


def test_localhost_needs_no_token_but_a_post_needs_the_header(state: ConsoleState) -> None:
    server = ConsoleServer(state)
    try:
        assert server.token is None and server.url == f"http://127.0.0.1:{server.port}/"
        assert status_of(server.url) == 200
        assert status_of(server.url + "stop", b"{}") == 403  # what a page of another site could send
        assert status_of(server.url + "stop", b"{}", {"X-Labctl": "1"}) == 409  # no run to stop
        assert status_of(server.url + "answer", b'{"prompt": 1, "answer": "done"}', {"X-Labctl": "1"}) == 409
    finally:
        server.close()


def test_a_port_in_use_is_named_in_a_clear_message(state: ConsoleState) -> None:
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        with pytest.raises(InputError, match=rf"--console-port {port}: .*127\.0\.0\.1:{port}, the port is already in use"):
            ConsoleServer(state, port=port)


def test_console_port_and_host_without_console_are_refused(tmp_path, write_campaign, capsys) -> None:
    from labctl.cli import main

    with pytest.raises(SystemExit) as done:
        main(["run", str(write_campaign()), "--sim", "--console-host", "0.0.0.0", "-o", str(tmp_path / "r.h5")])
    assert done.value.code == 2
    assert "--console-host and --console-port only apply with --console" in capsys.readouterr().err
    assert not (tmp_path / "r.h5").exists()
