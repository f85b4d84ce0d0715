"""Emulator of a Grbl 1.1 controller driving a linear stage: a model of the documented state machine.

Written from Grbl's v1.1 documents (``doc/markdown/interface.md``, ``commands.md``,
``jogging.md``, ``doc/csv/error_codes_en_US.csv``, ``alarm_codes_en_US.csv``):

* Lines end at LF or CR (each ends a line, so an empty line gets its own ``ok``);
  spaces are dropped and letters upper-cased; a line longer than 79 characters is
  answered ``error:11``. The serial receive buffer holds 127 bytes; a byte that
  arrives when it is full is lost.
* Real-time commands act at once, also while lines wait: ``?`` status report
  ``<State|MPos:x,y,z|FS:feed,speed>``, ``!`` feed hold, ``~`` cycle start/resume,
  ``0x18`` soft reset, ``0x85`` jog cancel, ``0x84`` safety door.
* States: Idle, Run (G0/G1 blocks), Jog (``$J=``), Hold:1 (decelerating) and Hold:0
  (stopped, ready to resume), Alarm, Door:2/1/0 (stopping, ajar, closed), Check (``$C``),
  Home (``$H``). A feed hold in Idle enters Hold:0 too. While held (Hold or Door)
  Grbl executes no line: a line sent then, the empty sync line included, waits
  unanswered until ``~`` resumes; ``~`` starts the queued blocks, or returns to Idle
  when nothing is queued. A feed hold or jog cancel during a jog decelerates, flushes
  the queued jogs and returns to Idle (jogging.md).
* A soft reset while moving (Run, Jog, Home or still decelerating) halts at once:
  ``ALARM:3`` (``ALARM:6`` while homing), position likely lost. A reset from Hold:0,
  after the hold has brought the axes to a stop, keeps the position and returns to
  Idle. Every reset flushes the queue and the receive buffer and prints the banner
  ``Grbl 1.1h ['$' for help]``, followed by ``[MSG:'$H'|'$X' to unlock]`` in the Alarm
  state and ``[MSG:Check Door]`` with the door open.
* Alarms: ``ALARM:1`` (hard limit) and ``ALARM:2`` (soft limit) are critical: Grbl
  prints ``[MSG:Reset to continue]`` and answers nothing, not even ``?``, until a soft
  reset. In the Alarm state G-code is refused (``error:9``); ``$X`` unlocks
  (``[MSG:Caution: Unlocked]``), ``$H`` homes. With homing enabled ($22) the controller
  starts in the Alarm state.
* Soft limits ($20): a jog beyond the travel is refused with ``error:15``, a G0/G1
  target beyond it raises ``ALARM:2`` (after a controlled stop when running).
  ``$H`` with homing disabled answers ``error:5``; ``$`` commands that need Idle
  answer ``error:8``; ``$20=1`` without homing ``error:10``.
* The planner holds 15 blocks; a motion line that finds it full waits unanswered.

Modelling choices: machine space is ``0 .. $130`` per axis (Grbl built with
``HOMING_FORCE_SET_ORIGIN`` and homing towards the negative end, ``$23=7``); blocks
run at their feed rate without acceleration ramps, but a hold or jog cancel
decelerates at ``$120`` mm/s². Not modelled: arcs, spindle, coolant, probing,
overrides, parking, sleep, work coordinate offsets, EEPROM commands other than
settings.
"""

from __future__ import annotations

import re
import time
from collections import deque
from dataclasses import dataclass

from sim.emulators.pty_device import PtyDevice

AXES = "XYZ"
RX_BUFFER_BYTES = 127
"""Usable bytes of Grbl's serial receive buffer (``RX_BUFFER_SIZE`` 128, ``[OPT:...,128]``)."""
LINE_MAX = 79
"""Longest line Grbl executes (``LINE_BUFFER_SIZE`` 80 including the terminator)."""
PLANNER_BLOCKS = 15
"""Planner blocks (``[OPT:...,15,...]``)."""

RESET, STATUS, HOLD, RESUME = 0x18, ord("?"), ord("!"), ord("~")
SAFETY_DOOR, JOG_CANCEL = 0x84, 0x85

