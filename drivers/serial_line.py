"""A serial port that exchanges ASCII lines with bounded waits (pyserial).

The Dimetix, Zaber and Grbl drivers share it: each opens the port with its own
line settings, writes a request, and reads reply lines that end in a fixed
terminator. Every wait is bounded; a silent or half-answering device raises
:class:`~drivers.errors.SerialTimeout` with what arrived so far, bytes that are
not ASCII raise :class:`~drivers.errors.SerialGarbage`, and a port that fails or
vanishes (an unplugged USB adapter: EIO, or pyserial's "returned no data") raises a fatal
:class:`~drivers.errors.DeviceVanished` naming the port.

pyserial reference: ``serial.Serial`` (``timeout``, ``write_timeout``,
``in_waiting``) and ``serial.SerialTimeoutException`` for a write that timed out;
``serial.SerialException`` is an ``OSError``; opening can also raise
``termios.error`` when the port refuses the line settings (seen on a
pseudo-terminal re-opened with 7 data bits and even parity).
"""

from __future__ import annotations

import contextlib
import termios
import time
from typing import Any

import serial

from drivers.errors import DeviceError, DeviceVanished, SerialGarbage, SerialTimeout, not_connected

POLL_S = 0.02
"""Read timeout of one ``read()`` call: how often a wait checks its deadline."""


class SerialLine:
    """One serial port carrying ASCII lines ending in ``terminator``.

    ``name`` names the device and port in every error; ``timeout_s`` bounds writes
    and is the default reply deadline. With ``terminator=b"\\n"`` a trailing CR is
    stripped too, so CR LF and LF lines both read. Bytes after a returned line stay
    buffered for the next :meth:`read_line`. Not thread-safe: the driver holds its
    own lock around an exchange.
    """

    def __init__(
        self,
        name: str,
        port: str,
        baud: int,
        *,
        terminator: bytes,
        timeout_s: float,
        **options: Any,
    ) -> None:
        self.name = name
        self.port = port
        self.baud = baud
        self.terminator = terminator
        self.timeout_s = timeout_s
        self.options = options
        self._serial: serial.Serial | None = None
        self._buffer = bytearray()

    @property
    def is_open(self) -> bool:
        """Whether the port is open."""
        return self._serial is not None

    def open(self) -> None:
        """Open the port (pyserial ``serial.Serial``); DeviceError naming port and baud rate on failure."""
        if self._serial is not None:
            return
        try:
            self._serial = serial.Serial(
                self.port, self.baud, timeout=POLL_S, write_timeout=self.timeout_s, **self.options
            )
        except (OSError, ValueError, termios.error) as exc:  # termios.error: the line settings were refused
            raise DeviceError(self.name, f"cannot open the port at {self.baud} baud: {exc}") from exc

    def close(self) -> None:
        """Close the port and drop buffered input (idempotent)."""
        port, self._serial = self._serial, None
        self._buffer.clear()
        if port is not None:
            with contextlib.suppress(OSError):
                port.close()

    def _port(self) -> serial.Serial:
        if self._serial is None:
            raise not_connected(self.name)
        return self._serial

    def _vanished(self, during: str, exc: OSError) -> DeviceVanished:
        return DeviceVanished(
            self.name, f"the port {self.port} failed or vanished {during} ({exc}): the USB-serial adapter was "
            "unplugged or lost power; check its cable", self.port,
        )

    def discard_input(self) -> bytes:
        """Drop and return everything received but not read yet (late replies, pushed messages)."""
        port = self._port()
        try:
            stale = bytes(self._buffer) + (port.read(waiting) if (waiting := port.in_waiting) else b"")
        except OSError as exc:  # pyserial's SerialException is an OSError
            raise self._vanished("reading", exc) from exc
        self._buffer.clear()
        return stale

    def write(self, data: bytes, what: str) -> None:
        """Send ``data`` (``what`` describes it in errors); a blocked write times out after ``timeout_s``."""
        port = self._port()
        try:
            port.write(data)
        except serial.SerialTimeoutException as exc:
            raise SerialTimeout(self.name, f"writing '{what}' timed out after {self.timeout_s} s") from exc
        except OSError as exc:
            raise self._vanished(f"writing '{what}'", exc) from exc

    def read_line(self, expected: str, deadline: float | None = None) -> str:
        """The next line without its terminator, waiting until ``deadline`` (monotonic time;
        default ``timeout_s`` from now). ``expected`` describes the awaited reply in errors."""
        port = self._port()
        started = time.monotonic()
        if deadline is None:
            deadline = started + self.timeout_s
        while (end := self._buffer.find(self.terminator)) < 0:
            if time.monotonic() > deadline:
                waited = time.monotonic() - started
                raise SerialTimeout(
                    self.name,
                    f"no complete reply within {waited:.2f} s (expected {expected}; got {bytes(self._buffer)!r})",
                )
            try:
                self._buffer += port.read(port.in_waiting or 1)
            except OSError as exc:
                raise self._vanished(f"waiting for {expected}", exc) from exc
        raw = bytes(self._buffer[:end])
        del self._buffer[: end + len(self.terminator)]
        if self.terminator == b"\n":
            raw = raw.rstrip(b"\r")
        try:
            return raw.decode("ascii")
        except UnicodeDecodeError as exc:
            raise SerialGarbage(self.name, f"non-ASCII reply {raw!r} (expected {expected})") from exc
