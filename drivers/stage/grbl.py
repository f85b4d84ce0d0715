"""A linear stage on one axis of a Grbl 1.1 controller.

Protocol: Grbl v1.1 ``doc/markdown/interface.md`` (responses ``ok`` / ``error:N``, push
messages ``ALARM:N`` and ``[MSG:...]``, real-time status report ``?`` →
``<State|MPos:x,y,z|...>``), ``jogging.md`` (``$J=`` jog commands, cancelled by a feed
hold ``!``) and ``doc/csv/error_codes_en_US.csv`` / ``alarm_codes_en_US.csv``.

Moves are jogs in machine coordinates (``$J=G53 G90 G21 X.. F..``): Grbl answers a
target beyond its own soft limits with ``error:15`` instead of an alarm, and a feed
hold stops a jog cleanly without a reset. Lines end in LF only, because Grbl ends a
line at CR as well and would answer the empty line of a CR LF with a second ``ok``.
"""

from __future__ import annotations

import contextlib
import logging
import threading
import time
from collections.abc import Mapping
from types import TracebackType
from typing import Any

from drivers.errors import DeviceError, LimitViolation, SerialGarbage, SerialTimeout
from drivers.protocols import DeviceIdentity
from drivers.serial_line import SerialLine

log = logging.getLogger(__name__)

ERROR_CODES: dict[int, str] = {
    1: "expected a G-code command letter",
    2: "bad or missing number format",
    3: "'$' system command not recognised or supported",
    4: "negative value for an expected positive value",
    5: "homing cycle is not enabled in the settings ($22)",
    6: "minimum step pulse time must be greater than 3 µs",
    7: "EEPROM read failed; affected settings were restored to defaults",
    8: "'$' command only possible while Grbl is idle",
    9: "G-code is locked out during an alarm or jog",
    10: "soft limits cannot be enabled without homing",
    11: "line too long: not executed",
    12: "setting would exceed the maximum step rate",
    13: "safety door opened",
    14: "build info or startup line too long for the EEPROM",
    15: "jog target exceeds the machine travel ($130..): jog ignored",
    16: "jog command without '=' or with forbidden G-code",
    17: "laser mode requires PWM output",
    20: "unsupported or invalid G-code command",
    21: "more than one G-code command of the same modal group",
    22: "feed rate not set",
    23: "G-code command needs an integer value",
    24: "more than one G-code command needing axis words",
    25: "repeated G-code word",
    26: "no axis words for a command that needs them",
    27: "invalid line number",
    28: "G-code command is missing a required value word",
    29: "G59.x work coordinate systems are not supported",
    30: "G53 only allowed with G0 and G1 motion",
    31: "axis words in a block that does not use them",
    32: "G2/G3 arc needs at least one in-plane axis word",
    33: "invalid motion target",
    34: "invalid arc radius",
    35: "G2/G3 arc needs at least one in-plane offset word",
    36: "unused value words in the block",
    37: "G43.1 tool length offset not on the configured tool-length axis",
    38: "tool number above the supported maximum",
}
"""``error:N`` meanings (Grbl 1.1, ``doc/csv/error_codes_en_US.csv``)."""

ALARM_CODES: dict[int, str] = {
    1: "hard limit triggered: machine position is likely lost, re-homing needed",
    2: "soft limit: motion target exceeds machine travel (position retained)",
    3: "reset while in motion: position is likely lost, re-homing needed",
    4: "probe fail: probe not in the expected initial state",
    5: "probe fail: probe did not contact within the programmed travel",
    6: "homing fail: the homing cycle was reset",
    7: "homing fail: safety door opened during homing",
    8: "homing fail: pull-off did not clear the limit switch",
    9: "homing fail: limit switch not found within the search distance",
    10: "homing fail: second switch of a dual axis not found",
}
"""``ALARM:N`` meanings (Grbl 1.1, ``doc/csv/alarm_codes_en_US.csv``, which lists 1-9; later 1.1
builds add 10 for dual-axis homing)."""

CRITICAL_ALARMS = frozenset({1, 2})
"""Limit alarms after which Grbl accepts nothing but a soft reset ("[MSG:Reset to continue]")."""

