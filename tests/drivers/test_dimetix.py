"""DimetixLaser against the Dimetix emulator over a real pseudo-terminal."""

from __future__ import annotations

import time
from collections.abc import Iterator

import pytest

from drivers.errors import DeviceError, DeviceVanished, SerialGarbage, SerialTimeout, TransientDeviceError
from drivers.laser import DimetixError, DimetixLaser, DimetixTargetError, read_distances
from drivers.laser.dimetix import ERROR_CODES, TARGET_ERROR_CODES, UNKNOWN
from drivers.protocols import RangeMeter
from sim.emulators import DimetixEmulator
from tests.drivers.manuals import load

DOCUMENTED_CODES = [entry["code"] for entry in load("dimetix_error_codes.toml")["code"]]

#: driver reply timeout (s) in these tests: generous, the emulator's thread may wait for a loaded CPU
REPLY_TIMEOUT_S = 3.0


@pytest.fixture
def dimetix_emulator() -> Iterator[DimetixEmulator]:
    with DimetixEmulator(distance_mm=1234.5) as emulator:
        yield emulator


@pytest.fixture
def laser(dimetix_emulator: DimetixEmulator) -> Iterator[DimetixLaser]:
    meter = DimetixLaser(dimetix_emulator.port, timeout_s=REPLY_TIMEOUT_S)
    meter.connect()
    yield meter
    meter.close()


def test_is_a_range_meter(laser: DimetixLaser) -> None:
    assert isinstance(laser, RangeMeter)


def test_measure_returns_the_distance_in_mm(laser: DimetixLaser, dimetix_emulator: DimetixEmulator) -> None:
    assert laser.measure_mm() == 1234.5
    dimetix_emulator.distance_mm = 3999.9
    assert laser.measure_mm() == 3999.9


def test_identity_and_settings(laser: DimetixLaser, dimetix_emulator: DimetixEmulator) -> None:
    identity = laser.identity()
    assert (identity.backend, identity.serial, identity.firmware) == ("dimetix", "12345678", "01230456")
    assert laser.settings() == {
        "port": dimetix_emulator.port,
        "baud": 19200,
        "format": "7E1",
        "device_id": 0,
        "timeout_s": REPLY_TIMEOUT_S,
    }


@pytest.mark.parametrize("code", DOCUMENTED_CODES)
def test_each_error_code_maps_to_its_documented_meaning(
    laser: DimetixLaser, dimetix_emulator: DimetixEmulator, code: int
) -> None:
    dimetix_emulator.inject_error(code)
    with pytest.raises(DimetixError) as caught:
        laser.measure_mm()
    error = caught.value
    assert error.code == code
    assert error.meaning == ERROR_CODES[code]
    assert f"E{code}" in str(error) and ERROR_CODES[code] in str(error)
    assert dimetix_emulator.port in str(error)
    assert isinstance(error, TransientDeviceError) == (code in TARGET_ERROR_CODES)
    assert laser.measure_mm() == 1234.5  # the sensor stays usable


def test_weak_signal_is_transient_and_temperature_is_fatal(
    laser: DimetixLaser, dimetix_emulator: DimetixEmulator
) -> None:
    dimetix_emulator.inject_error(255)
    with pytest.raises(DimetixTargetError, match="too weak"):
        laser.measure_mm()
    dimetix_emulator.inject_error(252)
    with pytest.raises(DimetixError, match="temperature too high") as caught:
        laser.measure_mm()
    assert not isinstance(caught.value, TransientDeviceError)


def test_undocumented_error_code(laser: DimetixLaser, dimetix_emulator: DimetixEmulator) -> None:
    dimetix_emulator.inject_error(999)
    with pytest.raises(DimetixError, match="E999: undocumented"):
        laser.measure_mm()


