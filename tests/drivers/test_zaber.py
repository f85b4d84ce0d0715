"""ZaberStage against the Zaber ASCII emulator over a real pseudo-terminal."""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator

import pytest
import serial

from drivers.errors import DeviceError, DeviceVanished, LimitViolation, SerialGarbage, SerialTimeout, TransientDeviceError
from drivers.protocols import LinearStage
from drivers.stage import ZaberFlagError, ZaberRejection, ZaberStage, move_stage
from drivers.stage.zaber import MOTION_FAILURES, REJECTION_REASONS, WARNING_FLAGS
from sim.emulators import ZaberEmulator
from tests.drivers.manuals import load

DOCUMENTED_REASONS = [entry["code"] for entry in load("zaber_ascii.toml")["reason"]]
DOCUMENTED_FAULTS = [entry["code"] for entry in load("zaber_ascii.toml")["flag"] if entry["code"].startswith("F")]

#: driver reply timeout (s) in these tests: generous, the emulator's thread may wait for a loaded CPU
REPLY_TIMEOUT_S = 3.0
#: long enough for a move the test interrupts, however late its interruption comes
MOVE_TIMEOUT_S = 60.0
#: seconds within which a request that the emulator drops would have been answered
FAST = 0.3
MM_PER_MICROSTEP = 0.000125  # an unround resolution, so that a mm/microstep mix-up cannot pass


@pytest.fixture
def zaber_emulator() -> Iterator[ZaberEmulator]:
    emulator = ZaberEmulator(mm_per_microstep=MM_PER_MICROSTEP, travel_mm=400.0, speed_mm_s=1000.0, start_mm=20.0)
    with emulator:
        yield emulator


def make_stage(emulator: ZaberEmulator, **options: object) -> ZaberStage:
    settings: dict[str, object] = {
        "travel_mm": (0.0, 400.0),
        "mm_per_microstep": MM_PER_MICROSTEP,
        "timeout_s": REPLY_TIMEOUT_S,
        "move_timeout_s": MOVE_TIMEOUT_S,
        "poll_interval_s": 0.005,
    }
    settings.update(options)
    return ZaberStage(emulator.port, **settings)  # type: ignore[arg-type]


@pytest.fixture
def stage(zaber_emulator: ZaberEmulator) -> Iterator[ZaberStage]:
    device = make_stage(zaber_emulator)
    device.connect()
    yield device
    device.close()


def wait_until_moving(emulator: ZaberEmulator, beyond_mm: float = 0.0) -> None:
    """Until the carriage moves (and is past ``beyond_mm``), within a minute."""
    deadline = time.monotonic() + 60.0
    while not (emulator.moving and emulator.position_mm > beyond_mm):
        assert time.monotonic() < deadline, "the carriage did not move"
        time.sleep(0.005)


@pytest.fixture
def homed(stage: ZaberStage) -> ZaberStage:
    stage.home()
    return stage


def moves_sent(emulator: ZaberEmulator) -> list[str]:
    with emulator.lock:
        return [c for c in emulator.commands if c.startswith(("move", "home"))]


def test_is_a_linear_stage(stage: ZaberStage) -> None:
    assert isinstance(stage, LinearStage)


def test_identity_and_settings(stage: ZaberStage, zaber_emulator: ZaberEmulator) -> None:
    identity = stage.identity()
    assert (identity.backend, identity.model, identity.serial, identity.firmware) == (
        "zaber",
        "Zaber device ID 50081",
        "123456",
        "7.38",
    )
    settings = stage.settings()
    assert settings["device_range_mm"] == [0.0, 400.0]
    assert settings["max_speed_mm_s"] == pytest.approx(1000.0, rel=1e-4)
    assert settings["travel_mm"] == [0.0, 400.0] and settings["port"] == zaber_emulator.port


