"""Emulator of a Dimetix laser distance sensor (DLS-C / FLS-C / D-series ASCII command set).

Requests are ``sN<cmd>`` lines (N = device ID 0..9, CR LF), replies ``gN...`` lines
(Dimetix Technical Reference Manual, "Command set"). Emulated: the start sequence
``gN?`` after power-on, single distance measurement ``sNg``, tracking with buffering
``sNf+t`` / ``sNq``, stop/clear ``sNc``, laser on/off ``sNo`` / ``sNp``, and the
identity queries serial number ``sNsn`` and software version ``sNsv``, which a sensor
built with ``identity_commands=False`` rejects like any unknown command.
Requests for another device ID get no reply, as on a shared RS-422 line.

Error codes (manual, "Error codes"): ``@E203`` for an unknown command or malformed
parameter, ``@E210`` for ``sNq`` outside tracking, ``@E211`` for a sampling time
shorter than a measurement takes, ``@E212`` for any command but ``sNc`` and ``sNq``
while tracking; any other code by injection (:meth:`DimetixEmulator.inject_error`).
"""

from __future__ import annotations

import math
import random
import re
import time
from collections import deque

from sim.emulators.pty_device import PtyDevice

_REQUEST = re.compile(r"s(\d)(.*)")
_TRACK_START = re.compile(r"f\+(\d{8})")
_WHILE_TRACKING = frozenset({"c", "q"})
"""The commands a tracking sensor still accepts (manual, E212: stop tracking with sNc first)."""


class DimetixEmulator(PtyDevice):
    """A Dimetix sensor looking at a target ``distance_mm`` away.

    ``noise_mm`` is the standard deviation of Gaussian measurement noise; a
    measurement takes ``measure_time_s``. ``identity_commands`` False models a
    firmware without ``sNsn`` / ``sNsv``. Tests read ``laser_on``, ``tracking`` and
    the received ``commands`` (without ``sN``), and inject error replies with
    :meth:`inject_error` and stray lines with :meth:`stray_lines_before_next_reply`.
    Stop/clear ends tracking and switches the laser off.
    """

    def __init__(
        self,
        *,
        distance_mm: float = 1500.0,
        noise_mm: float = 0.0,
        device_id: int = 0,
        serial_number: int = 12345678,
        software_version: str = "01230456",
        measure_time_s: float = 0.005,
        seed: int = 0,
        identity_commands: bool = True,
    ) -> None:
        super().__init__()
        self.distance_mm = distance_mm
        self.noise_mm = noise_mm
        self.device_id = device_id
        self.serial_number = serial_number
        self.software_version = software_version
        self.measure_time_s = measure_time_s
        self.identity_commands = identity_commands
        self.laser_on = False
        self.tracking = False
        self.commands: list[str] = []
        self._rng = random.Random(seed)
        self._errors: deque[int] = deque()
        self._stray: list[str] = []
        self._sample_s = 0.0
        self._last_read = 0.0

    def on_start(self) -> None:
        """Power-on: the start sequence ``gN?`` (manual, "Startup sequence")."""
        self.push(f"g{self.device_id}?\r\n".encode("ascii"))

    def inject_error(self, code: int, count: int = 1) -> None:
        """Answer the next ``count`` measurements (``sNg`` or ``sNq``) with ``gN@E<code>``."""
        with self.lock:
            self._errors.extend([code] * count)

    def stray_lines_before_next_reply(self, *lines: str) -> None:
        """Send ``lines`` (e.g. ``g0?``, the start sequence of a sensor that restarted, or a line
        of another sensor on the bus) just before the next reply."""
        with self.lock:
            self._stray.extend(lines)

    def handle_line(self, line: bytes) -> None:
        match = _REQUEST.fullmatch(line.decode("ascii", "replace"))
        if match is None or int(match.group(1)) != self.device_id:
            return
        cmd = match.group(2)
        self.commands.append(cmd)
        g = f"g{self.device_id}"
        if self.tracking and cmd not in _WHILE_TRACKING:
            self._answer(f"{g}@E212")  # not possible while tracking is active
        elif cmd == "g":
            self._measure(g)
        elif cmd == "q":
            self._read_buffer(g)
        elif (start := _TRACK_START.fullmatch(cmd)) is not None:
            self._start_tracking(g, int(start.group(1)) * 0.01)
        elif cmd == "c":
            self.tracking = False
            self.laser_on = False
            self._answer(f"{g}?")
        elif cmd in ("o", "p"):
            self.laser_on = cmd == "o"
            self._answer(f"{g}?")
        elif cmd == "sn" and self.identity_commands:
            self._answer(f"{g}sn+{self.serial_number:08d}")
        elif cmd == "sv" and self.identity_commands:
            self._answer(f"{g}sv+{self.software_version}")
        else:
            self._answer(f"{g}@E203")  # wrong syntax / unknown command

    def _measure(self, g: str) -> None:
        if self._errors:
            self._answer(f"{g}@E{self._errors.popleft():03d}", self.measure_time_s)
        else:
            self._answer(f"{g}g{self._distance_field()}", self.measure_time_s)

    def _start_tracking(self, g: str, sample_s: float) -> None:
        if 0 < sample_s < self.measure_time_s:
            self._answer(f"{g}@E211")  # sampling too fast
            return
        self.tracking = True
        self.laser_on = True
        self._sample_s = max(sample_s, self.measure_time_s, 1e-3)
        self._last_read = time.monotonic()
        self._answer(f"{g}f?")

    def _read_buffer(self, g: str) -> None:
        if not self.tracking:
            self._answer(f"{g}@E210")  # not in tracking mode
            return
        now = time.monotonic()
        samples = math.floor((now - self._last_read) / self._sample_s)
        fresh = min(samples, 2)  # 0 none new, 1 one new, 2 new and older ones overwritten
        if samples:
            self._last_read = now
        if self._errors:
            self._answer(f"{g}@E{self._errors.popleft():03d}+{fresh}")
        else:
            self._answer(f"{g}q{self._distance_field()}+{fresh}")

    def _distance_field(self) -> str:
        value = self.distance_mm + (self._rng.gauss(0.0, self.noise_mm) if self.noise_mm else 0.0)
        tenths = round(value * 10)
        return f"{'+' if tenths >= 0 else '-'}{abs(tenths):08d}"

    def _answer(self, text: str, after_s: float = 0.0) -> None:
        lines = [*self._stray, text]
        self._stray.clear()
        self.reply("".join(f"{line}\r\n" for line in lines).encode("ascii"), after_s)
