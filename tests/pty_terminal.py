"""``labctl`` in a subprocess on a real pseudo-terminal: what an operator at a console sees and types.

The pseudo-terminal is the child's controlling terminal (stdin, stdout and
stderr), so typing Ctrl-C (byte 0x03) makes the terminal driver send SIGINT,
exactly as at a console.
"""

from __future__ import annotations

import fcntl
import os
import re
import select
import signal
import subprocess
import sys
import termios
import time
from pathlib import Path


class Terminal:
    """A running ``python -m labctl ARGS`` on a pseudo-terminal."""

    def __init__(self, *args: str | Path, env: dict[str, str] | None = None) -> None:
        master, slave = os.openpty()

        def controlling_terminal() -> None:
            os.setsid()
            fcntl.ioctl(0, termios.TIOCSCTTY, 0)

        self.master = master
        self.output = ""
        self.process = subprocess.Popen(
            [sys.executable, "-m", "labctl", *map(str, args)],
            stdin=slave, stdout=slave, stderr=slave, preexec_fn=controlling_terminal,
            env={**os.environ, "COLUMNS": "200", "PYTHONFAULTHANDLER": "1", **(env or {})},
        )
        os.close(slave)

    def _read(self, timeout: float) -> bool:
        ready, _, _ = select.select([self.master], [], [], timeout)
        if not ready:
            return True
        try:
            data = os.read(self.master, 65536)
        except OSError:  # EIO: the child closed the terminal (it exited)
            return False
        if not data:
            return False
        self.output += data.decode(errors="replace")
        return True

    def expect(self, pattern: str, timeout: float = 120.0) -> re.Match[str]:
        """Wait until the output matches ``pattern`` (searched over everything printed so far)."""
        deadline = time.monotonic() + timeout
        while (found := re.search(pattern, self.output)) is None:
            left = deadline - time.monotonic()
            if left <= 0 or not self._read(min(left, 0.2)) and self.process.poll() is not None:
                raise AssertionError(f"{pattern!r} not printed within {timeout} s; output:\n{self.output}")
        return found

    def type(self, text: str) -> None:
        os.write(self.master, text.encode())

    def wait(self, timeout: float = 120.0) -> int:
        """The exit code; everything printed until then is in :attr:`output`."""
        deadline = time.monotonic() + timeout
        while self.process.poll() is None and time.monotonic() < deadline:
            self._read(0.1)
        if self.process.poll() is None:  # hung: make it print where (faulthandler), then stop it
            self.process.send_signal(signal.SIGABRT)
            time.sleep(1.0)
            self._read(0.5)
            self.process.kill()
            raise AssertionError(f"labctl still running after {timeout} s; output:\n{self.output}")
        while self._read(0.05) and select.select([self.master], [], [], 0)[0]:
            pass
        return self.process.returncode

    def hang_up(self) -> None:
        """Close the terminal as a dropped SSH session or a closed terminal window does: the kernel sends
        SIGHUP to the child, and its further output fails (EIO). Nothing more is read."""
        if self.master >= 0:
            os.close(self.master)
            self.master = -1

    def close(self) -> None:
        if self.process.poll() is None:
            self.process.kill()
            self.process.wait()
        self.hang_up()
