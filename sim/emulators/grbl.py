"""Emulator of a Grbl 1.1 controller driving a linear stage.

Follows Grbl's ``doc/markdown/interface.md`` (v1.1): lines end in LF or CR (each
one ends a line, so an empty line gets its own ``ok``), replies are ``ok`` or
``error:N``, ``ALARM:N`` and ``[MSG:...]`` are pushed, ``?`` returns a status report
``<State|MPos:x,y,z|FS:feed,speed>``, ``!`` (feed hold) cancels a jog, Ctrl-X
(0x18) soft-resets and prints the welcome banner. Emulated line commands:
``$J=`` jogs (``jogging.md``), ``$H`` homing, ``$$`` settings and ``$I`` build info.
Other G-code blocks are not emulated and answer ``error:20``.

Machine space is ``0 .. $130`` (homing at the negative end with the origin set
there). With homing enabled the controller starts in the Alarm state and asks
for ``$H``, as Grbl's homing lock does.
"""

from __future__ import annotations

import re
import time
from collections import deque
from dataclasses import dataclass

from sim.emulators.pty_device import PtyDevice

AXES = "XYZ"
_WORD = re.compile(r"([A-Z])([-+]?(?:\d+\.?\d*|\.\d+))")
_JOG_G_CODES = {20.0, 21.0, 53.0, 90.0, 91.0}


@dataclass
class _Motion:
    start: list[float]
    target: list[float]
    started: float
    duration: float
    homing: bool
    feed: float  # mm/min
    alarm_at_end: int | None = None


