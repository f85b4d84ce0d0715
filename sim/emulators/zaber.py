"""Emulator of a single-axis Zaber device speaking the Zaber ASCII protocol (firmware 7).

Message format (Zaber ASCII Protocol Manual, "Message Format"): a command is
``/[device [axis [id]]] [command [data]][:CC]`` ending in LF (CR LF accepted). ``device``
0 or none addresses every device, ``axis`` 0 or none the device itself, ``id`` is a
message ID (0..99 or ``--``) echoed in the reply, and ``:CC`` an optional checksum:
two hex digits that make the byte sum of everything between ``/`` and ``:`` plus
the checksum's value 0 modulo 256 (an LRC). A command whose checksum fails is
dropped unanswered (this emulator's reading; what a real device answers is listed
for the first day on hardware in docs/devices.md). Replies are ``@device axis [id] OK|RJ IDLE|BUSY flag data``
(CR LF), with ``:CC`` appended while ``comm.checksum`` is 1; ``flag`` is the active
warning flag of highest precedence or ``--``; a rejected (``RJ``) command's ``data``
is the reason. ``/`` alone is a ping every device answers. With ``comm.alert`` 1 the
device sends an alert ``!device axis IDLE flag`` when a movement ends.

Emulated commands: ``get`` of ``pos``, ``deviceid``, ``version``, ``system.serial``,
``system.axiscount``, ``limit.min``, ``limit.max``, ``maxspeed``, ``resolution``,
``comm.checksum``, ``comm.alert``; ``set`` of ``maxspeed``, ``comm.checksum``,
``comm.alert``; ``home``, ``move abs|rel``, ``stop``, ``estop``, ``warnings``,
``warnings clear``, ``system reset``, ``tools parking park|unpark|state``.
Rejections: ``BADCOMMAND`` (unknown command or setting; a move without reference
position), ``BADDATA`` (malformed or out-of-range data), ``BADAXIS`` (axis > 1),
``DEVICEONLY`` (a device setting or command sent to an axis), ``BADMESSAGEID``
(an ID above 99), ``PARKED`` (motion while parked), ``STATUSBUSY`` (parking while
moving); others (``AGAIN``, ``NOACCESS``, ...) by injection (:meth:`reject_next`).

The carriage moves at the speed set by ``maxspeed`` in real time and every reply
while it moves says ``BUSY``; a ``move`` or ``home`` sent while moving replaces the
running movement and raises ``NI``, as do ``stop`` and ``estop`` (both stop at once
here; a real ``stop`` decelerates). Until homed the axis has no reference position
(``WR``). ``system reset`` answers, then restarts the device: motion stops, flags are
cleared and the reference is lost unless the axis was parked. Fault (``F*``) flags
stay until a test removes them from :attr:`ZaberEmulator.flags`; ``warnings clear``
clears the others.
"""

from __future__ import annotations

import time
from collections import deque
from dataclasses import dataclass

from sim.emulators.pty_device import PtyDevice

FLAG_PRECEDENCE = (
    "FF", "FN", "FZ", "FH", "FV", "FO", "FC", "FM", "FD", "FQ", "FI", "FA", "FR", "FS", "FB", "FP", "FE", "FT",
    "WL", "WV", "WT", "WS", "WM", "WP", "WR", "WH",
    "NC", "NI", "ND", "NR", "NT", "NU", "NJ", "NB",
)  # fmt: skip
"""Warning flags, highest precedence first: faults, then warnings, then notices (manual,
"Warning Flags"), each group in the order Zaber's client library zaber-motion lists them."""

MAXSPEED_PER_MICROSTEP_S = 1.6384
"""``maxspeed`` data per (microstep/s) (manual, "Physical Units": velocity)."""

DEVICE_SETTINGS = frozenset({"deviceid", "version", "system.serial", "system.axiscount", "comm.checksum", "comm.alert"})
"""Settings of the device as a whole: sent to an axis they are rejected ``DEVICEONLY``."""


@dataclass
class _Motion:
    start: float
    target: float
    started: float
    speed: float  # microsteps / s
    homing: bool
    flag_at_end: str | None = None


def _lrc_ok(body: str, checksum: str) -> bool:
    """True if ``checksum`` (two hex digits) brings the byte sum of ``body`` to 0 modulo 256."""
    try:
        value = int(checksum, 16)
    except ValueError:
        return False
    return len(checksum) == 2 and (sum(body.encode("ascii", "replace")) + value) % 256 == 0


