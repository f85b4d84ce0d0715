"""A linear stage on one axis of a Grbl 1.1 controller.

Protocol: Grbl v1.1 ``doc/markdown/interface.md`` (responses ``ok`` / ``error:N``, push
messages ``ALARM:N`` and ``[MSG:...]``, real-time status report ``?`` →
``<State|MPos:x,y,z|...>``), ``jogging.md`` (``$J=`` jog commands, cancelled by a feed
hold ``!``) and ``doc/csv/error_codes_en_US.csv`` / ``alarm_codes_en_US.csv``.

Moves are jogs in machine coordinates (``$J=G53 G90 G21 X.. F..``): Grbl answers a
target beyond its own soft limits with ``error:15`` instead of an alarm, and a jog
cancel (``0x85``) stops a jog cleanly without a reset. Lines end in LF only, because
Grbl ends a line at CR as well and would answer the empty line of a CR LF with a
second ``ok``.

Every session leaves the controller usable by the next one. A feed hold ``!`` sent
while Grbl is Idle puts it into ``Hold:0``, where it executes no line (the empty
sync line of the next connection would wait unanswered) until a resume ``~`` or a
reset; so :meth:`GrblStage.stop` cancels a jog with ``0x85``, holds other motion with
``!`` and, once the hold has brought the axes to rest (``Hold:0``), soft-resets
(``0x18``): Grbl 1.1 kills the steppers on a reset only while in motion (``ALARM:3``,
position likely lost); a reset from a completed hold keeps the position, flushes the
queued blocks and returns to Idle. :meth:`GrblStage.connect` asks for the state with
``?`` before anything else and brings a controller left in Hold, Door, Jog or Run to
Idle the same way; an Alarm is reported and unlocked (``$X``) only when the
``confirm_unlock`` callback says it is safe.
"""

from __future__ import annotations

import contextlib
import logging
import threading
import time
from collections.abc import Callable, Mapping
from typing import Any

from drivers.device import SerialDevice
from drivers.errors import DeviceError, LimitViolation, SerialGarbage, SerialTimeout
from drivers.protocols import DeviceIdentity

log = logging.getLogger(__name__)

ERROR_CODES: dict[int, str] = {
    1: "G-code words consist of a letter and a value. Letter was not found.",
    2: "Missing the expected G-code word value or numeric value format is not valid.",
    3: "Grbl '$' system command was not recognized or supported.",
    4: "Negative value received for an expected positive value.",
    5: "Homing cycle failure. Homing is not enabled via settings.",
    6: "Minimum step pulse time must be greater than 3usec.",
    7: "An EEPROM read failed. Auto-restoring affected EEPROM to default values.",
    8: "Grbl '$' command cannot be used unless Grbl is IDLE. Ensures smooth operation during a job.",
    9: "G-code commands are locked out during alarm or jog state.",
    10: "Soft limits cannot be enabled without homing also enabled.",
    11: "Max characters per line exceeded. Received command line was not executed.",
    12: "Grbl '$' setting value cause the step rate to exceed the maximum supported.",
    13: "Safety door detected as opened and door state initiated.",
    14: "Build info or startup line exceeded EEPROM line length limit. Line not stored.",
    15: "Jog target exceeds machine travel. Jog command has been ignored.",
    16: "Jog command has no '=' or contains prohibited g-code.",
    17: "Laser mode requires PWM output.",
    20: "Unsupported or invalid g-code command found in block.",
    21: "More than one g-code command from same modal group found in block.",
    22: "Feed rate has not yet been set or is undefined.",
    23: "G-code command in block requires an integer value.",
    24: "More than one g-code command that requires axis words found in block.",
    25: "Repeated g-code word found in block.",
    26: "No axis words found in block for g-code command or current modal state which requires them.",
    27: "Line number value is invalid.",
    28: "G-code command is missing a required value word.",
    29: "G59.x work coordinate systems are not supported.",
    30: "G53 only allowed with G0 and G1 motion modes.",
    31: "Axis words found in block when no command or current modal state uses them.",
    32: "G2 and G3 arcs require at least one in-plane axis word.",
    33: "Motion command target is invalid.",
    34: "Arc radius value is invalid.",
    35: "G2 and G3 arcs require at least one in-plane offset word.",
    36: "Unused value words found in block.",
    37: "G43.1 dynamic tool length offset is not assigned to configured tool length axis.",
    38: "Tool number greater than max supported value.",
}
"""``error:N`` meanings as documented (Grbl 1.1h, ``doc/csv/error_codes_en_US.csv``, "Error Description")."""