def test_home_then_move_and_read_back(stage: ZaberStage, zaber_emulator: ZaberEmulator) -> None:
    stage.home()
    assert zaber_emulator.referenced and stage.position_mm() == 0.0
    start = time.monotonic()
    stage.move_to(123.456)
    elapsed = time.monotonic() - start
    assert not zaber_emulator.moving  # move_to returned only once idle ...
    assert elapsed >= 0.12  # ... after travelling 123 mm at 1000 mm/s
    assert stage.position_mm() == pytest.approx(123.456, abs=MM_PER_MICROSTEP)
    assert zaber_emulator.position_mm == pytest.approx(123.456, abs=MM_PER_MICROSTEP)
    with zaber_emulator.lock:
        assert f"move abs {round(123.456 / MM_PER_MICROSTEP)}" in zaber_emulator.commands


@pytest.mark.parametrize("target", [-0.001, 400.001, float("nan")])
def test_move_outside_soft_limits_is_refused_before_anything_moved(
    homed: ZaberStage, zaber_emulator: ZaberEmulator, target: float
) -> None:
    before = len(zaber_emulator.commands)
    with pytest.raises(LimitViolation, match="outside the soft limits .*nothing moved"):
        homed.move_to(target)
    assert len(zaber_emulator.commands) == before  # not even a query was sent
    assert homed.position_mm() == 0.0


def test_move_before_homing_is_refused(stage: ZaberStage, zaber_emulator: ZaberEmulator) -> None:
    start = zaber_emulator.position_mm
    with pytest.raises(ZaberFlagError, match="nothing moved: warning flag WR: no reference position") as caught:
        stage.move_to(10.0)
    assert caught.value.flag == "WR"
    assert moves_sent(zaber_emulator) == [] and zaber_emulator.position_mm == start


def test_device_refuses_move_without_reference(stage: ZaberStage) -> None:
    with pytest.raises(ZaberRejection, match="BADCOMMAND.*active flag WR") as caught:
        stage._send("move abs 100")
    assert caught.value.reason == "BADCOMMAND"


@pytest.mark.parametrize("reason", DOCUMENTED_REASONS)
def test_each_rejection_reason_maps_to_its_meaning(
    homed: ZaberStage, zaber_emulator: ZaberEmulator, reason: str
) -> None:
    zaber_emulator.reject_next(reason)
    with pytest.raises(ZaberRejection) as caught:
        homed.position_mm()
    assert caught.value.reason == reason
    assert f"{reason}: {REJECTION_REASONS[reason]}" in str(caught.value)
    assert zaber_emulator.port in str(caught.value)


def test_bad_axis_and_device_only_rejections_from_the_device(zaber_emulator: ZaberEmulator) -> None:
    with pytest.raises(ZaberRejection, match="BADAXIS"):
        make_stage(zaber_emulator, axis=2).connect()
    stage = make_stage(zaber_emulator)
    stage.connect()
    with pytest.raises(ZaberRejection, match="DEVICEONLY"):
        stage._send("get deviceid", axis=1)


@pytest.mark.parametrize("flag", DOCUMENTED_FAULTS)
def test_active_fault_refuses_motion(homed: ZaberStage, zaber_emulator: ZaberEmulator, flag: str) -> None:
    zaber_emulator.raise_flag(flag)
    with pytest.raises(ZaberFlagError, match=f"nothing moved: warning flag {flag}: ") as caught:
        homed.move_to(50.0)
    assert caught.value.meaning == WARNING_FLAGS[flag]
    assert moves_sent(zaber_emulator) == ["home"]
    with pytest.raises(ZaberFlagError, match=flag):  # also on a plain query
        homed.position_mm()


@pytest.mark.parametrize("flag", [*sorted(MOTION_FAILURES - {"WR", "WH"}), "FS", "FE"])
def test_flag_raised_during_a_move(homed: ZaberStage, zaber_emulator: ZaberEmulator, flag: str) -> None:
    zaber_emulator.interrupt_next_move(at_mm=30.0, flag=flag)
    with pytest.raises(ZaberFlagError, match=f"'move abs 800000' failed: warning flag {flag}"):
        homed.move_to(100.0)
    assert zaber_emulator.position_mm == pytest.approx(30.0, abs=MM_PER_MICROSTEP)


