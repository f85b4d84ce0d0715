"""Zaber linear stage over the Zaber ASCII protocol (firmware 6.06 and later).

Protocol: Zaber ASCII Protocol Manual, "Message Format". A command is
``/device axis id command`` (LF); its reply ``@device axis id OK|RJ IDLE|BUSY flag data``
(CR LF). The message ID (0..99) ties a reply to its command, so a reply that
arrives after a timeout is recognised and dropped. ``flag`` is the active warning
flag of highest precedence (``--``: none); ``data`` of a rejected (``RJ``) command is
the reason. Positions are in microsteps; ``mm_per_microstep`` is the stage's
microstep size from its datasheet (manual, "Physical Units").
"""

from __future__ import annotations

import contextlib
import logging
import re
import threading
import time
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from drivers.device import SerialDevice
from drivers.errors import DeviceError, LimitViolation, SerialGarbage, SerialTimeout
from drivers.protocols import DeviceIdentity

log = logging.getLogger(__name__)

WARNING_FLAGS: dict[str, str] = {
    "FF": "critical system error",
    "FN": "peripheral not supported",
    "FZ": "peripheral inactive",
    "FH": "hardware emergency stop driver disabled",
    "FV": "overvoltage or undervoltage driver disabled",
    "FO": "driver disabled on startup or by command",
    "FC": "current inrush error",
    "FM": "motor temperature error",
    "FD": "driver disabled: the motor driver switched itself off (e.g. overheating)",
    "FQ": "encoder error: the encoder-measured position may be unreliable",
    "FI": "index error",
    "FA": "analog encoder sync error",
    "FR": "overdrive limit exceeded",
    "FS": "stalled and stopped: the axis detected a stall and stopped itself",
    "FB": "stream/PVT sequence bounds error: a streamed motion failed a precondition",
    "FP": "interpolated path deviation: streamed motion stopped because an axis slipped",
    "FE": "limit error: the limit sensor cannot be reached or is faulty",
    "FT": "excessive twist: a lockstep group twisted beyond its limit and stopped",
    "WL": "unexpected limit trigger: a move did not finish because a limit sensor triggered",
    "WV": "voltage out of range: the supply voltage is outside the recommended range",
    "WT": "controller temperature high: above the recommended limit",
    "WS": "stalled with recovery: the axis stalled and recovered",
    "WM": "displaced when stationary: the axis was pushed out of position while at rest",
    "WP": "invalid calibration type",
    "WR": "no reference position: the axis must be homed",
    "WH": "device not homed: the axis has a reference position but was not homed",
    "NC": "manual control: the axis is being moved with the knob or joystick",
    "NI": "movement interrupted: by another command, a stop or manual control",
    "ND": "stream/PVT sequence discontinuity: streamed motion ran out of queued moves",
    "NR": "value rounded",
    "NT": "value truncated",
    "NU": "setting update pending",
    "NJ": "joystick calibrating",
    "NB": "device in firmware update mode",
}
"""Warning flags (manual, "Warning Flags"): F* faults, W* warnings, N* notices. Each meaning
starts with the flag's name in the manual; the explanations after it cover the flags
this stage can raise."""

REJECTION_REASONS: dict[str, str] = {
    "AGAIN": "the device cannot process the command right now; send it again",
    "BADAXIS": "the axis number is greater than the number of axes available",
    "BADCOMMAND": "the command or setting is incorrect or invalid (or needs a firmware update)",
    "BADDATA": "the command's data is incorrect or out of range",
    "BADMESSAGEID": "the message ID is neither -- nor a number from 0 to 99",
    "BADSPLIT": "the command was split into packets the wrong way",
    "DEVICEONLY": "an axis number was given for a device-scope command",
    "DRIVERDISABLED": "a motor driver is disabled (over-temperature, over-voltage, over-current or by command)",
    "FULL": "the device cannot allocate more memory for what the command needs",
    "INACTIVE": "the axis is inactive",
    "LOCKSTEP": "the axis is in an enabled lockstep group",
    "NOACCESS": "the command or setting is not available at the current access level",
    "NOTSUPPORTED": "the connected peripheral is not supported by this firmware",
    "PARKED": "the device cannot move because it is parked",
    "REMOTE": "the device is in EtherCAT (remote) control mode",
    "STATUSBUSY": "the device is busy and cannot execute the command now",
    "SYSTEMERROR": "the command failed because of a system failure (review the errors)",
}
"""Reasons of an ``RJ`` reply (manual, "Replies": rejection reasons)."""

