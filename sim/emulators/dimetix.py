"""Emulator of a Dimetix laser distance sensor (DLS-C / FLS-C / D-series ASCII command set).

Requests are ``sN<cmd>`` lines (N = device ID 0..9, CR LF), replies ``gN...`` lines
(Dimetix Technical Reference Manual, "Command set"). Emulated: single distance
measurement ``sNg``, tracking with buffering ``sNf+t`` / ``sNq``, stop/clear ``sNc``,
laser on/off ``sNo`` / ``sNp``, serial number ``sNsn`` and software version ``sNsv``.
Requests for another device ID get no reply, as on a shared RS-422 line.
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


class DimetixEmulator(PtyDevice):
    """A Dimetix sensor looking at a target ``distance_mm`` away.

    ``noise_mm`` is the standard deviation of Gaussian measurement noise; a
    measurement takes ``measure_time_s``. Tests read ``laser_on``, ``tracking`` and
    the received ``commands`` (without ``sN``), and inject error replies with
    :meth:`inject_error`. Stop/clear ends tracking and switches the laser off.
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
    ) -> None:
        super().__init__()
        self.distance_mm = distance_mm
        self.noise_mm = noise_mm
        self.device_id = device_id
        self.serial_number = serial_number
        self.software_version = software_version
        self.measure_time_s = measure_time_s
        self.laser_on = False
        self.tracking = False
        self.commands: list[str] = []
        self._rng = random.Random(seed)
        self._errors: deque[int] = deque()
        self._sample_s = 0.0
        self._last_read = 0.0

    def inject_error(self, code: int, count: int = 1) -> None:
        """Answer the next ``count`` measurements (``sNg`` or ``sNq``) with ``gN@E<code>``."""
        with self.lock:
            self._errors.extend([code] * count)

    def handle_line(self, line: bytes) -> None:
        match = _REQUEST.fullmatch(line.decode("ascii", "replace"))
        if match is None or int(match.group(1)) != self.device_id:
            return
        cmd = match.group(2)
        self.commands.append(cmd)
        g = f"g{self.device_id}"
        if cmd == "g":
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
        elif cmd == "sn":
            self._answer(f"{g}sn+{self.serial_number:08d}")
        elif cmd == "sv":
            self._answer(f"{g}sv+{self.software_version}")
        else:
            self._answer(f"{g}@E203")  # wrong syntax / unknown command

    def _measure(self, g: str) -> None:
        if self.tracking:
            self._answer(f"{g}@E212")  # not possible while tracking is active
        elif self._errors:
            self._answer(f"{g}@E{self._errors.popleft():03d}", self.measure_time_s)
        else:
            self._answer(f"{g}g{self._distance_field()}", self.measure_time_s)

    def _start_tracking(self, g: str, sample_s: float) -> None:
        if self.tracking:
            self._answer(f"{g}@E212")
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
        self.reply(text.encode("ascii") + b"\r\n", after_s)
