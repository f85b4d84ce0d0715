"""The Zaber emulator against Zaber's own client library (zaber-motion), and the driver with checksums.

zaber-motion frames every command itself: a message ID and, by default, a checksum
(``/1 1 07 get pos:25``); it verifies the checksum of every reply that has one and
drops a reply whose checksum is wrong. Raw commands (``generic_command``) need no
device database: the database is pointed at a file that does not exist, and only
``detect_devices`` notices.
"""

from __future__ import annotations

import re
import time
from collections.abc import Iterator

import pytest
from zaber_motion import DeviceDbSourceType, Library
from zaber_motion.ascii import Connection
from zaber_motion.exceptions import (
    BadCommandException,
    CommandFailedException,
    DeviceDbFailedException,
    RequestTimeoutException,
)

from drivers.errors import SerialGarbage
from drivers.stage import ZaberStage
from labctl.run.config import StageConfig
from labctl.run.hardware import stage_from_config
from sim.emulators import ZaberEmulator

STEP = 0.000125  # mm per microstep
TIMEOUT_MS = 3000  # generous: the emulator shares a loaded machine
FRAMED = re.compile(r"/(\d+) (\d+) (\d\d) ?(.*):([0-9A-F]{2})")
"""A command as zaber-motion sends it: device, axis, two-digit message ID, command, checksum."""


def lrc_ok(line: str) -> bool:
    """The manual's check, computed here independently: the bytes after ``/`` or ``@`` up to
    ``:`` plus the checksum's value sum to 0 modulo 256."""
    body, _, check = line[1:].rpartition(":")
    return (sum(body.encode("ascii")) + int(check, 16)) % 256 == 0


@pytest.fixture(scope="module", autouse=True)
def no_device_database() -> None:
    Library.set_device_db_source(DeviceDbSourceType.FILE, "/nonexistent/zaber-device-db.sqlite")
    Library.disable_device_db_store()


@pytest.fixture
def emulator() -> Iterator[ZaberEmulator]:
    with ZaberEmulator(mm_per_microstep=STEP, travel_mm=400.0, speed_mm_s=200.0, start_mm=20.0) as device:
        yield device


@pytest.fixture
def connection(emulator: ZaberEmulator) -> Iterator[Connection]:
    link = Connection.open_serial_port(emulator.port, direct=True)
    link.default_request_timeout = TIMEOUT_MS
    yield link
    link.close()


def command(link: Connection, text: str, axis: int = 1, **options: object):  # type: ignore[no-untyped-def]
    return link.generic_command(text, device=1, axis=axis, **options)  # type: ignore[arg-type]


def test_get_pos_with_message_id_and_checksum(emulator: ZaberEmulator, connection: Connection) -> None:
    assert connection.checksum_enabled  # the library's default
    reply = command(connection, "get pos")
    assert (reply.device_address, reply.axis_number, reply.reply_flag, reply.status) == (1, 1, "OK", "IDLE")
    assert reply.warning_flag == "WR"  # not homed since power-up
    assert int(reply.data) == round(20.0 / STEP)
    sent = FRAMED.fullmatch(emulator.lines[-1])
    assert sent is not None and sent.group(4) == "get pos" and lrc_ok(emulator.lines[-1])
    assert emulator.bad_checksums == 0


def test_empty_command_with_id_and_checksum_is_answered(emulator: ZaberEmulator, connection: Connection) -> None:
    reply = command(connection, "")  # '/1 1 NN:CC', which the earlier emulator never answered
    assert (reply.reply_flag, reply.data) == ("OK", "0")
    assert re.fullmatch(r"/1 1 \d\d:[0-9A-F]{2}", emulator.lines[-1])


def test_broadcast_ping_reaches_the_device(connection: Connection) -> None:
    replies = connection.generic_command_multi_response("", timeout=1000)  # '/0 0 NN:CC'; waits 1 s for all
    assert [(r.device_address, r.axis_number, r.reply_flag) for r in replies] == [(1, 0, "OK")]


def test_without_checksum_and_id_the_device_still_answers(emulator: ZaberEmulator, connection: Connection) -> None:
    connection.checksum_enabled = False
    reply = command(connection, "get deviceid", axis=0)
    assert reply.data == "50081"
    assert not emulator.lines[-1].count(":")