class GrblEmulator(PtyDevice):
    """A Grbl 1.1h board with ``max_travel_mm`` of travel on every axis.

    ``boot_s`` models a board that reboots when the port is opened: it ignores
    input for that long, then prints its banner. Tests inject ``error:N`` replies (:meth:`inject_error`), alarms
    (:meth:`inject_alarm`), a hard-limit switch that trips during the next move
    (:meth:`trip_hard_limit_at`) and a failing homing cycle (:meth:`fail_homing`).
    """

    def __init__(
        self,
        *,
        max_travel_mm: float = 400.0,
        max_rate_mm_min: float = 60_000.0,
        homing_enabled: bool = True,
        soft_limits: bool = True,
        start_mm: float | None = None,
        version: str = "1.1h",
        build_date: str = "20190830",
        info: str = "",
        boot_s: float = 0.0,
    ) -> None:
        super().__init__()
        self.boot_s = boot_s
        self.version = version
        self.build_date = build_date
        self.info = info
        self.settings: dict[int, float] = {
            0: 10, 1: 25, 10: 1, 13: 0, 20: int(soft_limits), 21: 1, 22: int(homing_enabled),
            25: max_rate_mm_min, 27: 1.0,
            110: max_rate_mm_min, 111: max_rate_mm_min, 112: max_rate_mm_min,
            130: max_travel_mm, 131: max_travel_mm, 132: max_travel_mm,
        }  # fmt: skip
        self.state = "Alarm" if homing_enabled else "Idle"
        self.lines: list[str] = []
        start = max_travel_mm / 2 if start_mm is None else start_mm
        self._position = [start, 0.0, 0.0]
        self._motion: _Motion | None = None
        self._awaiting_reset = False
        self._errors: deque[int] = deque()
        self._hard_limit_at: float | None = None
        self._homing_failure: int | None = None
        self._line = bytearray()
        self._booted_at = 0.0

    # -- fault injection ------------------------------------------------------------

    def inject_error(self, code: int) -> None:
        """Answer the next line with ``error:code`` instead of executing it."""
        with self.lock:
            self._errors.append(code)

    def inject_alarm(self, code: int) -> None:
        """Raise ``ALARM:code`` now: motion halts and G-code is locked out."""
        with self.lock:
            self._alarm(code, time.monotonic())

    def trip_hard_limit_at(self, at_mm: float) -> None:
        """Trip a limit switch (``ALARM:1``) when the next jog passes ``at_mm`` on X."""
        with self.lock:
            self._hard_limit_at = at_mm

    def fail_homing(self, code: int = 9) -> None:
        """Make the next ``$H`` fail with ``ALARM:code`` (8 pull-off failed, 9 switch not found)."""
        with self.lock:
            self._homing_failure = code

    @property
    def position_mm(self) -> float:
        """Current X machine position in mm."""
        with self.lock:
            return self._current(time.monotonic())[0]

    # -- protocol -------------------------------------------------------------------

    def on_start(self) -> None:
        self._booted_at = time.monotonic() + self.boot_s
        if not self.boot_s:
            self._banner()

    def handle_bytes(self, data: bytes) -> None:
        now = time.monotonic()
        if now < self._booted_at:
            return  # the boot loader runs after the port opened (Arduino auto-reset) and drops input
        for byte in data:
            if byte == 0x18:
                self._soft_reset(now)
            elif self._awaiting_reset:
                continue  # after a limit alarm only a reset is accepted ([MSG:Reset to continue])
            elif byte == ord("?"):
                if self.state != "Home":  # no status reports during a homing cycle
                    self._status(now)
            elif byte == ord("!"):
                if self.state == "Jog":  # a feed hold cancels a jog and returns to Idle
                    self._position = self._current(now)
                    self._motion = None
                    self.state = "Idle"
            elif byte in b"\r\n":
                line = self._line.decode("ascii", "replace").replace(" ", "").upper()
                self._line.clear()
                self.lines.append(line)
                self._execute(line, now)
            else:
                self._line.append(byte)

    def _execute(self, line: str, now: float) -> None:
        if self._errors:
            self._answer(f"error:{self._errors.popleft()}")
        elif line == "":
            self._answer("ok")
        elif line.startswith("$J="):
            self._jog(line[3:], now)
        elif line == "$H":
            self._home(now)
        elif line in ("$$", "$I"):
            if self.state not in ("Idle", "Alarm"):
                self._answer("error:8")
            elif line == "$$":
                self._answer(*(f"${key}={value:g}" for key, value in self.settings.items()), "ok")
            else:
                self._answer(f"[VER:{self.version}.{self.build_date}:{self.info}]", "[OPT:VZL,15,128]", "ok")
        elif line.startswith("$"):
            self._answer("error:3")
        elif self.state in ("Alarm", "Jog"):
            self._answer("error:9")
        else:
            self._answer("error:20")

    def _jog(self, block: str, now: float) -> None:
        if self.state not in ("Idle", "Jog"):
            self._answer("error:8")
            return
        words = _WORD.findall(block)
        if "".join(letter + value for letter, value in words) != block:
            self._answer("error:2")
            return
        targets: dict[int, float] = {}
        feed, scale, relative = None, 1.0, False
        for letter, value in words:
            number = float(value)
            if letter == "G" and number in _JOG_G_CODES:  # G53 (machine coordinates) changes nothing here
                if number in (20.0, 21.0):
                    scale = 25.4 if number == 20.0 else 1.0
                elif number in (90.0, 91.0):
                    relative = number == 91.0
            elif letter == "F":
                feed = number
            elif letter in AXES:
                targets[AXES.index(letter)] = number
            else:
                self._answer("error:16")
                return
        if feed is None:
            self._answer("error:22")
            return
        if not targets:
            self._answer("error:26")
            return
        start = self._current(now)
        target = list(start)
        for axis, value in targets.items():
            target[axis] = value * scale + (start[axis] if relative else 0.0)
        if self.settings[20] and any(not 0.0 <= target[axis] <= self.settings[130 + axis] for axis in targets):
            self._answer("error:15")
            return
        self._answer("ok")
        self._begin(start, target, now, feed * scale, homing=False)
        self.state = "Jog"

    def _home(self, now: float) -> None:
        if not self.settings[22]:
            self._answer("error:5")
        elif self.state not in ("Idle", "Alarm"):
            self._answer("error:8")
        elif self._homing_failure is not None:
            code, self._homing_failure = self._homing_failure, None
            self._alarm(code, now)
        else:
            self.state = "Home"
            self._begin(self._current(now), [0.0, 0.0, 0.0], now, self.settings[25], homing=True)

    def _begin(self, start: list[float], target: list[float], now: float, feed: float, *, homing: bool) -> None:
        feed = min(feed, self.settings[110])
        alarm = None
        limit = self._hard_limit_at
        if limit is not None and not homing and min(start[0], target[0]) <= limit <= max(start[0], target[0]):
            fraction = (limit - start[0]) / (target[0] - start[0]) if target[0] != start[0] else 0.0
            target = [s + fraction * (t - s) for s, t in zip(start, target, strict=True)]
            alarm, self._hard_limit_at = 1, None
        distance = sum((t - s) ** 2 for s, t in zip(start, target, strict=True)) ** 0.5
        self._motion = _Motion(start, target, now, distance / (feed / 60.0), homing, feed, alarm)

    def _current(self, now: float) -> list[float]:
        motion = self._motion
        if motion is None:
            return list(self._position)
        fraction = 1.0 if motion.duration <= 0 else min((now - motion.started) / motion.duration, 1.0)
        return [s + fraction * (t - s) for s, t in zip(motion.start, motion.target, strict=True)]

    def tick(self, now: float) -> None:
        if self.boot_s and now >= self._booted_at:
            self.boot_s = 0.0
            self._banner()
        motion = self._motion
        if motion is None or now - motion.started < motion.duration:
            return
        self._position = list(motion.target)
        self._motion = None
        if motion.alarm_at_end is not None:
            self._alarm(motion.alarm_at_end, now)
        else:
            self.state = "Idle"
            if motion.homing:
                self._answer("ok")

    def _alarm(self, code: int, now: float) -> None:
        self._position = self._current(now)
        self._motion = None
        self.state = "Alarm"
        self.push(f"ALARM:{code}\r\n".encode("ascii"))
        if code in (1, 2):  # limit alarms are critical: nothing but a reset is accepted
            self._awaiting_reset = True
            self.push(b"[MSG:Reset to continue]\r\n")

    def _soft_reset(self, now: float) -> None:
        if self._motion is not None:  # position is not guaranteed after a reset in motion
            self._alarm(6 if self.state == "Home" else 3, now)
        self._awaiting_reset = False
        self._line.clear()
        self._banner()

    def _banner(self) -> None:
        self.push(f"\r\nGrbl {self.version} ['$' for help]\r\n".encode("ascii"))
        if self.state == "Alarm":
            self.push(b"[MSG:'$H'|'$X' to unlock]\r\n")

    def _status(self, now: float) -> None:
        position = ",".join(f"{value:.3f}" for value in self._current(now))
        feed = self._motion.feed if self._motion is not None else 0.0
        self.reply(f"<{self.state}|MPos:{position}|FS:{feed:g},0>\r\n".encode("ascii"))

    def _answer(self, *lines: str) -> None:
        self.reply("".join(f"{line}\r\n" for line in lines).encode("ascii"))