_WORD = re.compile(r"([A-Z])([-+]?(?:\d+\.?\d*|\.\d+))")
_COMMENT = re.compile(r"\([^)]*\)|;.*$")
_SETTING = re.compile(r"\$(\d+)=([-+]?(?:\d+\.?\d*|\.\d+))")
_JOG_G_CODES = {20.0, 21.0, 53.0, 90.0, 91.0}
_GCODE_WORDS = {0.0, 1.0, 20.0, 21.0, 53.0, 90.0, 91.0}


@dataclass
class _Block:
    target: list[float]
    feed: float  # mm/min
    jog: bool


@dataclass
class _Motion:
    """Straight-line motion from ``start`` along unit vector ``direction``."""

    start: list[float]
    direction: list[float]
    started: float
    length: float  # mm
    speed: float  # mm/s at the start
    deceleration: float = 0.0  # mm/s², 0 for constant speed

    @property
    def duration(self) -> float:
        if self.deceleration:
            return self.speed / self.deceleration
        return self.length / self.speed if self.speed > 0 else 0.0

    def travelled(self, now: float) -> float:
        t = min(max(now - self.started, 0.0), self.duration)
        return min(self.speed * t - 0.5 * self.deceleration * t * t, self.length)

    def position(self, now: float) -> list[float]:
        s = self.travelled(now)
        return [p + s * d for p, d in zip(self.start, self.direction, strict=True)]

    def speed_at(self, now: float) -> float:
        t = min(max(now - self.started, 0.0), self.duration)
        return max(self.speed - self.deceleration * t, 0.0)


