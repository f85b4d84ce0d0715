"""A serial device emulator on a real pseudo-terminal.

The emulator owns the master side of an ``os.openpty()`` pair; :attr:`PtyDevice.port`
is the slave device path, which pyserial opens like any ``/dev/ttyUSB*``. A thread
reads the driver's requests from the master side, lets the subclass answer them
and advances the simulated device in real time (:meth:`PtyDevice.tick`).

Replies leave in order through an outbox, so an injected delay holds back every
later reply too, as a busy device would. Common fault injection lives here:
slow replies, garbled replies and a disconnect (both pty ends closed).
"""

from __future__ import annotations

import contextlib
import os
import select
import threading
import time
import tty
from collections import deque
from types import TracebackType
from typing import Self

GARBAGE = b"\x8f\xfe#%\x07\xc3q\r\n"
"""A reply no documented protocol produces: non-ASCII bytes ending in CR LF."""


class PtyDevice:
    """Base class: a pseudo-terminal, a service thread and ordered, fault-injectable replies.

    Subclasses implement :meth:`handle_line` (one request line, terminator stripped)
    or override :meth:`handle_bytes` for byte-level protocols, and may override
    :meth:`tick` to advance motion. Device state is guarded by :attr:`lock`, which
    the service thread holds while handling requests and ticking; tests take it
    when they inspect or change the state.
    """

    def __init__(self, *, tick_s: float = 0.002) -> None:
        self.lock = threading.RLock()
        self._tick_s = tick_s
        self._master: int | None = None
        self._slave: int | None = None
        self._thread: threading.Thread | None = None
        self._stopping = threading.Event()
        self._outbox: deque[tuple[float, bytes]] = deque()
        self._last_due = 0.0
        self._inbuf = bytearray()
        self._delays: deque[float] = deque()
        self._garble = 0

    # -- life cycle -------------------------------------------------------------

    @property
    def port(self) -> str:
        """Slave device path of the pseudo-terminal, to be opened with pyserial."""
        if self._slave is None:
            raise RuntimeError("emulator not started")
        return os.ttyname(self._slave)

    def start(self) -> Self:
        """Open the pseudo-terminal and start the service thread."""
        self._master, self._slave = os.openpty()
        tty.setraw(self._slave)  # no echo, no CR/LF translation before pyserial opens it
        os.set_blocking(self._master, False)
        self._stopping.clear()
        self.on_start()
        self._thread = threading.Thread(target=self._serve, name=type(self).__name__, daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        """Stop the thread and close both ends of the pseudo-terminal (idempotent)."""
        self._stopping.set()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout=2.0)
        self._thread = None
        for fd in (self._master, self._slave):
            if fd is not None:
                with contextlib.suppress(OSError):
                    os.close(fd)
        self._master = self._slave = None

    def disconnect(self) -> None:
        """Simulate an unplugged cable: the driver's next read or write fails with EIO."""
        self.stop()

    def __enter__(self) -> Self:
        return self.start()

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.stop()

    # -- fault injection ----------------------------------------------------------

    def delay_replies(self, seconds: float, count: int = 1) -> None:
        """Hold the next ``count`` replies back by ``seconds`` (later replies queue behind)."""
        with self.lock:
            self._delays.extend([seconds] * count)

    def garble_replies(self, count: int = 1) -> None:
        """Replace the next ``count`` replies by bytes that match no protocol."""
        with self.lock:
            self._garble += count

    def wait_quiet(self, timeout_s: float = 2.0) -> None:
        """Block until every queued reply (delayed ones included) has been written."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            with self.lock:
                if not self._outbox:
                    return
            time.sleep(0.001)
        raise TimeoutError(f"{type(self).__name__}: replies still queued after {timeout_s} s")

    # -- for subclasses -----------------------------------------------------------

    def on_start(self) -> None:
        """Called once the pseudo-terminal exists, before the thread runs (e.g. a banner)."""

    def handle_bytes(self, data: bytes) -> None:
        """Split the byte stream into lines at LF (CR stripped) and pass each to :meth:`handle_line`."""
        self._inbuf.extend(data)
        while (end := self._inbuf.find(b"\n")) >= 0:
            line = bytes(self._inbuf[:end]).rstrip(b"\r")
            del self._inbuf[: end + 1]
            self.handle_line(line)

    def handle_line(self, line: bytes) -> None:
        """Answer one request line."""
        raise NotImplementedError

    def tick(self, now: float) -> None:
        """Advance the simulated device to monotonic time ``now``."""

    def reply(self, data: bytes, after_s: float = 0.0) -> None:
        """Queue a reply to a request, ``after_s`` from now; subject to injected faults."""
        delay = after_s + (self._delays.popleft() if self._delays else 0.0)
        if self._garble:
            self._garble -= 1
            data = GARBAGE
        self._queue(data, delay)

    def push(self, data: bytes) -> None:
        """Queue an unsolicited message (an alarm, a banner); never delayed or garbled."""
        self._queue(data, 0.0)

    # -- internals ----------------------------------------------------------------

    def _queue(self, data: bytes, delay: float) -> None:
        due = max(time.monotonic() + delay, self._last_due)
        self._last_due = due
        self._outbox.append((due, data))

    def _serve(self) -> None:
        master = self._master
        assert master is not None
        while not self._stopping.is_set():
            try:
                ready, _, _ = select.select([master], [], [], self._tick_s)
                data = os.read(master, 4096) if ready else b""
            except OSError:  # closed by stop()/disconnect()
                return
            with self.lock:
                if data:
                    self.handle_bytes(data)
                now = time.monotonic()
                self.tick(now)
                self._flush(master, now)

    def _flush(self, master: int, now: float) -> None:
        while self._outbox and self._outbox[0][0] <= now:
            _, data = self._outbox.popleft()
            try:
                os.write(master, data)
            except BlockingIOError:  # nobody reads: the pty buffer is full, drop like a UART overrun
                pass
            except OSError:
                return
