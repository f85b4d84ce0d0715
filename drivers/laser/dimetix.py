"""Dimetix laser distance sensor over a serial port (ASCII command set).

Protocol: Dimetix Technical Reference Manual, chapter "Command set" (DLS-C/FLS-C
§9, D-series DAN/DPE/DAE §6). Commands are ``sN<cmd>`` and replies ``gN<...>``, both
terminated by CR LF, with N the device ID (0..9) set on the ID switch. Distances
are in 0.1 mm. A failed command answers ``gN@Ezzz`` (manual, "Error codes").
The sensor ships with 19200 baud, 7 data bits, even parity, 1 stop bit.
"""

from __future__ import annotations

import contextlib
import logging
import re
import threading
import time
from collections.abc import Mapping
from typing import Any

from drivers.device import SerialDevice
from drivers.errors import DeviceError, SerialGarbage, SerialTimeout, TransientDeviceError
from drivers.protocols import DeviceIdentity

log = logging.getLogger(__name__)

#: the DAN-10-150's stated accuracy (+-1 mm), a bound on its error at any distance
ACCURACY_MM = 1.0
#: the DAN-10-150's stated repeatability (0.3 mm), at 2 sigma
REPEATABILITY_2SIGMA_MM = 0.3

_START_SEQUENCE = re.compile(r"g\d\?")
_ANY_SENSOR = re.compile(r"g\d")


def _stray(line: str, prefix: str, expect: str) -> bool:
    """True for a line that answers no request of ours: a start sequence when ``?`` is not
    the awaited reply, or a line of a sensor whose device ID is not in ``prefix``."""
    if expect != "?" and _START_SEQUENCE.fullmatch(line):
        return True
    return _ANY_SENSOR.match(line) is not None and not line.startswith(prefix)

UNKNOWN = "unknown"
"""Serial number or software version of a sensor that does not tell them."""

ERROR_CODES: dict[int, str] = {
    203: "wrong command syntax, forbidden parameter or invalid result",
    210: "not in tracking mode: start tracking first",
    211: "sampling too fast: choose a longer sampling time",
    212: "command not possible while tracking: stop tracking with sNc first",
    220: "serial communication error: check the interface settings",
    230: "distance overflow caused by the user offset/gain configuration",
    231: "wrong mode to read the digital input status",
    232: "digital output 1 cannot be set while it is configured as an input",
    233: "number cannot be displayed: check the output format",
    234: "distance out of range",
    236: "digital output manual mode not possible while configured as an input",
    252: "temperature too high",
    253: "temperature too low",
    254: "bad signal from the target: measuring takes too long",
    255: "received signal too weak (or target lost): use a better target or distance",
    256: "received signal too strong: use a less reflective target or longer distance",
    258: "supply voltage too high",
    259: "supply voltage too low",
    260: "distance cannot be calculated: ambiguous targets",
    263: "too much light (or distance jump in moving-target mode)",
    264: "too much light: measuring on reflective targets not possible",
    330: "target acceleration too strong or distance jump (moving-target mode)",
    331: "over speed of the target: it moves too fast",
    360: "configured measuring time too short",
    361: "configured measuring time too long",
}
"""Meaning of each ``@Ezzz`` code (manual, "Error codes"; DLS-C/FLS-C chapter 9, D-series section 6.6)."""

TARGET_ERROR_CODES = frozenset({254, 255, 256, 260, 263, 264, 330, 331})
"""Codes caused by the target or beam path at that moment (a person crossing the beam,
a reflection): a later measurement may succeed, so they are transient."""


class DimetixError(DeviceError):
    """The sensor answered ``gN@Ezzz``; ``code`` and ``meaning`` tell why."""

    def __init__(self, device: str, command: str, code: int) -> None:
        self.code = code
        self.meaning = ERROR_CODES.get(code, "undocumented error code")
        super().__init__(device, f"'{command}' failed with error E{code}: {self.meaning}")