AXES = "XYZABC"

STARTUP_S = 3.0
"""How long :meth:`GrblStage.connect` waits for a controller that reboots when the port opens."""


class GrblError(DeviceError):
    """A line was answered with ``error:N``; Grbl did not execute it."""

    def __init__(self, device: str, command: str, code: int) -> None:
        self.code = code
        self.meaning = ERROR_CODES.get(code, "undocumented error code")
        super().__init__(device, f"'{command}' answered error:{code}: {self.meaning}")


class GrblAlarm(DeviceError):
    """Grbl is in the Alarm state (``code`` from ``ALARM:N``, None for the start-up homing lock)."""

    def __init__(self, device: str, context: str, code: int | None) -> None:
        self.code = code
        self.meaning = (
            "homing required after power-up or reset ([MSG:'$H'|'$X' to unlock])"
            if code is None
            else ALARM_CODES.get(code, "undocumented alarm code")
        )
        label = "alarm state" if code is None else f"ALARM:{code}"
        super().__init__(device, f"{context}: {label}: {self.meaning}")


class GrblStage:
    """One axis (``axis``, e.g. ``"X"``) of a Grbl controller as a :class:`~drivers.protocols.LinearStage`.

    ``travel_mm`` are soft limits in machine coordinates, checked before every move;
    moves run at ``feed_mm_min``. Replies are awaited at most ``timeout_s``; homing
    may take ``home_timeout_s`` and a move ``move_timeout_s``.
    """

    def __init__(
        self,
        port: str,
        baud: int = 115200,
        *,
        travel_mm: tuple[float, float],
        axis: str = "X",
        feed_mm_min: float = 1000.0,
        timeout_s: float = 1.0,
        home_timeout_s: float = 120.0,
        move_timeout_s: float = 120.0,
        poll_interval_s: float = 0.02,
        home_on_connect: bool = False,
    ) -> None:
        low, high = travel_mm
        if not low < high:
            raise ValueError(f"travel_mm must be (min, max) with min < max, got {travel_mm}")
        if axis.upper() not in AXES:
            raise ValueError(f"axis must be one of {', '.join(AXES)}, got {axis!r}")
        if feed_mm_min <= 0:
            raise ValueError(f"feed_mm_min must be positive, got {feed_mm_min}")
        self.port = port
        self.baud = baud
        self.travel_mm = (float(low), float(high))
        self.axis = axis.upper()
        self.feed_mm_min = feed_mm_min
        self.timeout_s = timeout_s
        self.home_timeout_s = home_timeout_s
        self.move_timeout_s = move_timeout_s
        self.poll_interval_s = poll_interval_s
        self.home_on_connect = home_on_connect
        self.name = f"Grbl stage ({self.axis} axis) on {port}"
        self._line = SerialLine(self.name, port, baud, terminator=b"\n", timeout_s=timeout_s)
        self._lock = threading.RLock()
        self._identity: DeviceIdentity | None = None
        self._grbl_settings: dict[str, str] = {}
        self._alarm: int | None = None
        self._reset_required = False

    # -- LinearStage ----------------------------------------------------------------

    def connect(self) -> None:
        """Open the port, check the link with an empty line (``ok``), read build info (``$I``)
        and settings (``$$``) (interface.md, "Grbl Response Messages", "Feedback Messages").
        With ``home_on_connect`` it runs the homing cycle too."""
        if self._line.is_open:
            return
        self._line.open()
        try:
            self._synchronise()
            info = self._command("$I")
            self._grbl_settings = dict(line.split("=", 1) for line in self._command("$$") if "=" in line)
            version = next((line[5:-1] for line in info if line.startswith("[VER:")), "")
            build, _, user_string = version.partition(":")
            self._identity = DeviceIdentity("grbl", "Grbl controller", user_string, build)
            if self.home_on_connect:
                self.home()
        except Exception:
            self.close()
            raise

    def close(self) -> None:
        """Close the port (idempotent)."""
        self._line.close()

    def safe_state(self) -> None:
        """Stop motion with a feed hold (``!``); never raises."""
        with contextlib.suppress(Exception):  # a dead or missing port must not stop the safe-state sweep
            self.stop()

    def identity(self) -> DeviceIdentity:
        """Build version from ``$I``; the serial is the ``$I`` user string (Grbl has no serial number)."""
        if self._identity is None:
            raise DeviceError(self.name, "not connected: call connect() first")
        return self._identity

    def settings(self) -> Mapping[str, Any]:
        """Configuration plus Grbl's ``$$`` settings as read at :meth:`connect`."""
        return {
            "port": self.port,
            "baud": self.baud,
            "axis": self.axis,
            "feed_mm_min": self.feed_mm_min,
            "travel_mm": list(self.travel_mm),
            "grbl": dict(self._grbl_settings),
        }

    def home(self) -> None:
        """Run the homing cycle (``$H``) and wait for its ``ok``.

        After a limit alarm Grbl accepts nothing until a soft reset (interface.md,
        "[MSG:Reset to continue]"); the machine has halted then, so this sends Ctrl-X first.
        """
        if self._reset_required:
            self._soft_reset()
        self._command("$H", timeout_s=self.home_timeout_s)
        self._alarm = None

    def move_to(self, position_mm: float) -> None:
        """Jog to an absolute machine position (jogging.md, ``$J=G53 G90 G21``) and wait until
        Grbl reports Idle there.

        Raises :class:`~drivers.errors.LimitViolation` before any I/O if the target lies
        outside ``travel_mm``, and :class:`GrblAlarm` without moving in the Alarm state.
        """
        low, high = self.travel_mm
        if not low <= position_mm <= high:
            raise LimitViolation(
                self.name, f"target {position_mm} mm lies outside the soft limits [{low}, {high}] mm; nothing moved"
            )
        command = f"$J=G53G90G21{self.axis}{position_mm:.3f}F{self.feed_mm_min:g}"
        with self._lock:
            self._drain()  # learn of alarms pushed since the last exchange
        if self._reset_required or self._status()[0] == "Alarm":
            raise GrblAlarm(self.name, f"'{command}' not sent, nothing moved; home first", self._alarm)
        self._command(command)
        reached = self._wait_idle(command)
        if abs(reached - position_mm) > 0.002:
            raise DeviceError(self.name, f"'{command}' stopped at {reached:.3f} mm instead of {position_mm} mm")

    def position_mm(self) -> float:
        """Machine position of the axis in mm (interface.md, "Real-time Status reports": ``MPos``)."""
        return self._status()[1]

    def stop(self) -> None:
        """Feed hold (``!``; jogging.md: a feed hold cancels jogs); waits until motion has stopped."""
        with self._lock:
            self._drain()
            self._line.write(b"!", "!")
        if self._reset_required:  # halted by a limit alarm; status reports resume only after a reset
            return
        deadline = time.monotonic() + self.move_timeout_s
        while self._status()[0] in ("Jog", "Run"):
            if time.monotonic() > deadline:
                raise DeviceError(self.name, f"still moving {self.move_timeout_s} s after a feed hold")
            time.sleep(self.poll_interval_s)

    def __enter__(self) -> GrblStage:
        self.connect()
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.safe_state()
        self.close()

    # -- motion helpers -------------------------------------------------------------

    def _wait_idle(self, command: str) -> float:
        deadline = time.monotonic() + self.move_timeout_s
        while True:
            state, position = self._status()
            if state == "Idle":
                return position
            if state == "Alarm":
                raise GrblAlarm(self.name, f"'{command}' failed", self._alarm)
            if state not in ("Jog", "Run"):
                raise DeviceError(self.name, f"'{command}' interrupted: Grbl is in state {state}")
            if time.monotonic() > deadline:
                self.stop()
                raise DeviceError(self.name, f"'{command}' still moving after {self.move_timeout_s} s; feed hold sent")
            time.sleep(self.poll_interval_s)

    def _synchronise(self) -> None:
        """Send empty lines until one is answered ``ok``: a board that resets when the port
        opens (Arduino auto-reset) ignores input until its boot loader hands over to Grbl."""
        deadline = time.monotonic() + max(STARTUP_S, self.timeout_s)
        while True:
            try:
                self._command("", timeout_s=min(self.timeout_s, max(deadline - time.monotonic(), 0.0)))
                return
            except SerialTimeout:
                if time.monotonic() >= deadline:
                    raise

    def _soft_reset(self) -> None:
        """Soft reset, Ctrl-X (interface.md: the welcome banner "also prints after a reset")."""
        with self._lock:
            self._line.write(b"\x18", "Ctrl-X")
            deadline = time.monotonic() + self.timeout_s
            while not self._read_line(deadline, "the 'Grbl X.Xx' banner after a reset").startswith("Grbl "):
                pass
            self._reset_required = False

    # -- serial exchange ----------------------------------------------------------------

    def _command(self, line: str, timeout_s: float | None = None) -> list[str]:
        """Send a line; return the lines before its ``ok``. ``error:N`` raises :class:`GrblError`."""
        with self._lock:
            self._drain()
            self._line.write(line.encode("ascii") + b"\n", line)
            deadline = time.monotonic() + (self.timeout_s if timeout_s is None else timeout_s)
            collected: list[str] = []
            while True:
                reply = self._read_line(deadline, f"'ok' for '{line}'")
                if reply == "ok":
                    return collected
                if reply.startswith("error:") and reply[6:].isdigit():
                    raise GrblError(self.name, line, int(reply[6:]))
                if self._is_push(reply) or reply.startswith("<"):  # a status report answers no line
                    continue
                if not reply.startswith(("$", "[")):
                    raise SerialGarbage(self.name, f"unexpected reply {reply!r} to '{line}'")
                collected.append(reply)

    def _status(self) -> tuple[str, float]:
        """Real-time status report ``?`` → (state, machine position of the axis in mm)."""
        with self._lock:
            self._drain()
            if self._reset_required:
                raise GrblAlarm(self.name, "no status report until a soft reset", self._alarm)
            self._line.write(b"?", "?")
            deadline = time.monotonic() + self.timeout_s
            while True:
                reply = self._read_line(deadline, "a status report '<State|MPos:...>' for '?'")
                if reply.startswith("<") and reply.endswith(">"):
                    break
                late = reply == "ok" or reply.startswith("error:")  # answers to earlier lines
                if not (late or self._is_push(reply)):
                    raise SerialGarbage(self.name, f"unexpected reply {reply!r} to '?'")
        fields = reply[1:-1].split("|")
        for field in fields[1:]:
            if field.startswith("MPos:"):
                try:
                    return fields[0].split(":")[0], float(field[5:].split(",")[AXES.index(self.axis)])
                except (ValueError, IndexError) as exc:
                    raise SerialGarbage(self.name, f"status report {reply!r} has no {self.axis} position") from exc
        raise DeviceError(self.name, f"status report {reply!r} has no MPos field: set $10=1 to report machine position")

    def _drain(self) -> None:
        """Drop late answers to earlier lines, but keep the alarm state from ``ALARM:N`` among them."""
        for line in self._line.discard_input().decode("ascii", "replace").splitlines():
            if line.startswith("ALARM:") and line[6:].isdigit():
                self._record_alarm(int(line[6:]))

    def _record_alarm(self, code: int) -> None:
        self._alarm = code
        self._reset_required = self._reset_required or code in CRITICAL_ALARMS

    def _is_push(self, line: str) -> bool:
        """Log and recognise feedback messages, the welcome banner and startup-line reports."""
        if line.startswith(("[MSG:", "Grbl ", ">")):
            log.info("%s: %s", self.name, line)
            return True
        return False

    def _read_line(self, deadline: float, expected: str) -> str:
        """Next non-empty line; ``ALARM:N`` raises :class:`GrblAlarm`."""
        while True:
            line = self._line.read_line(expected, deadline)
            if line.startswith("ALARM:") and line[6:].isdigit():
                self._record_alarm(int(line[6:]))
                raise GrblAlarm(self.name, f"while waiting for {expected}", self._alarm)
            if line:
                return line