def test_warnings_are_cleared_and_logged_before_a_move(
    homed: ZaberStage, zaber_emulator: ZaberEmulator, caplog: pytest.LogCaptureFixture
) -> None:
    zaber_emulator.raise_flag("WT")
    homed.move_to(5.0)
    assert "cleared WT (controller temperature high: above the recommended limit)" in caplog.text
    assert homed.position_mm() == pytest.approx(5.0)


def test_homing_that_cannot_reach_the_home_sensor(stage: ZaberStage, zaber_emulator: ZaberEmulator) -> None:
    zaber_emulator.interrupt_next_move(at_mm=10.0, flag="FE")
    with pytest.raises(ZaberFlagError, match="'home' failed: warning flag FE: limit error"):
        stage.home()
    assert not zaber_emulator.referenced


def test_slow_reply_times_out_and_the_late_reply_is_ignored(homed: ZaberStage, zaber_emulator: ZaberEmulator) -> None:
    zaber_emulator.delay_replies(REPLY_TIMEOUT_S + 0.5)
    with pytest.raises(SerialTimeout, match=r"expected '@01 1 \d\d \.\.\.' in reply to 'get pos'") as caught:
        homed.position_mm()
    assert isinstance(caught.value, TransientDeviceError)
    zaber_emulator.delay_replies(0.05)  # the late reply arrives while the next command waits (or before it)
    homed.move_to(7.0)
    assert homed.position_mm() == pytest.approx(7.0)


def test_garbage_reply(homed: ZaberStage, zaber_emulator: ZaberEmulator) -> None:
    zaber_emulator.garble_replies()
    with pytest.raises(SerialGarbage, match="non-ASCII reply"):
        homed.position_mm()
    assert homed.position_mm() == 0.0


def test_disconnect_during_a_move(homed: ZaberStage, zaber_emulator: ZaberEmulator) -> None:
    zaber_emulator.speed_mm_s = 20.0  # 20 s of travel; the cable goes once the carriage moves
    port = zaber_emulator.port
    cable = threading.Thread(target=lambda: (wait_until_moving(zaber_emulator), zaber_emulator.disconnect()))
    cable.start()
    with pytest.raises(DeviceVanished, match="failed or vanished") as caught:
        homed.move_to(399.0)
    cable.join()
    assert not isinstance(caught.value, TransientDeviceError) and caught.value.connection == port
    homed.safe_state()  # must not raise
    homed.close()


def test_stop_from_another_thread_interrupts_a_move(homed: ZaberStage, zaber_emulator: ZaberEmulator) -> None:
    zaber_emulator.speed_mm_s = 20.0  # 20 s of travel; stopped once the carriage has moved 1 mm
    stopper = threading.Thread(target=lambda: (wait_until_moving(zaber_emulator, beyond_mm=1.0), homed.safe_state()))
    stopper.start()
    with pytest.raises(DeviceError, match="stopped at .* instead of 399.0 mm"):
        homed.move_to(399.0)
    stopper.join()
    assert not zaber_emulator.moving
    assert 1.0 < zaber_emulator.position_mm < 390.0


def test_safe_state_after_a_failure_and_recovery(homed: ZaberStage, zaber_emulator: ZaberEmulator) -> None:
    zaber_emulator.interrupt_next_move(at_mm=20.0, flag="WL")
    with pytest.raises(ZaberFlagError, match="WL"):
        homed.move_to(50.0)
    homed.safe_state()
    homed.move_to(10.0)  # the WL flag was cleared before the next move
    assert homed.position_mm() == pytest.approx(10.0)


def test_move_timeout_stops_the_stage(zaber_emulator: ZaberEmulator) -> None:
    stage = make_stage(zaber_emulator)
    stage.connect()
    stage.home()  # with the default time limit: a loaded machine may need more than 0.05 s
    zaber_emulator.speed_mm_s = 20.0  # 19 s of travel: still moving when the driver looks, however late
    stage.move_timeout_s = 0.05
    with pytest.raises(DeviceError, match="still moving after 0.05 s; sent stop"):
        stage.move_to(399.0)
    assert not zaber_emulator.moving