ALARM_CODES: dict[int, str] = {
    1: "Hard limit has been triggered. Machine position is likely lost due to sudden halt. "
    "Re-homing is highly recommended.",
    2: "Soft limit alarm. G-code motion target exceeds machine travel. Machine position retained. "
    "Alarm may be safely unlocked.",
    3: "Reset while in motion. Machine position is likely lost due to sudden halt. Re-homing is highly recommended.",
    4: "Probe fail. Probe is not in the expected initial state before starting probe cycle when G38.2 and G38.3 "
    "is not triggered and G38.4 and G38.5 is triggered.",
    5: "Probe fail. Probe did not contact the workpiece within the programmed travel for G38.2 and G38.4.",
    6: "Homing fail. The active homing cycle was reset.",
    7: "Homing fail. Safety door was opened during homing cycle.",
    8: "Homing fail. Pull off travel failed to clear limit switch. Try increasing pull-off setting or check wiring.",
    9: "Homing fail. Could not find limit switch within search distances. Try increasing max travel, decreasing "
    "pull-off distance, or check wiring.",
    10: "Homing fail. Second dual axis limit switch failed to trigger within configured search distance after "
    "first. Try increasing trigger fail distance or check wiring.",
}
"""``ALARM:N`` meanings as documented (Grbl 1.1h, ``doc/csv/alarm_codes_en_US.csv``, "Alarm Description")."""

CRITICAL_ALARMS = frozenset({1, 2})
"""Limit alarms after which Grbl accepts nothing but a soft reset ("[MSG:Reset to continue]")."""

AXES = "XYZABC"

STARTUP_S = 3.0
"""How long :meth:`GrblStage.connect` waits for a controller that reboots when the port opens."""

STOP_S = 30.0
"""Longest deceleration :meth:`GrblStage.stop` waits for (1000 mm/min at Grbl's default 10 mm/s²: 1.7 s)."""


class GrblError(DeviceError):
    """A line was answered with ``error:N``; Grbl did not execute it."""

    def __init__(self, device: str, command: str, code: int) -> None:
        self.code = code
        self.meaning = ERROR_CODES.get(code, "undocumented error code")
        super().__init__(device, f"'{command}' answered error:{code}: {self.meaning}")


class GrblAlarm(DeviceError):
    """Grbl is in the Alarm state (``code`` from ``ALARM:N``, None when only the state is known)."""

    def __init__(self, device: str, context: str, code: int | None) -> None:
        self.code = code
        self.meaning = (
            "motion locked until homing ($H) or unlock ($X) ([MSG:'$H'|'$X' to unlock])"
            if code is None
            else ALARM_CODES.get(code, "undocumented alarm code")
        )
        label = "alarm state" if code is None else f"ALARM:{code}"
        super().__init__(device, f"{context}: {label}: {self.meaning}")