@pytest.mark.parametrize(
    ("text", "axis", "reason"),
    [
        ("get nosuch.setting", 1, "BADCOMMAND"),
        ("get deviceid", 1, "DEVICEONLY"),
        ("get pos", 2, "BADAXIS"),
        ("move abs 100", 1, "BADCOMMAND"),  # no reference position yet
        ("move abs banana", 1, "BADDATA"),
        ("set maxspeed 0", 1, "BADDATA"),
        ("system reset", 1, "DEVICEONLY"),
    ],
)
def test_rejections_reach_the_library_with_their_reason(connection: Connection, text: str, axis: int, reason: str) -> None:
    with pytest.raises(CommandFailedException) as caught:
        command(connection, text, axis=axis)
    assert caught.value.details.response_data == reason
    assert caught.value.details.reply_flag == "RJ"
    assert isinstance(caught.value, BadCommandException) == (reason == "BADCOMMAND")
    reply = command(connection, text, axis=axis, check_errors=False)
    assert (reply.reply_flag, reply.data) == ("RJ", reason)


def wait_idle(link: Connection, limit_s: float = 30.0) -> None:
    deadline = time.monotonic() + limit_s
    while command(link, "").status == "BUSY":
        assert time.monotonic() < deadline, "still BUSY"
        time.sleep(0.01)


def test_motion_busy_move_while_moving_stop_and_estop(emulator: ZaberEmulator, connection: Connection) -> None:
    command(connection, "home")
    wait_idle(connection)
    assert command(connection, "get pos").warning_flag == "--"
    with emulator.lock:
        emulator.speed_mm_s = 10.0  # slow: every move below is still under way when the next command comes
    assert command(connection, "move abs 1600000").status == "BUSY"  # 200 mm at 10 mm/s
    busy = command(connection, "get pos")
    assert busy.status == "BUSY" and 0 < int(busy.data) < 1_600_000
    replaced = command(connection, "move abs 80000")  # accepted while moving: the new target wins
    assert (replaced.reply_flag, replaced.status, replaced.warning_flag) == ("OK", "BUSY", "NI")
    wait_idle(connection)
    assert int(command(connection, "get pos").data) == 80000
    assert command(connection, "warnings clear").data.split() == ["01", "NI"]
    for stop in ("stop", "estop"):
        command(connection, "move abs 3000000")
        time.sleep(0.05)
        halted = command(connection, stop)
        assert (halted.reply_flag, halted.status, halted.warning_flag) == ("OK", "IDLE", "NI")
        assert 80000 < int(command(connection, "get pos").data) < 3_000_000
        command(connection, "warnings clear")


def test_reply_checksums_pass_the_library(emulator: ZaberEmulator, connection: Connection) -> None:
    assert command(connection, "set comm.checksum 1", axis=0).reply_flag == "OK"
    assert emulator.reply_checksums
    reply = command(connection, "get pos")  # the library drops a reply whose checksum is wrong ...
    assert int(reply.data) == round(20.0 / STEP)
    assert command(connection, "get comm.checksum", axis=0).data == "1"
    emulator.corrupt_checksums()
    with pytest.raises(RequestTimeoutException):  # ... as here, so the replies above were right
        command(connection, "get pos", timeout=300)


def test_system_reset_loses_the_reference(emulator: ZaberEmulator, connection: Connection) -> None:
    command(connection, "home")
    wait_idle(connection)
    assert command(connection, "system reset", axis=0).reply_flag == "OK"
    assert emulator.resets == 1
    assert command(connection, "get pos").warning_flag == "WR"


def test_parking(connection: Connection) -> None:
    command(connection, "home")
    wait_idle(connection)
    command(connection, "move abs 3000000")  # 375 mm at 200 mm/s: moving for almost 2 s
    with pytest.raises(CommandFailedException) as caught:
        command(connection, "tools parking park", axis=0)  # not while moving
    assert caught.value.details.response_data == "STATUSBUSY"
    command(connection, "stop")
    parked_at = int(command(connection, "get pos").data)
    command(connection, "warnings clear")
    command(connection, "tools parking park", axis=0)
    assert command(connection, "move abs 10", check_errors=False).data == "PARKED"
    command(connection, "system reset", axis=0)  # a parked axis keeps its reference over a reset
    command(connection, "tools parking unpark", axis=0)
    assert command(connection, "get pos").warning_flag == "--"
    assert int(command(connection, "get pos").data) == parked_at