MOTION_FAILURES = frozenset({"WL", "WS", "WM", "WR", "WH"})
"""Warnings that mean a move did not end where it was sent, or may not have."""

MAXSPEED_PER_MICROSTEP_S = 1.6384
"""``maxspeed`` data per (microstep/s) (manual, "Physical Units": velocity)."""

_REPLY = re.compile(r"@(\d{2}) (\d+) (?:(\d{1,2}) )?(OK|RJ) (IDLE|BUSY) (--|[A-Z]{2}) ?(.*?)(?::([0-9A-Fa-f]{2}))?")


def checksum(body: str) -> str:
    """The ASCII checksum of a message ``body`` (the text after ``/`` or ``@``): the two's
    complement of its byte sum modulo 256 as two upper-case hex digits (manual, "Message
    Format": checksum), so that body bytes plus checksum sum to 0 modulo 256."""
    return f"{(256 - sum(body.encode('ascii')) % 256) % 256:02X}"


@dataclass(frozen=True)
class Reply:
    """A decoded ``@`` reply."""

    accepted: bool
    busy: bool
    flag: str
    data: str


class ZaberRejection(DeviceError):
    """The device answered ``RJ``: it did not execute the command."""

    def __init__(self, device: str, command: str, reason: str, flag: str) -> None:
        self.reason = reason
        self.meaning = REJECTION_REASONS.get(reason, "undocumented rejection reason")
        active = "" if flag == "--" else f" (active flag {flag}: {WARNING_FLAGS.get(flag, 'undocumented flag')})"
        super().__init__(device, f"rejected '{command}': {reason}: {self.meaning}{active}")


class ZaberFlagError(DeviceError):
    """A fault flag, or a warning flag that means motion failed, was raised."""

    def __init__(self, device: str, context: str, flag: str) -> None:
        self.flag = flag
        self.meaning = WARNING_FLAGS.get(flag, "undocumented flag")
        super().__init__(device, f"{context}: warning flag {flag}: {self.meaning}")


