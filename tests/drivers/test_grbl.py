"""GrblStage against the Grbl 1.1 emulator over a real pseudo-terminal."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Iterator

import pytest

from drivers.errors import DeviceError, DeviceVanished, LimitViolation, SerialGarbage, SerialTimeout, TransientDeviceError
from drivers.protocols import LinearStage
from drivers.stage import GrblAlarm, GrblError, GrblStage, move_stage
from drivers.stage.grbl import ALARM_CODES, ERROR_CODES
from sim.emulators import GrblEmulator

FAST = 1.0  # driver reply timeout (s) in these tests: generous, the test machine may be loaded
FEED = 60_000.0  # mm/min = 1000 mm/s


@pytest.fixture
def grbl_emulator() -> Iterator[GrblEmulator]:
    with GrblEmulator(max_travel_mm=400.0, max_rate_mm_min=FEED, start_mm=20.0) as emulator:
        yield emulator


def make_stage(emulator: GrblEmulator, **options: object) -> GrblStage:
    settings: dict[str, object] = {
        "travel_mm": (0.0, 400.0),
        "feed_mm_min": FEED,
        "timeout_s": FAST,
        "home_timeout_s": 30.0,
        "move_timeout_s": 60.0,  # longer than any move a test interrupts, however late the interruption
        "poll_interval_s": 0.005,
    }
    settings.update(options)
    return GrblStage(emulator.port, **settings)  # type: ignore[arg-type]


@pytest.fixture
def stage(grbl_emulator: GrblEmulator) -> Iterator[GrblStage]:
    device = make_stage(grbl_emulator)
    device.connect()
    yield device
    device.close()


@pytest.fixture
def homed(stage: GrblStage) -> GrblStage:
    stage.home()
    return stage


def once_moving(emulator: GrblEmulator, action: Callable[[], object], beyond_mm: float = 0.0) -> threading.Thread:
    """A started thread that calls ``action`` once the emulated axis jogs or runs (and is past ``beyond_mm``),
    within a minute."""

    def wait_then_act() -> None:
        deadline = time.monotonic() + 60.0
        while emulator.state not in ("Jog", "Run") or emulator.position_mm <= beyond_mm:
            assert time.monotonic() < deadline, "the axis did not move"
            time.sleep(0.005)
        action()

    thread = threading.Thread(target=wait_then_act)
    thread.start()
    return thread


def jogs_sent(emulator: GrblEmulator) -> list[str]:
    with emulator.lock:
        return [line for line in emulator.lines if line.startswith("$J=")]


def test_is_a_linear_stage(stage: GrblStage) -> None:
    assert isinstance(stage, LinearStage)


def test_identity_and_settings(grbl_emulator: GrblEmulator) -> None:
    grbl_emulator.info = "stage-7"
    stage = make_stage(grbl_emulator)
    stage.connect()
    identity = stage.identity()
    assert (identity.backend, identity.model, identity.serial, identity.firmware) == (
        "grbl",
        "Grbl controller",
        "stage-7",
        "1.1h.20190830",
    )
    settings = stage.settings()
    assert settings["grbl"]["$130"] == "400" and settings["grbl"]["$22"] == "1"
    assert settings["axis"] == "X" and settings["travel_mm"] == [0.0, 400.0]


def test_home_then_move_and_read_back(stage: GrblStage, grbl_emulator: GrblEmulator) -> None:
    stage.home()
    assert grbl_emulator.state == "Idle" and stage.position_mm() == 0.0
    start = time.monotonic()
    stage.move_to(123.456)
    assert time.monotonic() - start >= 0.12  # 123 mm at 1000 mm/s, waited until Idle
    assert grbl_emulator.state == "Idle"
    assert stage.position_mm() == pytest.approx(123.456, abs=1e-3)
    assert jogs_sent(grbl_emulator) == ["$J=G53G90G21X123.456F60000"]


def test_lines_end_in_lf_only(homed: GrblStage, grbl_emulator: GrblEmulator) -> None:
    homed.move_to(1.0)
    with grbl_emulator.lock:
        assert "" not in grbl_emulator.lines[1:]  # only the link check was an empty line


@pytest.mark.parametrize("target", [-0.5, 400.5, float("nan")])
def test_move_outside_soft_limits_is_refused_before_anything_moved(
    homed: GrblStage, grbl_emulator: GrblEmulator, target: float
) -> None:
    with pytest.raises(LimitViolation, match="outside the soft limits .*nothing moved"):
        homed.move_to(target)
    assert jogs_sent(grbl_emulator) == [] and grbl_emulator.position_mm == 0.0


def test_move_before_homing_is_refused(stage: GrblStage, grbl_emulator: GrblEmulator) -> None:
    message = "nothing moved; home .or unlock. first: alarm state: motion locked until homing"
    with pytest.raises(GrblAlarm, match=message) as caught:
        stage.move_to(10.0)
    assert caught.value.code is None
    assert jogs_sent(grbl_emulator) == [] and grbl_emulator.position_mm == 20.0


def test_target_beyond_the_machine_travel_is_refused_by_grbl(grbl_emulator: GrblEmulator) -> None:
    stage = make_stage(grbl_emulator, travel_mm=(0.0, 500.0))
    stage.connect()
    stage.home()
    with pytest.raises(GrblError, match=r"error:15: Jog target exceeds machine travel") as caught:
        stage.move_to(450.0)
    assert caught.value.code == 15 and grbl_emulator.position_mm == 0.0


@pytest.mark.parametrize("code", sorted(ERROR_CODES))
def test_each_error_code_maps_to_its_meaning(homed: GrblStage, grbl_emulator: GrblEmulator, code: int) -> None:
    grbl_emulator.inject_error(code)
    with pytest.raises(GrblError) as caught:
        homed.move_to(10.0)
    assert caught.value.code == code
    assert f"error:{code}: {ERROR_CODES[code]}" in str(caught.value)
    assert grbl_emulator.port in str(caught.value)
    assert grbl_emulator.position_mm == 0.0


@pytest.mark.parametrize("code", sorted(ALARM_CODES))
def test_each_alarm_during_a_move_maps_to_its_meaning(homed: GrblStage, grbl_emulator: GrblEmulator, code: int) -> None:
    homed.feed_mm_min = 600.0  # 40 s of travel; the alarm comes once the axis moves
    alarm = once_moving(grbl_emulator, lambda: grbl_emulator.inject_alarm(code))
    with pytest.raises(GrblAlarm) as caught:
        homed.move_to(399.0)
    alarm.join()
    assert caught.value.code == code
    assert f"ALARM:{code}: {ALARM_CODES[code]}" in str(caught.value)
    assert grbl_emulator.state == "Alarm" and grbl_emulator.position_mm < 100.0
    homed.safe_state()  # must not raise, also while Grbl waits for a reset
    homed.home()  # recovers, with a soft reset first after a limit alarm
    homed.feed_mm_min = FEED
    homed.move_to(5.0)
    assert homed.position_mm() == pytest.approx(5.0)


def test_hard_limit_during_a_move(homed: GrblStage, grbl_emulator: GrblEmulator) -> None:
    grbl_emulator.trip_hard_limit_at(100.0)
    with pytest.raises(GrblAlarm, match="ALARM:1: Hard limit has been triggered") as caught:
        homed.move_to(300.0)
    assert caught.value.code == 1
    assert grbl_emulator.position_mm == pytest.approx(100.0)
    with pytest.raises(GrblAlarm, match="no status report until a soft reset"):
        homed.position_mm()
    with pytest.raises(GrblAlarm, match="nothing moved"):
        homed.move_to(50.0)


def test_alarm_pushed_while_idle_is_noticed_before_moving(homed: GrblStage, grbl_emulator: GrblEmulator) -> None:
    grbl_emulator.inject_alarm(2)
    grbl_emulator.wait_quiet()
    with pytest.raises(GrblAlarm, match="nothing moved; home .or unlock. first: ALARM:2: Soft limit alarm"):
        homed.move_to(50.0)
    assert jogs_sent(grbl_emulator) == []


def test_homing_failure(stage: GrblStage, grbl_emulator: GrblEmulator) -> None:
    grbl_emulator.fail_homing(9)
    with pytest.raises(GrblAlarm, match="ALARM:9: Homing fail. Could not find limit switch"):
        stage.home()


def test_homing_disabled() -> None:
    with GrblEmulator(homing_enabled=False) as emulator:
        stage = make_stage(emulator)
        stage.connect()
        with pytest.raises(GrblError, match=r"'\$H' answered error:5: Homing cycle failure. Homing is not enabled"):
            stage.home()


def test_board_that_reboots_when_the_port_opens() -> None:
    with GrblEmulator(boot_s=0.5) as emulator:
        stage = make_stage(emulator, timeout_s=0.2)
        stage.connect()  # retries the link check until the boot loader hands over
        assert stage.identity().firmware == "1.1h.20190830"


def test_slow_reply_times_out_then_recovers(homed: GrblStage, grbl_emulator: GrblEmulator) -> None:
    grbl_emulator.delay_replies(FAST + 0.1)
    with pytest.raises(SerialTimeout, match=r"expected a status report '<State\|MPos:...>' for '\?'") as caught:
        homed.position_mm()
    assert isinstance(caught.value, TransientDeviceError)
    grbl_emulator.wait_quiet()
    homed.move_to(3.0)
    assert homed.position_mm() == pytest.approx(3.0)


def test_a_late_status_report_during_a_move_is_asked_for_again(homed: GrblStage, grbl_emulator: GrblEmulator) -> None:
    homed.feed_mm_min = 6000.0  # 4 s for 400 mm; the late report comes while the axis moves
    late = once_moving(grbl_emulator, lambda: grbl_emulator.delay_replies(FAST + 0.1))
    homed.move_to(400.0)
    late.join()
    assert grbl_emulator.position_mm == pytest.approx(400.0) and grbl_emulator.state == "Idle"


def test_garbage_reply(homed: GrblStage, grbl_emulator: GrblEmulator) -> None:
    grbl_emulator.garble_replies()
    with pytest.raises(SerialGarbage, match="non-ASCII reply"):
        homed.position_mm()
    assert homed.position_mm() == 0.0


def test_disconnect_during_a_move(homed: GrblStage, grbl_emulator: GrblEmulator) -> None:
    homed.feed_mm_min = 1200.0  # 20 s of travel; the cable goes once the axis moves
    port = grbl_emulator.port
    cable = once_moving(grbl_emulator, grbl_emulator.disconnect)
    with pytest.raises(DeviceVanished, match="failed or vanished") as caught:
        homed.move_to(399.0)
    cable.join()
    assert not isinstance(caught.value, TransientDeviceError) and caught.value.connection == port
    homed.safe_state()  # must not raise
    homed.close()


def test_feed_hold_from_another_thread_interrupts_a_move(homed: GrblStage, grbl_emulator: GrblEmulator) -> None:
    homed.feed_mm_min = 1200.0  # 20 s of travel; held once the axis is 1 mm on its way
    hold = once_moving(grbl_emulator, homed.safe_state, beyond_mm=1.0)
    with pytest.raises(DeviceError, match="stopped at .* instead of 399.0 mm"):
        homed.move_to(399.0)
    hold.join()
    assert grbl_emulator.state == "Idle" and 1.0 < grbl_emulator.position_mm < 390.0


def test_move_timeout_stops_the_jog(grbl_emulator: GrblEmulator) -> None:
    stage = make_stage(grbl_emulator, move_timeout_s=0.05, feed_mm_min=1200.0)  # 20 s: still moving, however late
    stage.connect()
    stage.home()
    with pytest.raises(DeviceError, match="still moving after 0.05 s; stopped"):
        stage.move_to(399.0)
    assert grbl_emulator.state == "Idle"


def test_safe_state_without_connection_is_harmless() -> None:
    stage = GrblStage("/dev/does-not-exist", travel_mm=(0, 1))
    stage.safe_state()
    with pytest.raises(DeviceError, match="does-not-exist.*cannot open the port"):
        stage.connect()


def test_move_stage_helper(grbl_emulator: GrblEmulator) -> None:
    assert move_stage(grbl_emulator.port, "grbl", home=True, move_mm=42.0, feed_mm_min=FEED) == pytest.approx(42.0)
    assert grbl_emulator.state == "Idle"