@pytest.mark.realtime
def test_slow_reply_times_out_then_recovers(laser: DimetixLaser, dimetix_emulator: DimetixEmulator) -> None:
    dimetix_emulator.delay_replies(REPLY_TIMEOUT_S + 0.5)
    start = time.monotonic()
    with pytest.raises(SerialTimeout, match="expected 'g0g...' in reply to 's0g'") as caught:
        laser.measure_mm()
    assert REPLY_TIMEOUT_S <= time.monotonic() - start < REPLY_TIMEOUT_S + 2.0  # bounded: never hangs
    assert dimetix_emulator.port in str(caught.value)
    dimetix_emulator.wait_quiet(timeout_s=30.0)
    assert laser.measure_mm() == 1234.5


def test_garbage_reply(laser: DimetixLaser, dimetix_emulator: DimetixEmulator) -> None:
    dimetix_emulator.garble_replies()
    with pytest.raises(SerialGarbage, match="non-ASCII reply"):
        laser.measure_mm()
    assert laser.measure_mm() == 1234.5


def test_reply_of_the_wrong_shape_is_garbage(laser: DimetixLaser, dimetix_emulator: DimetixEmulator) -> None:
    with dimetix_emulator.lock:
        dimetix_emulator.software_version = "1.2"
    with pytest.raises(SerialGarbage, match="expected 'g0g...'"):
        laser._request("sv", "g")


def test_other_device_id_gets_no_answer(dimetix_emulator: DimetixEmulator) -> None:
    meter = DimetixLaser(dimetix_emulator.port, device_id=3, timeout_s=0.1)
    with pytest.raises(SerialTimeout, match="g3"):
        meter.connect()
    with pytest.raises(DeviceError, match="not connected"):
        meter.measure_mm()


def test_disconnect_is_fatal_and_safe_state_still_returns(
    laser: DimetixLaser, dimetix_emulator: DimetixEmulator
) -> None:
    port = dimetix_emulator.port
    dimetix_emulator.disconnect()
    with pytest.raises(DeviceVanished, match="failed or vanished") as caught:
        laser.measure_mm()
    assert not isinstance(caught.value, TransientDeviceError) and caught.value.connection == port
    laser.safe_state()
    laser.close()


def test_missing_port() -> None:
    with pytest.raises(DeviceError, match="/dev/does-not-exist.*cannot open the port"):
        DimetixLaser("/dev/does-not-exist").connect()


def test_safe_state_switches_laser_off_and_stops_tracking(
    laser: DimetixLaser, dimetix_emulator: DimetixEmulator
) -> None:
    laser.start_tracking()
    assert dimetix_emulator.tracking and dimetix_emulator.laser_on
    laser.safe_state()
    assert not dimetix_emulator.tracking and not dimetix_emulator.laser_on
    assert dimetix_emulator.commands[-2:] == ["c", "p"]  # stop/clear, then laser off


def test_safe_state_after_a_failure(laser: DimetixLaser, dimetix_emulator: DimetixEmulator) -> None:
    laser.laser_on()
    dimetix_emulator.inject_error(256)
    with pytest.raises(DimetixTargetError):
        laser.measure_mm()
    laser.safe_state()
    assert not dimetix_emulator.laser_on


def test_safe_state_without_connection_is_harmless() -> None:
    DimetixLaser("/dev/does-not-exist").safe_state()


def test_laser_on_and_off(laser: DimetixLaser, dimetix_emulator: DimetixEmulator) -> None:
    laser.laser_on()
    assert dimetix_emulator.laser_on
    laser.laser_off()
    assert not dimetix_emulator.laser_on


def test_tracking_with_buffering(laser: DimetixLaser, dimetix_emulator: DimetixEmulator) -> None:
    laser.start_tracking(sample_time_s=0.05)
    assert laser.read_tracking() is None  # nothing measured yet
    deadline = time.monotonic() + 30.0  # generous: the emulator's thread may wait for a loaded CPU
    while (value := laser.read_tracking()) is None:  # the first sample, 0.05 s later on an idle machine
        assert time.monotonic() < deadline, "no tracking sample"
        time.sleep(0.01)
    assert value == 1234.5
    with pytest.raises(DimetixError, match="E212: command not possible while tracking"):
        laser.measure_mm()
    dimetix_emulator.inject_error(255)
    with pytest.raises(DimetixTargetError, match="E255"):
        while True:  # the samples already taken, then the failed one
            assert laser.read_tracking() == 1234.5 and time.monotonic() < deadline + 30.0
            time.sleep(0.01)
    laser.stop_tracking()
    assert not dimetix_emulator.tracking
    with pytest.raises(DimetixError, match="E210: not in tracking mode"):
        laser.read_tracking()