class ZaberEmulator(PtyDevice):
    """A Zaber linear stage with ``travel_mm`` of travel and one axis.

    The carriage starts unreferenced at ``start_mm`` (default: mid-travel) and moves
    at ``speed_mm_s`` (which a test may change between moves, or the host with
    ``set maxspeed``). ``reply_checksums`` is the initial ``comm.checksum``. Tests may
    inject rejections (:meth:`reject_next`), corrupt reply checksums
    (:meth:`corrupt_checksums`), send messages ahead of a reply
    (:meth:`messages_before_next_reply`), raise flags (:meth:`raise_flag`) and stop the next
    move part-way with a flag (:meth:`interrupt_next_move`, e.g. ``WL`` for a triggered
    limit sensor, ``FS`` for a stall); they read the raw request lines in
    :attr:`lines`, the commands (without header and checksum) in :attr:`commands`
    and the number of requests dropped for a bad checksum in :attr:`bad_checksums`.
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
        reply_checksums: bool = False,
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
        self.parked = False
        self.reply_checksums = reply_checksums
        self.alerts = False
        self.flags: set[str] = set()
        self.lines: list[str] = []
        self.commands: list[str] = []
        self.bad_checksums = 0
        self.resets = 0
        self._position = float(round((travel_mm / 2 if start_mm is None else start_mm) / mm_per_microstep))
        self._motion: _Motion | None = None
        self._rejections: deque[str] = deque()
        self._interrupt: tuple[float, str] | None = None
        self._corrupt_checksums = 0
        self._early: list[str] = []

    # -- fault injection ------------------------------------------------------------

    def reject_next(self, reason: str) -> None:
        """Reject the next command with ``RJ`` and ``reason`` (e.g. ``AGAIN``)."""
        with self.lock:
            self._rejections.append(reason)

    def corrupt_checksums(self, count: int = 1) -> None:
        """Send the next ``count`` reply checksums off by one (needs ``comm.checksum`` 1)."""
        with self.lock:
            self._corrupt_checksums += count

    def messages_before_next_reply(self, *lines: str) -> None:
        """Send ``lines`` (alerts ``!...``, info messages ``#...``) just ahead of the next reply,
        as when an alert crosses a command on the wire."""
        with self.lock:
            self._early.extend(lines)

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

    # -- protocol: framing ------------------------------------------------------------

    def handle_line(self, line: bytes) -> None:
        text = line.decode("ascii", "replace").strip()
        if not text.startswith("/"):
            return
        self.lines.append(text)
        body = text[1:]
        if ":" in body:
            body, _, checksum = body.rpartition(":")
            if not _lrc_ok(body, checksum):
                self.bad_checksums += 1
                return
        words = body.split()
        numbers: list[int] = []
        while words and words[0].isdigit() and len(numbers) < 2:
            numbers.append(int(words.pop(0)))
        device = numbers[0] if numbers else 0
        if device not in (0, self.device):
            return
        axis = numbers[1] if len(numbers) > 1 else 0
        message_id = words.pop(0) if len(numbers) == 2 and words and (words[0].isdigit() or words[0] == "--") else None
        header = f"@{self.device:02d} {axis}" + ("" if message_id is None else f" {message_id.zfill(2)}")
        command = " ".join(words)
        self.commands.append(command)
        now = time.monotonic()
        if message_id is not None and message_id != "--" and int(message_id) > 99:
            data, rejected = "BADMESSAGEID", True
        elif axis > 1:
            data, rejected = "BADAXIS", True
        elif self._rejections:
            data, rejected = self._rejections.popleft(), True
        else:
            data, rejected = self._execute(command.split(), axis, now)
        self._send(f"{header} {'RJ' if rejected else 'OK'} {self._status()} {self._top_flag()} {data}")
        if command == "system reset" and not rejected:
            self._reset()

    def _send(self, text: str, *, unsolicited: bool = False) -> None:
        """Send a reply (or an alert, ``unsolicited``), with its checksum while ``comm.checksum`` is 1."""
        if self.reply_checksums:
            corrupt = int(self._corrupt_checksums > 0 and not unsolicited)
            self._corrupt_checksums -= corrupt
            text += f":{(corrupt - sum(text[1:].encode('ascii'))) & 0xFF:02X}"
        data = text.encode("ascii") + b"\r\n"
        if not unsolicited and self._early:
            data = "".join(f"{line}\r\n" for line in self._early).encode("ascii") + data
            self._early.clear()
        if unsolicited:
            self.push(data)
        else:
            self.reply(data)

    # -- protocol: commands -------------------------------------------------------------

    def _execute(self, words: list[str], axis: int, now: float) -> tuple[str, bool]:
        """Carry out one command; return (data, rejected)."""
        match words:
            case []:
                return "0", False
            case ["get", setting]:
                return self._get(setting, axis, now)
            case ["set", setting, value]:
                return self._set(setting, value, axis)
            case ["warnings"] | ["warnings", "clear"]:
                active = self._active_flags()
                if words[-1] == "clear":
                    self.flags = {flag for flag in self.flags if flag.startswith("F")}
                return " ".join([f"{len(active):02d}", *active]), False
            case ["system", "reset"]:
                return ("DEVICEONLY", True) if axis else ("0", False)
            case ["tools", "parking", action]:
                return self._parking(action, axis)
            case ["stop"] | ["estop"]:
                self._halt(now)
                return "0", False
            case ["home"]:
                return self._move(0.0, now, homing=True)
            case ["move", ("abs" | "rel") as kind, value]:
                return self._move_command(kind, value, now)
        return "BADCOMMAND", True

    def _get(self, setting: str, axis: int, now: float) -> tuple[str, bool]:
        values = {
            "pos": str(round(self._current(now))),
            "limit.min": "0",
            "limit.max": str(self.limit_max),
            "maxspeed": str(round(self.speed_mm_s / self.mm_per_microstep * MAXSPEED_PER_MICROSTEP_S)),
            "resolution": "64",
            "deviceid": str(self.device_id),
            "version": self.version,
            "system.serial": str(self.serial_number),
            "system.axiscount": "1",
            "comm.checksum": str(int(self.reply_checksums)),
            "comm.alert": str(int(self.alerts)),
        }
        if setting not in values:
            return "BADCOMMAND", True
        if axis and setting in DEVICE_SETTINGS:
            return "DEVICEONLY", True
        return values[setting], False

    def _set(self, setting: str, value: str, axis: int) -> tuple[str, bool]:
        if setting not in ("maxspeed", "comm.checksum", "comm.alert"):
            return "BADCOMMAND", True
        if axis and setting in DEVICE_SETTINGS:
            return "DEVICEONLY", True
        valid = value in ("0", "1") if setting != "maxspeed" else value.isdigit() and int(value) > 0
        if not valid:
            return "BADDATA", True
        if setting == "maxspeed":
            self.speed_mm_s = int(value) / MAXSPEED_PER_MICROSTEP_S * self.mm_per_microstep
        elif setting == "comm.checksum":
            self.reply_checksums = value == "1"
        else:
            self.alerts = value == "1"
        return "0", False

    def _parking(self, action: str, axis: int) -> tuple[str, bool]:
        if axis:
            return "DEVICEONLY", True
        if action == "state":
            return str(int(self.parked)), False
        if action not in ("park", "unpark"):
            return "BADCOMMAND", True
        if self._motion is not None:
            return "STATUSBUSY", True
        self.parked = action == "park"
        return "0", False

    def _move_command(self, kind: str, value: str, now: float) -> tuple[str, bool]:
        try:
            distance = int(value)
        except ValueError:
            return "BADDATA", True
        target = distance + (round(self._current(now)) if kind == "rel" else 0)
        if not 0 <= target <= self.limit_max:
            return "BADDATA", True
        return self._move(float(target), now, homing=False)

    def _move(self, target: float, now: float, *, homing: bool) -> tuple[str, bool]:
        if self.parked:
            return "PARKED", True
        if not homing and not self.referenced:
            return "BADCOMMAND", True
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
        return "0", False

    def _halt(self, now: float) -> None:
        if self._motion is not None:
            self._position = self._current(now)
            self._motion = None
            self.flags.add("NI")

    def _reset(self) -> None:
        """Restart after ``system reset``: motion stops, flags clear, the reference survives only parking."""
        self._position = self._current(time.monotonic())
        self._motion = None
        self.flags = set()
        self._rejections.clear()
        self.referenced = self.referenced and self.parked
        self.resets += 1

    # -- motion and status ----------------------------------------------------------

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
        if self.alerts:
            self._send(f"!{self.device:02d} 1 IDLE {self._top_flag()}", unsolicited=True)

    def _status(self) -> str:
        return "BUSY" if self._motion is not None else "IDLE"

    def _active_flags(self) -> list[str]:
        active = set(self.flags) | ({"WR"} if not self.referenced else set())
        rank = {flag: i for i, flag in enumerate(FLAG_PRECEDENCE)}
        return sorted(active, key=lambda flag: (rank.get(flag, len(rank)), flag))

    def _top_flag(self) -> str:
        active = self._active_flags()
        return active[0] if active else "--"
