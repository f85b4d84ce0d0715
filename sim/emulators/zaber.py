"""Emulator of a single-axis Zaber stage speaking the Zaber ASCII protocol.

Message format (Zaber ASCII Protocol Manual, "Message Format"): commands
``/device axis [id] command [data]`` ending in LF; replies
``@device axis [id] OK|RJ IDLE|BUSY flag data`` ending in CR LF, where ``flag`` is
the highest-precedence active warning flag or ``--``, and ``data`` of a rejection
(``RJ``) is the reason. Emulated commands: ``get pos``, ``get deviceid``,
``get version``, ``get system.serial``, ``get limit.min|limit.max|maxspeed``,
``home``, ``move abs``, ``stop``, ``warnings`` and ``warnings clear``.

The carriage moves at ``speed_mm_s`` in real time. Until homed the axis has no
reference position (flag ``WR``) and rejects ``move abs`` (modelled as ``BADCOMMAND``;
the driver does not rely on that reason, it refuses to move while ``WR`` is set). Fault (``F*``) flags
stay until a test removes them from :attr:`ZaberEmulator.flags`; ``warnings clear``
clears the others.
"""

from __future__ import annotations

import time
from collections import deque
from dataclasses import dataclass

from sim.emulators.pty_device import PtyDevice

FLAG_PRECEDENCE = (
    "FD", "FQ", "FS", "FT", "FB", "FP", "FE",
    "WL", "WV", "WT", "WS", "WM", "WP", "WR", "WH",
    "NC", "NI", "ND", "NU", "NJ",
)  # fmt: skip
"""Warning flags, highest precedence first (manual, "Warning Flags")."""

MAXSPEED_PER_MICROSTEP_S = 1.6384
"""``maxspeed`` data per (microstep/s) (manual, "Physical Units": velocity)."""


@dataclass
class _Motion:
    start: float
    target: float
    started: float
    speed: float  # microsteps / s
    homing: bool
    flag_at_end: str | None = None