def test_alerts_when_a_move_ends(emulator: ZaberEmulator, connection: Connection) -> None:
    connection.enable_alerts()  # '/0 0 set comm.alert 1', no message ID, reply ignored
    time.sleep(0.05)
    assert emulator.alerts
    alerts = []
    subscription = connection.alert.subscribe(alerts.append)
    try:
        command(connection, "home")
        wait_idle(connection)
        time.sleep(0.1)
    finally:
        subscription.dispose()
    assert [(a.device_address, a.axis_number, a.status) for a in alerts] == [(1, 1, "IDLE")]


def test_raw_commands_need_no_device_database(connection: Connection) -> None:
    assert command(connection, "get version", axis=0).data == "7.38"
    connection.default_request_timeout = 1000  # detection waits that long for further devices
    with pytest.raises(DeviceDbFailedException):  # only identification consults the database
        connection.detect_devices()


# -- the driver with checksums ------------------------------------------------------------


def test_driver_with_checksums_against_reply_checksums() -> None:
    with ZaberEmulator(mm_per_microstep=STEP, travel_mm=400.0, speed_mm_s=2000.0, reply_checksums=True) as emulator:
        stage = ZaberStage(emulator.port, travel_mm=(0.0, 400.0), mm_per_microstep=STEP, timeout_s=2.0, checksums=True)
        with stage:
            stage.home()
            stage.move_to(123.4)
            assert stage.position_mm() == pytest.approx(123.4, abs=STEP)
            assert stage.settings()["checksums"] is True
        assert emulator.bad_checksums == 0
        assert emulator.lines and all(FRAMED.fullmatch(line) and lrc_ok(line) for line in emulator.lines)


def test_driver_refuses_a_reply_with_a_wrong_checksum() -> None:
    with ZaberEmulator(mm_per_microstep=STEP, travel_mm=400.0, reply_checksums=True) as emulator:
        with ZaberStage(emulator.port, travel_mm=(0.0, 400.0), mm_per_microstep=STEP, timeout_s=2.0) as stage:
            emulator.corrupt_checksums()
            with pytest.raises(SerialGarbage, match="fails its checksum"):
                stage.position_mm()
            assert stage.position_mm() == pytest.approx(200.0)  # the next exchange is fine again


def test_a_corrupted_command_is_dropped(emulator: ZaberEmulator) -> None:
    stage = ZaberStage(emulator.port, travel_mm=(0.0, 400.0), mm_per_microstep=STEP, timeout_s=2.0, checksums=True)
    stage.connect()
    try:
        reply = stage._send("get pos")
        assert int(reply.data) == round(20.0 / STEP)
        before = len(emulator.commands)
        stage._line.write(b"/1 1 42 get pos:00\n", "get pos")  # a checksum no byte sum matches
        deadline = time.monotonic() + 5.0
        while emulator.bad_checksums == 0 and time.monotonic() < deadline:
            time.sleep(0.01)
        assert emulator.bad_checksums == 1 and len(emulator.commands) == before  # not executed ...
        assert stage._line.discard_input() == b""  # ... and unanswered
    finally:
        stage.close()


def test_campaign_setting_reaches_the_driver(emulator: ZaberEmulator) -> None:
    config = StageConfig(protocol="zaber", port=emulator.port, mm_per_microstep=STEP, travel_mm=(0, 400), checksums=True)
    stage = stage_from_config(config)
    assert isinstance(stage, ZaberStage) and stage.checksums
    with stage:
        assert stage.position_mm() == pytest.approx(20.0)
    assert all(FRAMED.fullmatch(line) and lrc_ok(line) for line in emulator.lines)


def test_speed_setting_and_relative_moves(emulator: ZaberEmulator, connection: Connection) -> None:
    command(connection, "home")
    wait_idle(connection)
    maxspeed = round(100.0 / STEP * 1.6384)  # 100 mm/s in the manual's velocity unit
    command(connection, f"set maxspeed {maxspeed}")
    assert int(command(connection, "get maxspeed").data) == maxspeed
    assert emulator.speed_mm_s == pytest.approx(100.0, rel=1e-6)
    start = time.monotonic()
    command(connection, "move rel 80000")  # 10 mm
    wait_idle(connection)
    assert time.monotonic() - start >= 0.09
    command(connection, "move rel -40000")
    wait_idle(connection)
    assert int(command(connection, "get pos").data) == 40000
    assert command(connection, "move rel -40001", check_errors=False).data == "BADDATA"  # beyond limit.min