class GrblEmulator(PtyDevice):
    """A Grbl 1.1h board with ``max_travel_mm`` of travel on every axis.

    ``boot_s`` models a board that reboots when the port is opened: it ignores
    input for that long, then prints its banner. Tests inject ``error:N`` replies
    (:meth:`inject_error`), alarms (:meth:`inject_alarm`), a hard-limit switch that
    trips during the next move (:meth:`trip_hard_limit_at`), a failing homing cycle
    (:meth:`fail_homing`) and the safety door (:meth:`open_door`, :meth:`close_door`).
    """

    def __init__(
        self,
        *,
        max_travel_mm: float = 400.0,
        max_rate_mm_min: float = 60_000.0,
        acceleration_mm_s2: float = 10_000.0,
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
            0: 10, 1: 25, 10: 1, 13: 0, 20: int(soft_limits), 21: 0, 22: int(homing_enabled), 23: 7,
            25: max_rate_mm_min, 27: 1.0,
            110: max_rate_mm_min, 111: max_rate_mm_min, 112: max_rate_mm_min,
            120: acceleration_mm_s2, 121: acceleration_mm_s2, 122: acceleration_mm_s2,
            130: max_travel_mm, 131: max_travel_mm, 132: max_travel_mm,
        }  # fmt: skip
        self.state = "Alarm" if homing_enabled else "Idle"
        self.hold_complete = False
        """Hold:0 (True) or Hold:1 (False) while :attr:`state` is ``Hold``."""
        self.door_open = False
        self.lines: list[str] = []
        """Every line Grbl took from its receive buffer, as executed."""
        start = max_travel_mm / 2 if start_mm is None else start_mm
        self._position = [start, 0.0, 0.0]
        self._motion: _Motion | None = None
        self._block: _Block | None = None  # the block being executed
        self._planner: deque[_Block] = deque()
        self._after_stop: str = ""  # what a deceleration ends in: "hold", "idle", "alarm2", "door"
        self._resume_state = "Idle"  # the state a resumed hold returns to
        self._critical = False  # hard/soft limit: nothing but a reset is accepted
        self._status_pending = False  # '?' during homing is answered when homing ends
        self._rx = bytearray()
        self._errors: deque[int] = deque()
        self._hard_limit_at: float | None = None
        self._homing_failure: int | None = None
        self._booted_at = 0.0
        self._modal = {"relative": False, "inches": False, "feed": None, "motion": None}

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
        """Trip a limit switch (``ALARM:1``) when the next motion passes ``at_mm`` on X."""
        with self.lock:
            self._hard_limit_at = at_mm

    def fail_homing(self, code: int = 9) -> None:
        """Make the next ``$H`` fail with ``ALARM:code`` (8 pull-off failed, 9 switch not found)."""
        with self.lock:
            self._homing_failure = code

    def open_door(self) -> None:
        """Open the safety door (the switch input, or ``0x84``): a moving machine stops, Door state."""
        with self.lock:
            self._door(time.monotonic())

    def close_door(self) -> None:
        """Close the safety door: Door:1 becomes Door:0, ready to resume with ``~``."""
        with self.lock:
            self.door_open = False

    @property
    def position_mm(self) -> float:
        """Current X machine position in mm."""
        with self.lock:
            return self._current(time.monotonic())[0]

    @property
    def status_state(self) -> str:
        """The state as the status report names it (``Hold:0``, ``Door:1``, ...)."""
        with self.lock:
            return self._state_name()

    # -- protocol: bytes and real-time commands ---------------------------------------

    def on_start(self) -> None:
        self._booted_at = time.monotonic() + self.boot_s
        if not self.boot_s:
            self._banner()

    def handle_bytes(self, data: bytes) -> None:
        now = time.monotonic()
        if now < self._booted_at:
            return  # the boot loader runs after the port opened (Arduino auto-reset) and drops input
        for byte in data:
            if byte == RESET:
                self._soft_reset(now)
            elif self._critical:
                continue  # halted by a limit alarm: only a reset is accepted ([MSG:Reset to continue])
            elif byte == STATUS:
                self._status_request(now)
            elif byte == HOLD:
                self._feed_hold(now)
            elif byte == RESUME:
                self._cycle_start(now)
            elif byte == JOG_CANCEL:
                if self.state == "Jog" and not self._after_stop:
                    self._decelerate(now, "idle")
            elif byte == SAFETY_DOOR:
                self._door(now)
            elif byte < 0x80 and len(self._rx) < RX_BUFFER_BYTES:  # a full buffer loses the byte
                self._rx.append(byte)
        self._process_lines(now)

    def _status_request(self, now: float) -> None:
        if self.state == "Home":  # the homing cycle answers a status request when it ends
            self._status_pending = True
        else:
            self._status(now)

    def _feed_hold(self, now: float) -> None:
        if self.state in ("Alarm", "Check", "Door"):
            return
        if self.state == "Jog":  # a hold cancels a jog (jogging.md)
            if not self._after_stop:
                self._decelerate(now, "idle")
        elif self.state == "Run":
            self._resume_state = "Run"
            self.state, self.hold_complete = "Hold", False
            self._decelerate(now, "hold")
        elif self.state == "Idle":
            self._resume_state = "Idle"
            self.state, self.hold_complete = "Hold", True

    def _cycle_start(self, now: float) -> None:
        if self.state == "Door" and not self.door_open and self.hold_complete:
            self.state = "Hold"  # the door is closed: resume as from a completed hold
        if self.state == "Hold" and self.hold_complete:
            self.hold_complete = False
            if self._block is not None or self._planner:
                self.state = "Run"
                self._next_block(now, resume=True)
            else:
                self.state = "Idle"
        elif self.state == "Idle" and self._planner:
            self.state = "Run"
            self._next_block(now)

    def _door(self, now: float) -> None:
        if self.state in ("Alarm", "Check"):
            self.door_open = True
            return
        self.door_open = True
        self.push(b"[MSG:Check Door]\r\n")
        if self.state == "Jog":
            if not self._after_stop:
                self._decelerate(now, "door")
            return
        if self.state in ("Run", "Hold") and self._motion is not None and self._motion.deceleration == 0.0:
            self._decelerate(now, "door")
            self.hold_complete = False
        elif self.state in ("Idle", "Hold"):
            self.hold_complete = self._motion is None
        self.state = "Door"

    # -- protocol: lines -------------------------------------------------------------------

    def _suspended(self) -> bool:
        return self.state in ("Hold", "Door", "Home") or self._critical

    def _process_lines(self, now: float) -> None:
        while not self._suspended():
            ends = [i for i in (self._rx.find(b"\n"), self._rx.find(b"\r")) if i >= 0]
            if not ends:
                return
            end = min(ends)
            raw = bytes(self._rx[:end]).decode("ascii", "replace")
            line = _COMMENT.sub("", raw).replace(" ", "").replace("\t", "").upper()
            if self._is_motion(line) and len(self._planner) >= PLANNER_BLOCKS:
                return  # the planner is full: the line waits, unanswered
            del self._rx[: end + 1]
            self.lines.append(line)
            if len(raw) > LINE_MAX:
                self._answer("error:11")
            elif self._errors:
                self._answer(f"error:{self._errors.popleft()}")
            else:
                self._execute(line, now)

    @staticmethod
    def _is_motion(line: str) -> bool:
        return line.startswith("$J=") or (line != "" and not line.startswith("$"))

    def _execute(self, line: str, now: float) -> None:
        if line == "":
            self._answer("ok")
        elif line == "$":
            self._answer("[HLP:$$ $# $G $I $N $x=val $Nx=line $J=line $SLP $C $X $H ~ ! ? ctrl-x]", "ok")
        elif line.startswith("$J"):
            if self.state not in ("Idle", "Jog"):
                self._answer("error:8")
            elif not line.startswith("$J="):
                self._answer("error:3")
            else:
                self._jog(line[3:], now)
        elif line[:2] in ("$$", "$G", "$C", "$X"):
            self._execute_query(line, now)
        elif line.startswith("$"):
            self._execute_system(line, now)
        elif self.state in ("Alarm", "Jog"):
            self._answer("error:9")
        else:
            self._gcode(line, now)

    def _execute_query(self, line: str, now: float) -> None:
        """``$$``, ``$G``, ``$C`` and ``$X``: accepted in any state Grbl reads lines in."""
        if len(line) != 2:
            self._answer("error:3")
        elif line == "$$":
            if self.state == "Run":
                self._answer("error:8")
            else:
                self._answer(*(f"${key}={value:g}" for key, value in self.settings.items()), "ok")
        elif line == "$G":
            units = "G20" if self._modal["inches"] else "G21"
            distance = "G91" if self._modal["relative"] else "G90"
            self._answer(f"[GC:G0 G54 G17 {units} {distance} G94 M5 M9 T0 F0 S0]", "ok")
        elif line == "$C":
            if self.state == "Check":
                self._answer("[MSG:Disabled]", "ok")
                self._soft_reset(now)
            elif self.state != "Idle":
                self._answer("error:8")
            else:
                self.state = "Check"
                self._answer("[MSG:Enabled]", "ok")
        elif self.state == "Alarm":  # $X
            if self.door_open:
                self._answer("error:13")
            else:
                self.state = "Idle"
                self._answer("[MSG:Caution: Unlocked]", "ok")
        else:
            self._answer("ok")  # $X outside the Alarm state has no effect

    def _execute_system(self, line: str, now: float) -> None:
        """``$`` commands that need the Idle or Alarm state: ``$I``, ``$H``, ``$N``, ``$#``, ``$x=value``."""
        if self.state not in ("Idle", "Alarm"):
            self._answer("error:8")
        elif line == "$I":
            self._answer(f"[VER:{self.version}.{self.build_date}:{self.info}]", f"[OPT:VZL,{PLANNER_BLOCKS},128]", "ok")
        elif line == "$H":
            self._home(now)
        elif line == "$N":
            self._answer("$N0=", "$N1=", "ok")
        elif line == "$#":
            self._answer("[G54:0.000,0.000,0.000]", "[G28:0.000,0.000,0.000]", "[G30:0.000,0.000,0.000]",
                         "[G92:0.000,0.000,0.000]", "[TLO:0.000]", "[PRB:0.000,0.000,0.000:0]", "ok")
        elif match := _SETTING.fullmatch(line):
            self._write_setting(int(match[1]), float(match[2]))
        else:
            self._answer("error:3")

    def _write_setting(self, key: int, value: float) -> None:
        if key not in self.settings:
            self._answer("error:3")
        elif value < 0:
            self._answer("error:4")
        elif key == 20 and value and not self.settings[22]:
            self._answer("error:10")  # soft limits need homing
        else:
            self.settings[key] = value
            self._answer("ok")

    def _parse_words(self, block: str) -> list[tuple[str, float]] | None:
        words = _WORD.findall(block)
        if "".join(letter + value for letter, value in words) != block:
            self._answer("error:2" if block[:1].isalpha() else "error:1")
            return None
        return [(letter, float(value)) for letter, value in words]

    def _jog(self, block: str, now: float) -> None:
        words = self._parse_words(block)
        if words is None:
            return
        targets: dict[int, float] = {}
        feed, scale, relative = None, 25.4 if self._modal["inches"] else 1.0, False
        for letter, number in words:
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
        target = self._target(targets, scale, relative)
        if self._beyond_travel(target):
            self._answer("error:15")
            return
        self._queue_block(_Block(target, feed * scale, jog=True), now)
        self._answer("ok")

    def _gcode(self, block: str, now: float) -> None:
        """G0/G1 with G20/G21, G90/G91, G53, F and axis words; anything else is ``error:20``."""
        words = self._parse_words(block)
        if words is None:
            return
        targets: dict[int, float] = {}
        modal = dict(self._modal)
        for letter, number in words:
            if letter == "G" and number in _GCODE_WORDS:
                if number in (0.0, 1.0):
                    modal["motion"] = int(number)
                elif number in (20.0, 21.0):
                    modal["inches"] = number == 20.0
                elif number in (90.0, 91.0):
                    modal["relative"] = number == 91.0
            elif letter == "F":
                modal["feed"] = number
            elif letter in AXES:
                targets[AXES.index(letter)] = number
            else:
                self._answer("error:20")
                return
        if targets and modal["motion"] is None:
            self._answer("error:31")
            return
        if targets and modal["motion"] == 1 and modal["feed"] is None:
            self._answer("error:22")
            return
        self._modal = modal
        scale = 25.4 if modal["inches"] else 1.0
        if not targets or self.state == "Check":
            self._answer("ok")
            return
        target = self._target(targets, scale, bool(modal["relative"]))
        if self._beyond_travel(target):  # soft limit: a controlled stop when running, then ALARM:2
            if self.state == "Run":
                self._decelerate(now, "alarm2")
            else:
                self._alarm(2, now)
            return
        feed = self.settings[110] if modal["motion"] == 0 else float(modal["feed"]) * scale
        self._queue_block(_Block(target, feed, jog=False), now)
        self._answer("ok")

    def _target(self, targets: dict[int, float], scale: float, relative: bool) -> list[float]:
        base = list(self._planner[-1].target) if self._planner else (
            list(self._block.target) if self._block is not None else self._current(time.monotonic()))
        return [targets[axis] * scale + (base[axis] if relative else 0.0) if axis in targets else base[axis]
                for axis in range(len(AXES))]

    def _beyond_travel(self, target: list[float]) -> bool:
        return bool(self.settings[20]) and any(
            not 0.0 <= value <= self.settings[130 + axis] for axis, value in enumerate(target))

    # -- motion ------------------------------------------------------------------------------

    def _queue_block(self, block: _Block, now: float) -> None:
        self._planner.append(block)
        if self.state == "Idle":
            self.state = "Jog" if block.jog else "Run"
            self._next_block(now)

    def _next_block(self, now: float, resume: bool = False) -> None:
        """Start the block interrupted by a hold (``resume``) or the next queued one."""
        if not (resume and self._block is not None):
            self._block = self._planner.popleft() if self._planner else None
        if self._block is None:
            self._motion = None
            self.state = "Idle"
            return
        start = self._current(now)
        delta = [t - s for s, t in zip(start, self._block.target, strict=True)]
        length = sum(d * d for d in delta) ** 0.5
        direction = [d / length for d in delta] if length else [0.0] * len(AXES)
        limit = self._hard_limit_at
        if limit is not None and direction[0] and min(start[0], self._block.target[0]) <= limit <= max(
                start[0], self._block.target[0]):
            length = (limit - start[0]) / direction[0]
            self._after_stop = "alarm1"
            self._hard_limit_at = None
        speed = min(self._block.feed, self.settings[110]) / 60.0
        self._motion = _Motion(start, direction, now, length, speed)

    def _decelerate(self, now: float, then: str) -> None:
        """Ramp the current motion down at ``$120`` (a hold, jog cancel, door or soft limit)."""
        self._after_stop = then
        motion = self._motion
        if motion is None:
            self._stopped(now)
            return
        position = motion.position(now)
        speed = motion.speed_at(now)
        remaining = motion.length - motion.travelled(now)
        self._position = position
        acceleration = self.settings[120]
        if speed <= 0.0 or remaining <= 0.0:
            self._motion = None
            self._stopped(now)
            return
        length = min(speed * speed / (2 * acceleration), remaining)
        self._motion = _Motion(position, motion.direction, now, length, speed, acceleration)

    def _stopped(self, now: float) -> None:
        """A deceleration (or an interrupted block) has brought the axes to rest."""
        then, self._after_stop = self._after_stop, ""
        if then == "hold":
            self.hold_complete = True
        elif then == "door":
            self.hold_complete = True
            if self.state == "Jog":
                self._block, self._planner = None, deque()
                self._resume_state = "Idle"
            self.state = "Door"
        elif then == "idle":  # jog cancelled: flush the queued jogs
            self._block, self._planner = None, deque()
            self.state = "Idle"
        elif then == "alarm2":
            self._alarm(2, now)
        elif then == "alarm1":
            self._alarm(1, now)

    def _current(self, now: float) -> list[float]:
        return list(self._position) if self._motion is None else self._motion.position(now)

    def tick(self, now: float) -> None:
        if self.boot_s and now >= self._booted_at:
            self.boot_s = 0.0
            self._banner()
        motion = self._motion
        if motion is not None and now - motion.started >= motion.duration:
            self._position = motion.position(now)
            self._motion = None
            if self._after_stop:
                self._stopped(now)
            elif self.state == "Home":
                self._home_done()
            elif self.state in ("Run", "Jog"):
                self._block = None
                self._next_block(now)
        self._process_lines(now)

    # -- homing, alarms, reset ----------------------------------------------------------------

    def _home(self, now: float) -> None:
        if not self.settings[22]:
            self._answer("error:5")
        elif self.door_open:
            self._answer("error:13")
        elif self._homing_failure is not None:
            code, self._homing_failure = self._homing_failure, None
            self._alarm(code, now)
        else:
            self.state = "Home"
            start = self._current(now)
            length = sum(p * p for p in start) ** 0.5
            direction = [-p / length for p in start] if length else [0.0] * len(AXES)
            self._motion = _Motion(start, direction, now, length, self.settings[25] / 60.0)

    def _home_done(self) -> None:
        self._position = [0.0] * len(AXES)
        self.state = "Idle"
        self._answer("ok")
        if self._status_pending:
            self._status_pending = False
            self._status(time.monotonic())

    def _alarm(self, code: int, now: float) -> None:
        self._position = self._current(now)
        self._motion, self._block, self._planner, self._after_stop = None, None, deque(), ""
        self.state = "Alarm"
        self.push(f"ALARM:{code}\r\n".encode("ascii"))
        if code in (1, 2):  # limit alarms are critical: nothing but a reset is accepted
            self._critical = True
            self.push(b"[MSG:Reset to continue]\r\n")

    def _soft_reset(self, now: float) -> None:
        moving = self._motion is not None or self.state in ("Run", "Jog", "Home")
        if moving and not self._critical:  # position is not guaranteed after a reset in motion
            self._alarm(6 if self.state == "Home" else 3, now)
        self._motion, self._block, self._planner, self._after_stop = None, None, deque(), ""
        self._critical = self._status_pending = False
        self._rx.clear()
        self._modal = {"relative": False, "inches": False, "feed": None, "motion": None}
        if self.state != "Alarm":
            self.state = "Door" if self.door_open else "Idle"
            self.hold_complete = True
            self._resume_state = "Idle"
        self._banner()

    def _banner(self) -> None:
        self.push(f"\r\nGrbl {self.version} ['$' for help]\r\n".encode("ascii"))
        if self.state == "Alarm":
            self.push(b"[MSG:'$H'|'$X' to unlock]\r\n")
        elif self.door_open:
            self.push(b"[MSG:Check Door]\r\n")

    def _state_name(self) -> str:
        if self.state == "Hold":
            return f"Hold:{0 if self.hold_complete else 1}"
        if self.state == "Door":
            if not self.hold_complete:
                return "Door:2"
            return "Door:1" if self.door_open else "Door:0"
        return self.state

    def _status(self, now: float) -> None:
        position = ",".join(f"{value:.3f}" for value in self._current(now))
        feed = self._motion.speed_at(now) * 60.0 if self._motion is not None else 0.0
        self.reply(f"<{self._state_name()}|MPos:{position}|FS:{feed:.0f},0>\r\n".encode("ascii"))

    def _answer(self, *lines: str) -> None:
        self.reply("".join(f"{line}\r\n" for line in lines).encode("ascii"))
