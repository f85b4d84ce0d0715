"""The console's web server: the page, the state as JSON, the latest frames as PNG, and the operator's
answers and Stop, on ``http.server``'s threading server (one thread per request, any number of browsers).

Served on 127.0.0.1 unless another address is given; then every request must carry the random token the
printed URL holds (``?token=``), else 403. Answers and Stop are POSTs with an ``X-Labctl`` header, which a
page of another site cannot send without the server's consent (the server never gives it)."""

from __future__ import annotations

import errno
import json
import secrets
import threading
from http import HTTPStatus
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from importlib import resources
from typing import Any
from urllib.parse import parse_qs, urlsplit

from labctl.console.state import ConsoleState
from labctl.errors import InputError

LOCALHOST = "127.0.0.1"
HEADER = "X-Labctl"
"""The header every POST must carry."""


class ConsoleServer:
    """Serves ``state`` on ``host``:``port`` (0: any free port) in a thread of its own until :meth:`close`."""

    def __init__(self, state: ConsoleState, host: str = LOCALHOST, port: int = 0) -> None:
        self.state = state
        self.host = host
        self.token = secrets.token_urlsafe(16) if host != LOCALHOST else None
        self.page = resources.files("labctl.console").joinpath("page.html").read_bytes()
        try:
            self.httpd = ThreadingHTTPServer((host, port), _handler(self))
        except OSError as exc:
            if exc.errno == errno.EADDRINUSE:
                raise InputError(f"--console-port {port}: cannot serve the console on {host}:{port}, the port is "
                                 "already in use; choose another one (0: any free port)") from None
            raise InputError(f"--console-host {host}: cannot serve the console on {host}:{port}: "
                             f"{exc.strerror or exc}") from None
        self.httpd.daemon_threads = True
        self.port = int(self.httpd.server_address[1])
        self._thread = threading.Thread(target=self.httpd.serve_forever, name="console-http", daemon=True)
        self._thread.start()

    @property
    def url(self) -> str:
        """The page's address, with the token when one is required."""
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"http://{host}:{self.port}/" + (f"?token={self.token}" if self.token else "")

    def authorized(self, query: dict[str, list[str]]) -> bool:
        """Whether a request may be served: always on 127.0.0.1, else with the right token."""
        if self.token is None:
            return True
        given = query.get("token", [""])[0]
        return secrets.compare_digest(given.encode(), self.token.encode())

    def close(self) -> None:
        """Stop serving and release the port."""
        self.httpd.shutdown()
        self.httpd.server_close()
        self._thread.join()


def _handler(server: ConsoleServer) -> type[BaseHTTPRequestHandler]:
    class Handler(BaseHTTPRequestHandler):
        """The console's routes."""

        def log_message(self, format: str, *args: Any) -> None:  # noqa: A002 (the base class's name)
            """Requests are not logged: the terminal shows the run."""

        def _send(self, status: int, body: bytes, content_type: str) -> None:
            self.send_response(status)
            self.send_header("Content-Type", content_type)
            self.send_header("Content-Length", str(len(body)))
            self.send_header("Cache-Control", "no-store")
            self.end_headers()
            self.wfile.write(body)

        def _json(self, document: Any, status: int = HTTPStatus.OK) -> None:
            self._send(status, json.dumps(document, allow_nan=False, default=str).encode(), "application/json")

        def _route(self) -> str | None:
            """The path, or None after a 403 (token missing or wrong)."""
            parts = urlsplit(self.path)
            if not server.authorized(parse_qs(parts.query)):
                self._send(HTTPStatus.FORBIDDEN, b"forbidden: open the URL with its token, as labctl printed it\n",
                           "text/plain; charset=utf-8")
                return None
            return parts.path

        def do_GET(self) -> None:  # noqa: N802 (http.server's name)
            """The page, the state and the images."""
            path = self._route()
            if path is None:
                return
            if path == "/":
                self._send(HTTPStatus.OK, server.page, "text/html; charset=utf-8")
            elif path == "/state.json":
                self._json(_finite(server.state.snapshot()))
            elif path in ("/depth.png", "/intensity.png"):
                png = server.state.png(path[1:-4])
                if png is None:
                    self._send(HTTPStatus.NOT_FOUND, b"no frame yet\n", "text/plain; charset=utf-8")
                else:
                    self._send(HTTPStatus.OK, png, "image/png")
            else:
                self._send(HTTPStatus.NOT_FOUND, b"not found\n", "text/plain; charset=utf-8")

        def do_POST(self) -> None:  # noqa: N802 (http.server's name)
            """An answer to the waiting prompt, or Stop."""
            path = self._route()
            if path is None:
                return
            if self.headers.get(HEADER) != "1":
                self._send(HTTPStatus.FORBIDDEN, f"forbidden: {HEADER} header missing\n".encode(),
                           "text/plain; charset=utf-8")
                return
            length = min(int(self.headers.get("Content-Length") or 0), 65536)
            try:
                body = json.loads(self.rfile.read(length) or b"{}")
            except ValueError:
                self._json({"ok": False, "error": "the body is not JSON"}, HTTPStatus.BAD_REQUEST)
                return
            if path == "/answer" and isinstance(body, dict):
                prompt = body.get("prompt")
                ok = isinstance(prompt, int) and server.state.answer(prompt, str(body.get("answer", "")))
                self._json({"ok": ok}, HTTPStatus.OK if ok else HTTPStatus.CONFLICT)
            elif path == "/stop":
                ok = server.state.request_stop()
                self._json({"ok": ok}, HTTPStatus.OK if ok else HTTPStatus.CONFLICT)
            else:
                self._send(HTTPStatus.NOT_FOUND, b"not found\n", "text/plain; charset=utf-8")

    return Handler


def _finite(value: Any) -> Any:
    """NaN and infinities as null (JSON has neither)."""
    if isinstance(value, float):
        return value if value == value and abs(value) != float("inf") else None
    if isinstance(value, dict):
        return {k: _finite(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_finite(v) for v in value]
    return value