class ZaberEmulator(PtyDevice):
    """A Zaber linear stage with ``travel_mm`` of travel and one axis.

    The carriage starts unreferenced at ``start_mm`` (default: mid-travel) and moves
    at ``speed_mm_s`` (which a test may change between moves). Tests
    may inject rejections (:meth:`reject_next`), raise flags (:meth:`raise_flag`) and
    stop the next move part-way with a flag (:meth:`interrupt_next_move`, e.g. ``WL``
    for a triggered limit sensor, ``FS`` for a stall).
    """

    def __init__(
        self,
        *,
        mm_per_microstep: float,
        travel_mm: float = 300.0,
        speed_mm_s: float = 1000.0,
        start_mm: float | None = None,
        device: int = 1,
        device_id: int = 50081,
        serial_number: int = 123456,
        version: str = "7.38",
    ) -> None:
        super().__init__()
        self.device = device
        self.device_id = device_id
        self.serial_number = serial_number
        self.version = version
        self.mm_per_microstep = mm_per_microstep
        self.limit_max = round(travel_mm / mm_per_microstep)
        self.speed_mm_s = speed_mm_s
        self.referenced = False
        self.flags: set[str] = set()
        self.commands: list[str] = []
        self._position = float(round((travel_mm / 2 if start_mm is None else start_mm) / mm_per_microstep))
        self._motion: _Motion | None = None
        self._rejections: deque[str] = deque()
        self._interrupt: tuple[float, str] | None = None

    # -- fault injection ------------------------------------------------------------

    def reject_next(self, reason: str) -> None:
        """Reject the next command with ``RJ`` and ``reason`` (e.g. ``BADDATA``)."""
        with self.lock:
            self._rejections.append(reason)

    def raise_flag(self, flag: str) -> None:
        """Set a warning or fault flag, e.g. ``FD`` (driver disabled)."""
        with self.lock:
            self.flags.add(flag)

    def interrupt_next_move(self, at_mm: float, flag: str) -> None:
        """Stop the next move or homing run that passes ``at_mm`` there and raise ``flag``."""
        with self.lock:
            self._interrupt = (at_mm / self.mm_per_microstep, flag)

    @property
    def position_mm(self) -> float:
        """Current carriage position in mm."""
        with self.lock:
            return self._current(time.monotonic()) * self.mm_per_microstep

    @property
    def moving(self) -> bool:
        """True while the carriage moves."""
        with self.lock:
            return self._motion is not None

    # -- protocol -------------------------------------------------------------------

    def handle_line(self, line: bytes) -> None:
        text = line.decode("ascii", "replace").strip()
        if not text.startswith("/"):
            return
        words = text[1:].split()
        numbers: list[int] = []
        while words and words[0].isdigit() and len(numbers) < 3:
            numbers.append(int(words.pop(0)))
        device = numbers[0] if numbers else 0
        if device not in (0, self.device):
            return
        axis = numbers[1] if len(numbers) > 1 else 0
        header = f"@{self.device:02d} {axis}" + (f" {numbers[2]:02d}" if len(numbers) > 2 else "")
        command = " ".join(words)
        self.commands.append(command)
        now = time.monotonic()
        if axis > 1:
            self._answer(header, "BADAXIS", now, rejected=True)
        elif self._rejections:
            self._answer(header, self._rejections.popleft(), now, rejected=True)
        else:
            data, rejected = self._execute(command, axis, now)
            self._answer(header, data, now, rejected=rejected)

    def _execute(self, command: str, axis: int, now: float) -> tuple[str, bool]:
        device_settings = {
            "get deviceid": str(self.device_id),
            "get version": self.version,
            "get system.serial": str(self.serial_number),
        }
        if command in device_settings:
            return ("DEVICEONLY", True) if axis else (device_settings[command], False)
        if command == "get pos":
            return str(round(self._current(now))), False
        if command == "get limit.min":
            return "0", False
        if command == "get limit.max":
            return str(self.limit_max), False
        if command == "get maxspeed":
            return str(round(self.speed_mm_s / self.mm_per_microstep * MAXSPEED_PER_MICROSTEP_S)), False
        if command == "home":
            self._start(0.0, now, homing=True)
            return "0", False
        if command.startswith("move abs "):
            return self._move_abs(command.removeprefix("move abs "), now)
        if command == "stop":
            if self._motion is not None:
                self._position = self._current(now)
                self._motion = None
                self.flags.add("NI")
            return "0", False
        if command in ("warnings", "warnings clear"):
            active = self._active_flags()
            if command == "warnings clear":
                self.flags = {flag for flag in self.flags if flag.startswith("F")}
            return " ".join([f"{len(active):02d}", *active]), False
        if command == "":
            return "0", False
        return "BADCOMMAND", True

    def _move_abs(self, value: str, now: float) -> tuple[str, bool]:
        try:
            target = int(value)
        except ValueError:
            return "BADDATA", True
        if not self.referenced:
            return "BADCOMMAND", True
        if not 0 <= target <= self.limit_max:
            return "BADDATA", True
        self._start(float(target), now, homing=False)
        return "0", False

    def _start(self, target: float, now: float, *, homing: bool) -> None:
        start = self._current(now)
        if self._motion is not None:
            self.flags.add("NI")  # a new movement interrupted the running one
        motion = _Motion(start, target, now, self.speed_mm_s / self.mm_per_microstep, homing)
        if self._interrupt is not None:
            at, flag = self._interrupt
            if min(start, target) <= at <= max(start, target):
                motion.target, motion.flag_at_end = at, flag
                self._interrupt = None
        self._motion = motion

    def _current(self, now: float) -> float:
        motion = self._motion
        if motion is None:
            return self._position
        distance = motion.target - motion.start
        travelled = min(motion.speed * (now - motion.started), abs(distance))
        return motion.start + (travelled if distance >= 0 else -travelled)

    def tick(self, now: float) -> None:
        motion = self._motion
        if motion is None or motion.speed * (now - motion.started) < abs(motion.target - motion.start):
            return
        self._position = motion.target
        self._motion = None
        if motion.flag_at_end is not None:
            self.flags.add(motion.flag_at_end)
        elif motion.homing:  # an interrupted homing run leaves the axis without reference
            self.referenced = True
            self._position = 0.0

    def _active_flags(self) -> list[str]:
        active = set(self.flags) | ({"WR"} if not self.referenced else set())
        rank = {flag: i for i, flag in enumerate(FLAG_PRECEDENCE)}
        return sorted(active, key=lambda flag: (rank.get(flag, len(rank)), flag))

    def _answer(self, header: str, data: str, now: float, *, rejected: bool) -> None:
        active = self._active_flags()
        status = "BUSY" if self._motion is not None else "IDLE"
        text = f"{header} {'RJ' if rejected else 'OK'} {status} {active[0] if active else '--'} {data}"
        self.reply(text.encode("ascii") + b"\r\n")
