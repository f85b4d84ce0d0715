"""The Grbl 1.1 emulator's state machine, byte for byte, and the driver's code tables against the manual.

The exchanges below are the ones the real Grbl 1.1h firmware (compiled for the host with
grbl-sim, on a pty) answered; the emulator must answer them the same way. The code tables
are compared with Grbl's documented code lists, transcribed into
``manuals/grbl_codes.toml`` (its header names the document and version).
"""

from __future__ import annotations

import time
from collections.abc import Iterator

import pytest
import serial

from drivers.stage.grbl import ALARM_CODES, ERROR_CODES
from sim.emulators import GrblEmulator
from tests.drivers.manuals import load

pytestmark = pytest.mark.realtime  # transient states (a hold decelerating for 0.5 s) read on time

BANNER = b"\r\nGrbl 1.1h ['$' for help]\r\n"
UNLOCK = b"[MSG:'$H'|'$X' to unlock]\r\n"


def documented(kind: str) -> dict[int, str]:
    """Code -> documented description of Grbl's ``error`` or ``alarm`` codes."""
    return {entry["code"]: entry["description"] for entry in load("grbl_codes.toml")[kind]}


def test_error_table_is_the_documented_list() -> None:
    assert ERROR_CODES == documented("error")


def test_alarm_table_is_the_documented_list() -> None:
    assert ALARM_CODES == documented("alarm")


#: seconds within which the emulator answers (generous: its thread may wait for a loaded CPU)
REPLY_WITHIN_S = 10.0


class Link:
    """Raw bytes to and from the emulator, as a terminal would send them."""

    def __init__(self, port: str) -> None:
        self.port = serial.Serial(port, 115200, timeout=0.01)

    def write(self, data: bytes) -> None:
        self.port.write(data)

    def expect(self, data: bytes, reply: bytes) -> None:
        """Send ``data``; exactly ``reply`` must come back (waiting up to REPLY_WITHIN_S for its length,
        then 0.1 s for anything more; 0.2 s when nothing is expected)."""
        self.port.write(data)
        deadline, received = time.monotonic() + REPLY_WITHIN_S, b""
        while len(received) < len(reply) and time.monotonic() < deadline:
            received += self.port.read(4096)
        assert received + self.read(0.1 if reply else 0.2) == reply

    def read(self, wait_s: float) -> bytes:
        end = time.monotonic() + wait_s
        received = b""
        while time.monotonic() < end:
            received += self.port.read(4096)
        return received

    def state(self) -> str:
        """The state from a status report; nothing else may arrive meanwhile."""
        self.port.write(b"?")
        deadline, report = time.monotonic() + REPLY_WITHIN_S, b""
        while not report.endswith(b">\r\n") and time.monotonic() < deadline:
            report += self.port.read(4096)
        assert report.startswith(b"<"), report
        return report[1:].split(b"|")[0].decode()

    def wait_for(self, state: str, timeout_s: float = 30.0) -> None:
        deadline = time.monotonic() + timeout_s
        while (now := self.state()) != state:
            assert time.monotonic() < deadline, f"still {now}, expected {state}"


@pytest.fixture
def emulator() -> Iterator[GrblEmulator]:
    with GrblEmulator(homing_enabled=False, max_rate_mm_min=600.0, acceleration_mm_s2=20.0, start_mm=10.0) as grbl:
        yield grbl


@pytest.fixture
def link(emulator: GrblEmulator) -> Iterator[Link]:
    emulator.wait_quiet(timeout_s=REPLY_WITHIN_S)  # the power-up banner written, then dropped as the port opens
    terminal = Link(emulator.port)
    yield terminal
    terminal.port.close()


def test_feed_hold_while_idle_holds_every_line_until_resumed(link: Link) -> None:
    link.expect(b"!", b"")
    assert link.state() == "Hold:0"
    link.expect(b"\n", b"")  # the empty sync line waits, unanswered
    assert link.state() == "Hold:0"
    link.expect(b"~", b"ok\r\n")  # resumed: the waiting line is answered now
    assert link.state() == "Idle"


def test_reset_from_a_completed_hold_keeps_the_position(link: Link, emulator: GrblEmulator) -> None:
    link.expect(b"G1X30F600\n", b"ok\r\n")
    time.sleep(0.2)
    link.write(b"!")
    assert link.state() == "Hold:1"  # decelerating (10 mm/s at 20 mm/s^2: 0.5 s)
    link.wait_for("Hold:0")
    held = emulator.position_mm
    assert 10.0 < held < 30.0
    link.expect(b"\x18", BANNER)  # no ALARM:3: the axes were at rest
    assert link.state() == "Idle" and emulator.position_mm == held