class DimetixTargetError(DimetixError, TransientDeviceError):
    """An error code caused by the target or beam path; worth retrying."""


def _error(device: str, command: str, code: int) -> DimetixError:
    cls = DimetixTargetError if code in TARGET_ERROR_CODES else DimetixError
    return cls(device, command, code)


class DimetixLaser(SerialDevice):
    """A Dimetix DLS/FLS/D-series sensor as a :class:`~drivers.protocols.RangeMeter`.

    ``timeout_s`` bounds every reply; measuring a poor target can take seconds,
    so keep it well above the sensor's measuring time. Use as a context manager
    (connect on entry, safe state and close on exit) or call :meth:`connect`.
    """

    def __init__(
        self,
        port: str,
        baud: int = 19200,
        *,
        device_id: int = 0,
        bytesize: int = 7,
        parity: str = "E",
        stopbits: int = 1,
        timeout_s: float = 3.0,
    ) -> None:
        if not 0 <= device_id <= 9:
            raise ValueError(f"Dimetix device ID must be 0..9, got {device_id}")
        self.device_id = device_id
        self.bytesize = bytesize
        self.parity = parity
        self.stopbits = stopbits
        self.timeout_s = timeout_s
        super().__init__(
            port,
            baud,
            f"Dimetix laser on {port}",
            terminator=b"\r\n",
            timeout_s=timeout_s,
            bytesize=bytesize,
            parity=parity,
            stopbits=stopbits,
        )
        self._lock = threading.RLock()  # safe_state() may come from another thread

    # -- RangeMeter -----------------------------------------------------------------

    def connect(self) -> None:
        """Open the port, stop anything running (``sNc``) and read serial number and version.

        Manual: "STOP/CLEAR command (sNc)", "Get serial number (sNsn)",
        "Get software version (sNsv)". The identity queries are optional: a sensor that
        answers them with an error code (``gN@Ezzz``, e.g. E203 on a firmware without
        them) is identified as ``"unknown"`` with a logged warning; it still measures.
        A sensor that does not answer at all is refused.
        """
        if self._line.is_open:
            return
        self._line.open()
        try:
            self._first_answer()
            serial_number = self._optional_identity("sn", "serial number")
            version = self._optional_identity("sv", "software version")
        except Exception:
            self.close()
            raise
        self._identity = DeviceIdentity(
            backend="dimetix",
            model="Dimetix laser distance sensor",
            serial=serial_number,
            firmware=version,
        )

    def _first_answer(self) -> None:
        """``sNc``, the first request: silence here means no sensor listens on these line settings."""
        try:
            self._request("c", "?")
        except SerialTimeout as exc:
            raise SerialTimeout(
                self.name, f"{exc.message}: is the sensor powered and wired to this port, set to {self.baud} baud "
                f"{self.bytesize}{self.parity}{self.stopbits} and device ID {self.device_id}?"
            ) from exc

    def _optional_identity(self, command: str, what: str) -> str:
        """The answer to identity query ``sN<command>``, or :data:`UNKNOWN` if the sensor rejects it."""
        try:
            return self._request(command, f"{command}+")
        except DimetixError as error:
            log.warning(
                "%s: %s %s: '%s' answered E%d (%s)",
                self.name, what, UNKNOWN, self._describe(command).strip("'"), error.code, error.meaning,
            )  # fmt: skip
            return UNKNOWN

    def safe_state(self) -> None:
        """Stop tracking (``sNc``) and switch the laser off (``sNp``); never raises.

        Manual: "STOP/CLEAR command (sNc)", "Laser OFF (sNp)".
        """
        for command in ("c", "p"):
            with contextlib.suppress(Exception):  # a dead or missing port must not stop the safe-state sweep
                self._request(command, "?")

    def settings(self) -> Mapping[str, Any]:
        """Serial line settings and device ID."""
        return {
            "port": self.port,
            "baud": self.baud,
            "format": f"{self.bytesize}{self.parity}{self.stopbits}",
            "device_id": self.device_id,
            "timeout_s": self.timeout_s,
        }

    def measure_mm(self) -> float:
        """One distance measurement in mm (manual, "Distance measurement (sNg)": ``gNg+xxxxxxxx`` in 0.1 mm)."""
        return self._distance(self._request("g", "g"), "g")

    # -- further commands -------------------------------------------------------------

    def laser_on(self) -> None:
        """Switch the laser beam on, e.g. for aiming (manual, "Laser ON (sNo)")."""
        self._request("o", "?")

    def laser_off(self) -> None:
        """Switch the laser beam off (manual, "Laser OFF (sNp)")."""
        self._request("p", "?")

    def start_tracking(self, sample_time_s: float = 0.0) -> None:
        """Measure continuously into the sensor's one-value buffer every ``sample_time_s``
        (0 = as fast as possible); manual, "Tracking with buffering - Start (sNf)"."""
        ticks = round(sample_time_s / 0.01)
        if not 0 <= ticks <= 99_999_999:
            raise ValueError(f"sample time must be 0..999999.99 s, got {sample_time_s}")
        self._request(f"f+{ticks:08d}", "f?")

    def read_tracking(self) -> float | None:
        """Latest buffered distance in mm, or None if nothing new was measured since the last read.

        Manual, "Read out - Tracking with buffering (sNq)": ``gNq+xxxxxxxx+c``, c = 0 no new
        value, 1 new value, 2 new value and older ones overwritten.
        """
        payload = self._request("q", "q")
        distance, sep, fresh = payload.rpartition("+")
        if not sep or fresh not in ("0", "1", "2"):
            raise SerialGarbage(self.name, f"reply to {self._describe('q')} lacks the '+c' status: {payload!r}")
        return None if fresh == "0" else self._distance(distance, "q")

    def stop_tracking(self) -> None:
        """Stop tracking (manual, "STOP/CLEAR command (sNc)")."""
        self._request("c", "?")

    # -- serial exchange ----------------------------------------------------------------

    def _describe(self, command: str) -> str:
        return f"'s{self.device_id}{command}'"

    def _request(self, command: str, expect: str) -> str:
        """Send ``sN<command>`` and return what follows ``gN<expect>`` in the reply.

        Skipped while waiting: a start sequence ``gM?`` (manual, "Startup sequence": a
        sensor that was just powered on), unless ``?`` is the expected reply, and lines
        of sensors with another device ID."""
        request = f"s{self.device_id}{command}"
        prefix = f"g{self.device_id}"
        expected = f"'{prefix}{expect}...' in reply to '{request}'"
        with self._lock:
            self._line.discard_input()  # a reply that arrived after an earlier timeout
            self._line.write(f"{request}\r\n".encode("ascii"), request)
            deadline = time.monotonic() + self.timeout_s
            line = self._line.read_line(expected, deadline)
            while _stray(line, prefix, expect):
                line = self._line.read_line(expected, deadline)
        if line.startswith(f"{prefix}@E") and line[4:7].isdigit():
            raise _error(self.name, request, int(line[4:7]))
        if not line.startswith(prefix + expect):
            raise SerialGarbage(self.name, f"expected '{prefix}{expect}...' in reply to '{request}', got {line!r}")
        return line[len(prefix + expect) :]

    def _distance(self, field: str, command: str) -> float:
        if len(field) != 9 or field[0] not in "+-" or not field[1:].isdigit():
            raise SerialGarbage(
                self.name, f"distance {field!r} in reply to {self._describe(command)} is not ±xxxxxxxx (0.1 mm)"
            )
        return int(field) / 10.0


def read_distances(port: str, baud: int = 19200, count: int = 1) -> list[float]:
    """Take ``count`` single measurements (mm) and leave the laser off (manual, "sNg", "sNp")."""
    with DimetixLaser(port, baud) as laser:
        return [laser.measure_mm() for _ in range(count)]