class ZaberStage(SerialDevice):
    """One axis of a Zaber device as a :class:`~drivers.protocols.LinearStage`.

    ``travel_mm`` are the soft limits checked before every move; ``mm_per_microstep``
    converts the device's microsteps to mm. Every reply is awaited at most
    ``timeout_s``; a move or homing cycle may take ``move_timeout_s``. Every command
    carries a message ID; with ``checksums`` it also carries a checksum (``:CC``).
    A reply's checksum is verified whenever the device sends one (setting
    ``comm.checksum`` 1), whatever ``checksums`` says.
    """

    def __init__(
        self,
        port: str,
        baud: int = 115200,
        *,
        travel_mm: tuple[float, float],
        mm_per_microstep: float,
        device: int = 1,
        axis: int = 1,
        timeout_s: float = 1.0,
        move_timeout_s: float = 120.0,
        poll_interval_s: float = 0.02,
        home_on_connect: bool = False,
        checksums: bool = False,
    ) -> None:
        low, high = travel_mm
        if not low < high:
            raise ValueError(f"travel_mm must be (min, max) with min < max, got {travel_mm}")
        if mm_per_microstep <= 0:
            raise ValueError(f"mm_per_microstep must be positive, got {mm_per_microstep}")
        self.travel_mm = (float(low), float(high))
        self.mm_per_microstep = mm_per_microstep
        self.device = device
        self.axis = axis
        self.timeout_s = timeout_s
        self.move_timeout_s = move_timeout_s
        self.poll_interval_s = poll_interval_s
        self.home_on_connect = home_on_connect
        self.checksums = checksums
        super().__init__(port, baud, f"Zaber stage {device}/{axis} on {port}", terminator=b"\r\n", timeout_s=timeout_s)
        self._lock = threading.RLock()
        self._message_id = 0
        self._device_settings: dict[str, Any] = {}

    # -- LinearStage ----------------------------------------------------------------

    def connect(self) -> None:
        """Open the port, read identity (device ID, serial number, firmware version) and travel
        range, and check ``travel_mm`` lies within it.

        Manual, "Command Reference": ``get deviceid``, ``get version``, ``get system.serial``,
        ``get limit.min``, ``get limit.max``, ``get maxspeed``. With ``home_on_connect`` it homes too.
        """
        if self._line.is_open:
            return
        self._line.open()
        try:
            self._read_device()
            if self.home_on_connect:
                self.home()
        except Exception:
            self.close()
            raise

    def safe_state(self) -> None:
        """Stop motion (``stop``); never raises."""
        with contextlib.suppress(Exception):  # a dead or missing port must not stop the safe-state sweep
            self.stop()

    def settings(self) -> Mapping[str, Any]:
        """Configuration and the device's own travel range and speed limit."""
        return {
            "port": self.port,
            "baud": self.baud,
            "device": self.device,
            "axis": self.axis,
            "checksums": self.checksums,
            "mm_per_microstep": self.mm_per_microstep,
            "travel_mm": list(self.travel_mm),
            **self._device_settings,
        }

    def home(self) -> None:
        """Home the axis and wait until it is idle with a reference position (manual, ``home``)."""
        self._clear_warnings("home", refuse=frozenset())
        self._send("home")
        self._wait_idle("home")
        self._check_after_motion("home")

    def move_to(self, position_mm: float) -> None:
        """Absolute move (manual, ``move abs``); returns when idle at the target.

        Raises :class:`~drivers.errors.LimitViolation` before any I/O if the target lies
        outside ``travel_mm``, and :class:`ZaberFlagError` without moving if a fault is
        active or the axis has no reference position.
        """
        low, high = self.travel_mm
        if not low <= position_mm <= high:
            raise LimitViolation(
                self.name, f"target {position_mm} mm lies outside the soft limits [{low}, {high}] mm; nothing moved"
            )
        target = round(position_mm / self.mm_per_microstep)
        command = f"move abs {target}"
        self._clear_warnings(command, refuse=frozenset({"WR", "WH"}))
        self._send(command)
        reached = self._wait_idle(command)
        self._check_after_motion(command)
        if abs(reached - target) > 1:
            raise DeviceError(
                self.name,
                f"'{command}' stopped at {reached * self.mm_per_microstep:.4f} mm instead of {position_mm} mm",
            )

    def position_mm(self) -> float:
        """Current position in mm (manual, ``get pos``)."""
        return self._integer("get pos") * self.mm_per_microstep

    def stop(self) -> None:
        """Decelerate to a stop and wait until idle (manual, ``stop``)."""
        self._send("stop", check_faults=False)
        self._wait_idle("stop", check_faults=False)

    # -- motion helpers -------------------------------------------------------------

    def _first_answer(self) -> str:
        """``get deviceid``, the first request: silence or a foreign reply here means no Zaber controller
        listens on this port with these settings."""
        hint = (f"is a Zaber controller (ASCII protocol, device {self.device}) powered and wired to this port at "
                f"{self.baud} baud?")
        try:
            return self._send("get deviceid", axis=0).data
        except SerialTimeout as exc:
            raise SerialTimeout(self.name, f"{exc.message}: {hint}") from exc
        except SerialGarbage as exc:
            raise SerialGarbage(self.name, f"{exc.message}: {hint}") from exc

    def _read_device(self) -> None:
        device_id = self._first_answer()
        version = self._send("get version", axis=0).data
        try:
            serial_number = self._send("get system.serial", axis=0).data
        except ZaberRejection:  # a firmware without this setting rejects it
            serial_number = ""
        limit_min = self._integer("get limit.min") * self.mm_per_microstep
        limit_max = self._integer("get limit.max") * self.mm_per_microstep
        maxspeed = self._integer("get maxspeed")
        low, high = self.travel_mm
        if low < limit_min - self.mm_per_microstep or high > limit_max + self.mm_per_microstep:
            raise DeviceError(
                self.name,
                f"configured travel [{low}, {high}] mm exceeds the device range [{limit_min}, {limit_max}] mm "
                f"(limit.min/limit.max at {self.mm_per_microstep} mm per microstep)",
            )
        self._identity = DeviceIdentity("zaber", f"Zaber device ID {device_id}", serial_number, version)
        self._device_settings = {
            "device_range_mm": [limit_min, limit_max],
            "max_speed_mm_s": maxspeed / MAXSPEED_PER_MICROSTEP_S * self.mm_per_microstep,
        }

    def _clear_warnings(self, context: str, *, refuse: frozenset[str]) -> None:
        """Read and clear the warning flags (manual, ``warnings clear``); refuse to move on a
        fault or on a flag in ``refuse``, log left-over warnings."""
        flags = self._send("warnings clear", check_faults=False).data.split()[1:]
        for flag in flags:
            if flag.startswith("F") or flag in refuse:
                raise ZaberFlagError(self.name, f"'{context}' not sent, nothing moved", flag)
        for flag in flags:
            if flag.startswith("W") and flag not in ("WR", "WH"):
                log.warning("%s: cleared %s (%s) before '%s'", self.name, flag, WARNING_FLAGS.get(flag, "?"), context)

    def _check_after_motion(self, context: str) -> None:
        flags = self._send("warnings", check_faults=False).data.split()[1:]
        for flag in flags:
            if flag.startswith("F") or flag in MOTION_FAILURES:
                raise ZaberFlagError(self.name, f"'{context}' failed", flag)
        for flag in flags:
            if flag.startswith("W"):
                log.warning("%s: after '%s': %s: %s", self.name, context, flag, WARNING_FLAGS.get(flag, "?"))

    def _wait_idle(self, context: str, *, check_faults: bool = True) -> int:
        """Poll ``get pos`` until the axis is idle; return the position in microsteps."""
        deadline = time.monotonic() + self.move_timeout_s
        while True:
            reply = self._send("get pos", check_faults=False)
            if check_faults and reply.flag.startswith("F"):
                raise ZaberFlagError(self.name, f"'{context}' failed", reply.flag)
            if not reply.busy:
                return self._integer("get pos", reply)
            if time.monotonic() > deadline:
                self._send("stop", check_faults=False)
                raise DeviceError(self.name, f"'{context}' still moving after {self.move_timeout_s} s; sent stop")
            time.sleep(self.poll_interval_s)

    # -- serial exchange ----------------------------------------------------------------

    def _integer(self, command: str, reply: Reply | None = None) -> int:
        """The integer data of ``reply`` (sent now if None) to ``command``."""
        reply = self._send(command) if reply is None else reply
        try:
            return int(reply.data)
        except ValueError as exc:
            raise SerialGarbage(self.name, f"reply data {reply.data!r} to '{command}' is not an integer") from exc

    def _send(self, command: str, *, axis: int | None = None, check_faults: bool = True) -> Reply:
        """Send one command and return its reply; ``RJ`` raises :class:`ZaberRejection`,
        an active fault flag :class:`ZaberFlagError` (unless ``check_faults`` is False)."""
        axis = self.axis if axis is None else axis
        with self._lock:
            self._message_id = (self._message_id + 1) % 100
            message_id = self._message_id
            self._line.discard_input()  # late replies to earlier commands
            body = f"{self.device} {axis} {message_id:02d} {command}"
            if self.checksums:
                body += f":{checksum(body)}"
            self._line.write(f"/{body}\n".encode("ascii"), command)
            reply = self._read_reply(command, axis, message_id)
        if not reply.accepted:
            raise ZaberRejection(self.name, command, reply.data, reply.flag)
        if check_faults and reply.flag.startswith("F"):
            raise ZaberFlagError(self.name, f"during '{command}'", reply.flag)
        return reply

    def _read_reply(self, command: str, axis: int, message_id: int) -> Reply:
        expected = f"'@{self.device:02d} {axis} {message_id:02d} ...' in reply to '{command}'"
        deadline = time.monotonic() + self.timeout_s
        while True:
            line = self._line.read_line(expected, deadline)
            if line[:1] in ("#", "!"):  # info and alert messages are not replies
                continue
            match = _REPLY.fullmatch(line)
            if match is None:
                raise SerialGarbage(self.name, f"reply {line!r} is not a Zaber ASCII reply (expected {expected})")
            device, reply_axis, reply_id, flag, status, warning, data, check = match.groups()
            if check is not None and check.upper() != checksum(line[1 : line.rindex(":")]):
                raise SerialGarbage(self.name, f"reply {line!r} fails its checksum (expected {expected})")
            if (int(device), int(reply_axis)) != (self.device, axis) or reply_id is None or int(reply_id) != message_id:
                continue  # a late reply to an earlier command
            return Reply(flag == "OK", status == "BUSY", warning, data)