def test_resume_continues_the_held_program(link: Link, emulator: GrblEmulator) -> None:
    link.expect(b"G1X14F600\n", b"ok\r\n")  # a hold before the line is read would hold Idle Grbl
    link.write(b"!")
    link.wait_for("Hold:0")
    link.write(b"~")
    assert link.state() == "Run"
    link.wait_for("Idle")
    assert emulator.position_mm == pytest.approx(14.0)


def test_reset_while_jogging_raises_alarm_3_and_the_unlock_message(link: Link) -> None:
    link.expect(b"$J=G53G90G21X60F600\n", b"ok\r\n")
    assert link.state() == "Jog"
    link.expect(b"\x18", b"ALARM:3\r\n" + BANNER + UNLOCK)
    assert link.state() == "Alarm"
    link.expect(b"\n", b"ok\r\n")  # the Alarm state still answers lines
    link.expect(b"G1X1F100\n", b"error:9\r\n")  # G-code locked out
    link.expect(b"$X\n", b"[MSG:Caution: Unlocked]\r\nok\r\n")
    assert link.state() == "Idle"


@pytest.mark.parametrize("stop", [b"!", b"\x85"])
def test_feed_hold_or_jog_cancel_ends_a_jog_idle(link: Link, emulator: GrblEmulator, stop: bytes) -> None:
    link.expect(b"$J=G53G90G21X60F600\n$J=G53G90G21X80F600\n", b"ok\r\nok\r\n")
    link.write(stop)
    assert link.state() == "Jog"  # still decelerating: a jog cancel reports Jog, never Hold
    link.wait_for("Idle")
    time.sleep(0.1)
    assert emulator.position_mm < 20.0 and link.state() == "Idle"  # both queued jogs flushed


def test_jog_cancel_outside_a_jog_is_ignored(link: Link) -> None:
    link.expect(b"\x85", b"")
    assert link.state() == "Idle"


def test_homing_disabled_and_soft_limits_need_homing(link: Link) -> None:
    link.expect(b"$H\n", b"error:5\r\n")
    link.expect(b"$20=1\n", b"error:10\r\n")


def test_soft_limits(emulator: GrblEmulator) -> None:
    with GrblEmulator(homing_enabled=True, max_travel_mm=100.0, start_mm=50.0) as grbl:
        terminal = Link(grbl.port)
        terminal.read(0.05)  # the power-up banner, unless opening the port flushed it
        assert terminal.state() == "Alarm"  # homing lock at power-up
        terminal.expect(b"$X\n", b"[MSG:Caution: Unlocked]\r\nok\r\n")
        terminal.expect(b"$J=G53G90G21X120F600\n", b"error:15\r\n")  # jog refused, no alarm
        assert terminal.state() == "Idle"
        terminal.expect(b"G0X120\n", b"ALARM:2\r\n[MSG:Reset to continue]\r\n")
        terminal.expect(b"?\n", b"")  # a critical alarm answers nothing but a reset
        terminal.expect(b"\x18", BANNER + UNLOCK)
        assert terminal.state() == "Alarm" and grbl.position_mm == 50.0  # position retained
        terminal.port.close()


def test_hard_limit_is_critical(link: Link, emulator: GrblEmulator) -> None:
    emulator.trip_hard_limit_at(12.0)
    link.expect(b"$J=G53G90G21X40F600\n", b"ok\r\nALARM:1\r\n[MSG:Reset to continue]\r\n")
    link.expect(b"?", b"")
    link.expect(b"\x18", BANNER + UNLOCK)
    assert link.state() == "Alarm" and emulator.position_mm == pytest.approx(12.0)


def test_safety_door(link: Link, emulator: GrblEmulator) -> None:
    emulator.open_door()
    assert link.read(0.05) == b"[MSG:Check Door]\r\n"
    assert link.state() == "Door:1"
    link.expect(b"\n", b"")  # held like a feed hold
    link.expect(b"~", b"")  # cannot resume with the door open
    emulator.close_door()
    assert link.state() == "Door:0"
    link.expect(b"~", b"ok\r\n")
    assert link.state() == "Idle"


def test_check_mode_and_line_limits(link: Link, emulator: GrblEmulator) -> None:
    link.expect(b"$C\n", b"[MSG:Enabled]\r\nok\r\n")
    assert link.state() == "Check"
    link.expect(b"G1X50F100\n", b"ok\r\n")  # parsed, not moved
    assert emulator.position_mm == 10.0
    link.expect(b"$C\n", b"[MSG:Disabled]\r\nok\r\n" + BANNER)
    link.expect(b"G1X" + b"0" * 80 + b"1F100\n", b"error:11\r\n")
    link.expect(b"$I\n", b"[VER:1.1h.20190830:]\r\n[OPT:VZL,15,128]\r\nok\r\n")