def test_read_distances_helper() -> None:
    with DimetixEmulator(distance_mm=800.0, noise_mm=0.5, seed=1) as emulator:
        distances = read_distances(emulator.port, count=5)
        assert len(distances) == 5
        assert all(abs(d - 800.0) < 3.0 for d in distances)
        assert len(set(distances)) > 1
        assert not emulator.laser_on


def test_sensor_without_identity_queries_is_unknown_not_refused(caplog: pytest.LogCaptureFixture) -> None:
    with DimetixEmulator(distance_mm=987.6, identity_commands=False) as emulator:
        port = emulator.port
        with DimetixLaser(port, timeout_s=REPLY_TIMEOUT_S) as laser:
            identity = laser.identity()
            assert (identity.backend, identity.serial, identity.firmware) == ("dimetix", UNKNOWN, UNKNOWN)
            assert laser.measure_mm() == 987.6  # it measures all the same
        assert emulator.commands[:3] == ["c", "sn", "sv"]
    warnings = [r for r in caplog.records if r.levelname == "WARNING" and "dimetix" in r.name]
    assert len(warnings) == 2
    assert "serial number unknown: 's0sn' answered E203 (wrong command syntax" in warnings[0].getMessage()
    assert "software version unknown: 's0sv' answered E203" in warnings[1].getMessage()
    assert port in warnings[0].getMessage()


def test_identity_query_that_times_out_is_still_refused() -> None:
    with DimetixEmulator() as emulator:
        laser = DimetixLaser(emulator.port, timeout_s=REPLY_TIMEOUT_S)
        emulator.delay_replies(0.0)  # 's0c' answers at once
        emulator.delay_replies(REPLY_TIMEOUT_S + 0.5)  # 's0sn' answers too late
        with pytest.raises(SerialTimeout, match="'g0sn\\+...' in reply to 's0sn'"):
            laser.connect()
        with pytest.raises(DeviceError, match="not connected"):
            laser.identity()


def test_tracking_mode_refuses_everything_but_stop_and_read(
    laser: DimetixLaser, dimetix_emulator: DimetixEmulator
) -> None:
    laser.start_tracking(0.02)
    for command in (laser.laser_on, laser.laser_off, laser.measure_mm, lambda: laser.start_tracking(0.02)):
        with pytest.raises(DimetixError, match="E212") as caught:
            command()
        assert caught.value.code == 212
    assert dimetix_emulator.tracking
    laser.stop_tracking()
    laser.laser_on()
    assert dimetix_emulator.laser_on


def test_sampling_faster_than_a_measurement_is_refused(laser: DimetixLaser, dimetix_emulator: DimetixEmulator) -> None:
    with dimetix_emulator.lock:
        dimetix_emulator.measure_time_s = 0.05
    with pytest.raises(DimetixError, match="E211: sampling too fast"):
        laser.start_tracking(0.01)
    assert not dimetix_emulator.tracking
    laser.start_tracking(0.0)  # 0: as fast as the sensor can
    assert dimetix_emulator.tracking


def test_start_sequence_after_power_on_is_not_taken_for_a_reply(dimetix_emulator: DimetixEmulator) -> None:
    with DimetixLaser(dimetix_emulator.port, timeout_s=REPLY_TIMEOUT_S) as laser:  # 'g0?' waits in the line
        assert laser.identity().serial == "12345678"
        assert laser.measure_mm() == 1234.5


def test_restart_sequence_and_other_sensors_lines_are_skipped(
    laser: DimetixLaser, dimetix_emulator: DimetixEmulator
) -> None:
    dimetix_emulator.stray_lines_before_next_reply("g0?", "g7g+00000010")
    assert laser.measure_mm() == 1234.5
    dimetix_emulator.stray_lines_before_next_reply("g7?")
    laser.laser_on()  # '?' is the awaited reply here, but not from sensor 7
    assert dimetix_emulator.laser_on