def test_travel_beyond_the_device_range(zaber_emulator: ZaberEmulator) -> None:
    with pytest.raises(DeviceError, match=r"travel \[0.0, 500.0\] mm exceeds the device range"):
        make_stage(zaber_emulator, travel_mm=(0.0, 500.0)).connect()


def test_safe_state_without_connection_is_harmless() -> None:
    stage = ZaberStage("/dev/does-not-exist", travel_mm=(0, 1), mm_per_microstep=1e-3)
    stage.safe_state()
    with pytest.raises(DeviceError, match="does-not-exist.*cannot open the port"):
        stage.connect()


def test_move_stage_helper(zaber_emulator: ZaberEmulator) -> None:
    position = move_stage(zaber_emulator.port, "zaber", home=True, move_mm=42.0, mm_per_microstep=MM_PER_MICROSTEP)
    assert position == pytest.approx(42.0)
    with pytest.raises(ValueError, match="unknown stage protocol 'thorlabs'"):
        move_stage(zaber_emulator.port, "thorlabs")


@pytest.mark.parametrize(
    ("request_line", "reply"),
    [
        (b"/1 1 01 get pos:2B\n", b"@01 1 01 OK IDLE WR 160000\r\n"),  # zaber-motion's framing
        (b"/1 1 00:FE\n", b"@01 1 00 OK IDLE WR 0\r\n"),  # empty command: LRC of '1 1 00' is FE
        (b"/\n", b"@01 0 OK IDLE WR 0\r\n"),  # '/' alone: every device answers
        (b"/1 1 get pos\r\n", b"@01 1 OK IDLE WR 160000\r\n"),  # no ID, no checksum, CR LF
        (b"/1 1 -- get pos\n", b"@01 1 -- OK IDLE WR 160000\r\n"),
        (b"/1 1 123 get pos\n", b"@01 1 123 RJ IDLE WR BADMESSAGEID\r\n"),
        (b"/2 1 01 get pos\n/1 1 02 get pos\n", b"@01 1 02 OK IDLE WR 160000\r\n"),  # device 2 is not there
    ],
)
def test_raw_framing(zaber_emulator: ZaberEmulator, request_line: bytes, reply: bytes) -> None:
    with serial.Serial(zaber_emulator.port, 115200, timeout=2.0) as port:
        port.write(request_line)
        assert port.readline() == reply


def test_command_with_a_wrong_checksum_is_dropped(zaber_emulator: ZaberEmulator) -> None:
    with serial.Serial(zaber_emulator.port, 115200, timeout=FAST) as port:
        port.write(b"/1 1 00:FF\n")  # the LRC of '1 1 00' is FE
        deadline = time.monotonic() + 5.0
        while zaber_emulator.bad_checksums == 0 and time.monotonic() < deadline:
            time.sleep(0.01)
        assert zaber_emulator.bad_checksums == 1
        assert port.readline() == b""  # dropped: no reply within FAST
        port.timeout = 2.0
        zaber_emulator.reply_checksums = True  # comm.checksum 1: replies carry one too
        port.write(b"/1 0 07 get deviceid\n")
        line = port.readline()
        assert line.startswith(b"@01 0 07 OK IDLE WR 50081:")
        assert (sum(line[1:-5]) + int(line[-4:-2], 16)) % 256 == 0


def test_alerts_and_info_messages_before_a_reply_are_skipped(
    stage: ZaberStage, zaber_emulator: ZaberEmulator
) -> None:
    with zaber_emulator.lock:
        zaber_emulator.alerts = True  # comm.alert 1: '!01 1 IDLE --' when a movement ends
    stage.home()
    zaber_emulator.messages_before_next_reply("!01 1 IDLE --", "#01 1 07 a note")
    assert stage.position_mm() == 0.0
    stage.move_to(12.5)
    assert stage.position_mm() == pytest.approx(12.5)