class GrblStage(SerialDevice):
    """One axis (``axis``, e.g. ``"X"``) of a Grbl controller as a :class:`~drivers.protocols.LinearStage`.

    ``travel_mm`` are soft limits in machine coordinates, checked before every move;
    moves run at ``feed_mm_min``. Replies are awaited at most ``timeout_s``; homing
    may take ``home_timeout_s`` and a move ``move_timeout_s``. ``confirm_unlock`` is
    asked (with a description of the alarm) when :meth:`connect` finds Grbl in the
    Alarm state and no homing follows: True unlocks with ``$X``, False (and no callback)
    leaves the alarm in place, so moves are refused until :meth:`home`.
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
        confirm_unlock: Callable[[str], bool] | None = None,
    ) -> None:
        low, high = travel_mm
        if not low < high:
            raise ValueError(f"travel_mm must be (min, max) with min < max, got {travel_mm}")
        if axis.upper() not in AXES:
            raise ValueError(f"axis must be one of {', '.join(AXES)}, got {axis!r}")
        if feed_mm_min <= 0:
            raise ValueError(f"feed_mm_min must be positive, got {feed_mm_min}")
        self.travel_mm = (float(low), float(high))
        self.axis = axis.upper()
        self.feed_mm_min = feed_mm_min
        self.timeout_s = timeout_s
        self.home_timeout_s = home_timeout_s
        self.move_timeout_s = move_timeout_s
        self.poll_interval_s = poll_interval_s
        self.home_on_connect = home_on_connect
        self.confirm_unlock = confirm_unlock
        super().__init__(port, baud, f"Grbl stage ({self.axis} axis) on {port}", terminator=b"\n", timeout_s=timeout_s)
        self._lock = threading.RLock()
        self._grbl_settings: dict[str, str] = {}
        self._alarm: int | None = None
        self._reset_required = False

    # -- LinearStage ----------------------------------------------------------------

    def connect(self) -> None:
        """Open the port, learn the state (``?``) and bring Grbl to Idle (:meth:`stop`; a
        ``Door:0`` is reset, an open door refused), check the link with an empty line
        (``ok``), read build info (``$I``) and settings (``$$``) (interface.md, "Grbl
        Response Messages", "Real-time Status Reports", "Feedback Messages"). In the
        Alarm state it homes with ``home_on_connect``, else unlocks (``$X``) only if
        ``confirm_unlock`` agrees. With ``home_on_connect`` it runs the homing cycle.
        The identity's firmware is the build version from ``$I``, its serial the ``$I`` user
        string (Grbl has no serial number).
        """
        if self._line.is_open:
            return
        self._line.open()
        try:
            self._wake()
            self.stop()
            state = self._status()[0]
            if state == "Door:0":  # door closed again: a reset leaves the hold without resuming motion
                self._soft_reset()
                state = self._status()[0]
            if state.startswith("Door"):
                raise DeviceError(self.name, f"the safety door is open (state {state}): close it, then connect again")
            self._synchronise()
            info = self._command("$I")
            self._grbl_settings = dict(line.split("=", 1) for line in self._command("$$") if "=" in line)
            version = next((line[5:-1] for line in info if line.startswith("[VER:")), "")
            build, _, user_string = version.partition(":")
            self._identity = DeviceIdentity("grbl", "Grbl controller", user_string, build)
            if state == "Alarm" and not self.home_on_connect:
                self._offer_unlock()
            if self.home_on_connect:
                self.home()
        except Exception:
            self.close()
            raise

    def safe_state(self) -> None:
        """Stop motion and leave Grbl Idle for the next session (:meth:`stop`); never raises.

        If Grbl cannot be asked for its state (a dead link), it sends a jog cancel and
        a feed hold blind: stopping the axis matters more than the next session."""
        if not self._line.is_open:
            return
        try:
            self.stop()
        except Exception as exc:  # a dead or missing port must not stop the safe-state sweep
            log.warning("%s: safe state: %s", self.name, exc)
            with contextlib.suppress(Exception):
                self._line.write(b"\x85!", "jog cancel and feed hold")

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
        try:
            alarmed = self._reset_required or self._status()[0] == "Alarm"
        except GrblAlarm:  # an ALARM:N pushed just before the status report
            alarmed = True
        if alarmed:
            raise GrblAlarm(self.name, f"'{command}' not sent, nothing moved; home (or unlock) first", self._alarm)
        self._command(command)
        reached = self._wait_idle(command)
        if abs(reached - position_mm) > 0.002:
            raise DeviceError(self.name, f"'{command}' stopped at {reached:.3f} mm instead of {position_mm} mm")

    def position_mm(self) -> float:
        """Machine position of the axis in mm (interface.md, "Real-time Status reports": ``MPos``)."""
        return self._status()[1]

    def stop(self) -> None:
        """Stop motion and leave Grbl Idle (interface.md, "Real-time Commands"; jogging.md).

        A jog is cancelled with ``0x85`` and ends Idle by itself; a program (Run) gets a
        feed hold ``!``; once the hold has come to rest (``Hold:0``) a soft reset ``0x18``
        flushes the queue and returns to Idle with the position kept. An Idle or Alarm
        controller is left alone (no ``!``: a hold while Idle would block every later
        line). After a limit alarm, which has halted the machine, it soft-resets so that
        Grbl answers again. Raises DeviceError if motion does not stop within ``STOP_S``.
        """
        with self._lock:
            self._drain()
            if self._reset_required:  # halted by a limit alarm; Grbl answers nothing but a reset
                self._soft_reset()
                return
            state = self._status()[0]
            if state == "Jog":
                self._line.write(b"\x85", "jog cancel 0x85")
            elif state == "Run":
                self._line.write(b"!", "feed hold !")
            elif state == "Home":
                self._soft_reset()  # the only way to stop a homing cycle (ALARM:6)
                return
        deadline = time.monotonic() + STOP_S
        while state in ("Jog", "Run", "Hold:1"):
            if time.monotonic() > deadline:
                raise DeviceError(self.name, f"still moving ({state}) {STOP_S} s after the stop request")
            time.sleep(self.poll_interval_s)
            state = self._status_until(deadline)[0]
        if state == "Hold:0":  # at rest: a reset now keeps the position and leaves the hold
            self._soft_reset()

    # -- state recovery -------------------------------------------------------------

    def _wake(self) -> None:
        """Ask for the state until Grbl answers; a controller that stays silent gets a soft reset.

        A board that resets when the port opens (Arduino auto-reset) ignores input until its
        boot loader hands over (up to ``STARTUP_S``); Grbl halted by a limit alarm answers
        nothing, not even ``?``, until a reset (interface.md, "[MSG:Reset to continue]")."""
        deadline = time.monotonic() + max(STARTUP_S, self.timeout_s)
        while True:
            try:
                self._status()
                return
            except GrblAlarm:  # an ALARM:N pushed meanwhile; after a limit alarm stop() resets
                if self._reset_required:
                    return
            except SerialTimeout:
                if time.monotonic() >= deadline:
                    break
        log.warning("%s: no status report within %.1f s; sending a soft reset", self.name, STARTUP_S)
        try:
            self._soft_reset()
        except SerialTimeout as exc:
            raise DeviceError(
                self.name, f"no answer to '?' nor a banner after a soft reset: is a Grbl 1.1 controller at "
                f"{self.baud} baud on this port? ({exc})"
            ) from exc

    def _offer_unlock(self) -> None:
        """Report the alarm and unlock (``$X``) only if ``confirm_unlock`` says the axis may move."""
        alarm = GrblAlarm(self.name, "Grbl is in the Alarm state", self._alarm)
        log.warning("%s", alarm)
        if self.confirm_unlock is None or not self.confirm_unlock(
            f"{alarm}. Unlocking ($X) allows motion although the position may be lost; "
            "unlock only if the stage is clear and its position is trusted"
        ):
            return
        self._command("$X")
        self._alarm = None

    def _status_until(self, deadline: float) -> tuple[str, float]:
        """:meth:`_status`, asking again until ``deadline`` when a report does not come in
        time (grbl-sim skipped them for seconds near the end of a jog): a running motion is
        not abandoned for one missing report."""
        while True:
            try:
                return self._status()
            except SerialTimeout as exc:
                if time.monotonic() > deadline:
                    raise
                log.warning("%s: %s; asking again", self.name, exc)

    def _wait_idle(self, command: str) -> float:
        deadline = time.monotonic() + self.move_timeout_s
        while True:
            state, position = self._status_until(deadline)
            if state == "Idle":
                return position
            if state == "Alarm":
                raise GrblAlarm(self.name, f"'{command}' failed", self._alarm)
            if state not in ("Jog", "Run"):
                raise DeviceError(self.name, f"'{command}' interrupted: Grbl is in state {state}")
            if time.monotonic() > deadline:
                self.stop()
                raise DeviceError(self.name, f"'{command}' still moving after {self.move_timeout_s} s; stopped")
            time.sleep(self.poll_interval_s)

    def _synchronise(self) -> None:
        """An empty line answered ``ok``; a first ``error:N`` only ends a line a previous
        session left half-written, so one more empty line must then be answered ``ok``."""
        try:
            self._command("")
        except GrblError:
            self._command("")

    def _soft_reset(self) -> None:
        """Soft reset, Ctrl-X (interface.md: the welcome banner "also prints after a reset");
        an ``ALARM:N`` before the banner (``ALARM:3`` for a reset in motion) is recorded."""
        with self._lock:
            self._line.discard_input()
            self._line.write(b"\x18", "Ctrl-X")
            deadline = time.monotonic() + self.timeout_s
            while True:
                line = self._line.read_line("the 'Grbl X.Xx' banner after a reset", deadline)
                if line.startswith("ALARM:") and line[6:].isdigit():
                    self._alarm = int(line[6:])
                elif line.startswith("Grbl "):
                    break
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
        """Real-time status report ``?`` → (state with sub-state, e.g. ``Hold:0``, machine
        position of the axis in mm)."""
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
                    return fields[0], float(field[5:].split(",")[AXES.index(self.axis)])
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
