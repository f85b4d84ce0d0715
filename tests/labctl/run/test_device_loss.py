"""Devices that vanish in the middle of a real-lab run, and the run continued on the re-plugged device.

A serial adapter unplugged is its pseudo-terminal closed under the driver (the emulator's
``disconnect``: the next read or write fails with EIO, as on a USB-serial adapter pulled out);
a lost robot connection is the UR controller emulator's servers closed under ur-rtde's clients.
The run must end with exit 1 and one message naming the device and its port, no traceback, the
other devices in their safe state (what their emulators received), and the run file ``aborted``;
``labctl resume --port ROLE=NEW`` (``--host robot=NEW``) then finishes it on the device under its
new name (address). A camera that stops delivering frames in the middle of a stack is the real
RealSense adapter playing a recording shorter than the stack; re-plugged, it is a recording long
enough at the same path, and plain ``labctl resume`` finishes the run.
"""

from __future__ import annotations

import json
import textwrap
from collections.abc import Callable
from pathlib import Path

import h5py
import numpy as np
import pytest

from sim.emulators import DimetixEmulator, GrblEmulator, ZaberEmulator
from sim.emulators.ur import URControllerProcess
from tests.drivers.test_realsense import H, W, scene, write_recording
from tests.drivers.test_ur_rtde_emulator import CENTER_MM, RADIUS_MM, ZERO_POSE_M, circle, home_q
from tests.labctl.run.test_real_lab import STEP, campaign, lab_header
from tests.pty_terminal import Terminal

SPEED_MM_S = 200.0
"""Slow enough that the run is still moving when the test pulls the plug after step 00001 (each later
step moves the stage 200 mm: about a second each)."""


def zaber() -> ZaberEmulator:
    return ZaberEmulator(mm_per_microstep=STEP, travel_mm=400.0, speed_mm_s=2 * SPEED_MM_S, start_mm=150.0)


def grbl() -> GrblEmulator:
    return GrblEmulator(max_travel_mm=400.0, max_rate_mm_min=120 * SPEED_MM_S, start_mm=150.0)


def stage_section(protocol: str, port: str) -> str:
    return f'protocol = "{protocol}"\nport = "{port}"' + (f"\nmm_per_microstep = {STEP}" if protocol == "zaber" else "")


def status(run_file: Path) -> tuple[str, str, int]:
    with h5py.File(run_file, "r") as f:
        complete = sum(bool(g.attrs["complete"]) for g in f["steps"].values())
        return str(f.attrs["status"]), str(f.attrs.get("status_reason", "")), complete


def run_to_abort(path: Path, run_file: Path, lose_a_device: Callable[[Terminal], None]) -> str:
    """``labctl run`` on a terminal, ``lose_a_device(terminal)`` while it runs: the run's output once it has
    ended with exit 1."""
    terminal = Terminal("run", path, "-o", run_file)
    try:
        lose_a_device(terminal)
        assert terminal.wait(timeout=60) == 1, terminal.output
    finally:
        terminal.close()
    return terminal.output


def after_step_1(unplug: Callable[[], None]) -> Callable[[Terminal], None]:
    """``unplug`` once the run reports step 00001 complete."""

    def lose_a_device(terminal: Terminal) -> None:
        terminal.expect("00001_depth_sweep complete", timeout=120)
        unplug()

    return lose_a_device


def assert_stage_stopped(stage: ZaberEmulator) -> None:
    """The Zaber stage in its safe state: stopped, its position read back, not moving."""
    with stage.lock:
        assert stage.commands[-2:] == ["stop", "get pos"] and not stage.moving


def resume(run_file: Path, *options: str) -> str:
    """``labctl resume`` on a terminal: the operator confirms the mounted target, the run completes."""
    terminal = Terminal("resume", run_file, *options)
    try:
        terminal.expect(r"OPERATOR: .*\n.*Press Enter when done", timeout=120)
        terminal.type("\r")
        assert terminal.wait(timeout=120) == 0, terminal.output
        return terminal.output
    finally:
        terminal.close()


def assert_clean_abort(output: str, run_file: Path, device: str, port: str, role: str) -> None:
    assert "Traceback" not in output
    assert f"{device} on {port}: the port {port} failed or vanished" in output
    assert "the USB-serial adapter was unplugged or lost power; check its cable" in output
    assert "The other devices are in their safe state" in output
    assert f"labctl resume {run_file} (add --port {role}=NEW_PORT if it came back under another name than {port})" in output
    state, reason, complete = status(run_file)
    assert state == "aborted" and f"the port {port} failed or vanished" in reason
    assert 2 <= complete < 4, complete  # the plug was pulled during the run, not after it


@pytest.mark.slow
@pytest.mark.parametrize(("protocol", "device"), [("zaber", "Zaber stage 1/1"), ("grbl", "Grbl stage (X axis)")])
def test_an_unplugged_stage_aborts_cleanly_and_resume_continues_on_its_new_port(
    tmp_path: Path, protocol: str, device: str
) -> None:
    path, run_file = tmp_path / "campaign.toml", tmp_path / "run.h5"
    emulator = zaber if protocol == "zaber" else grbl
    stage = emulator().start()
    # where the devices come back (started now, so their pseudo-terminals get other names); the laser comes
    # back too, as a pty once opened at 7E1 refuses those settings when opened again at the same speed
    # (glibc's tcsetattr check of PARENB/CSIZE; a real adapter accepts them)
    with emulator() as new_stage, DimetixEmulator(distance_mm=1234.5) as new_laser:
        try:
            with DimetixEmulator(distance_mm=1234.5) as laser:
                path.write_text(campaign(stage_section(protocol, stage.port), laser.port, speed_mm_s=SPEED_MM_S))
                old_port = stage.port
                output = run_to_abort(path, run_file, after_step_1(stage.disconnect))
                with laser.lock:
                    assert laser.commands[-2:] == ["c", "p"] and not laser.laser_on  # the laser is off
        finally:
            stage.stop()
        assert_clean_abort(output, run_file, device, old_port, "stage")
        assert new_stage.port != old_port
        output = resume(run_file, "--port", f"stage={new_stage.port}", "--port", f"laser={new_laser.port}")
        assert new_stage.position_mm == pytest.approx(400.0, abs=1e-3)  # the last sweep position, on the new port
        new_port = new_stage.port
    assert f"stage port: {new_port} (recorded in {run_file})" in output
    state, _, complete = status(run_file)
    assert state == "complete" and complete == 4
    with h5py.File(run_file, "r") as f:
        history = json.loads(f.attrs["device_overrides_json"])
    assert ("stage", "port", new_port, old_port) in [(e["role"], e["field"], e["value"], e["previous"]) for e in history]


@pytest.mark.slow
def test_an_unplugged_laser_aborts_cleanly_with_the_stage_stopped_and_resume_continues_on_its_new_port(
    tmp_path: Path,
) -> None:
    path, run_file = tmp_path / "campaign.toml", tmp_path / "run.h5"
    with zaber() as stage, DimetixEmulator(distance_mm=1500.0) as new_laser:  # where the laser comes back
        laser = DimetixEmulator(distance_mm=1234.5).start()
        try:
            path.write_text(campaign(stage_section("zaber", stage.port), laser.port, speed_mm_s=SPEED_MM_S))
            old_port = laser.port
            output = run_to_abort(path, run_file, after_step_1(laser.disconnect))
        finally:
            laser.stop()
        assert_stage_stopped(stage)
        assert_clean_abort(output, run_file, "Dimetix laser", old_port, "laser")
        assert new_laser.port != old_port
        resume(run_file, "--port", f"laser={new_laser.port}")  # the stage stays on its port
        assert new_laser.commands.count("g") >= 2 and new_laser.commands[-2:] == ["c", "p"]
        with stage.lock:
            assert stage.commands.count("home") == 2 and stage.position_mm == pytest.approx(400.0, abs=1e-3)
    state, _, complete = status(run_file)
    assert state == "complete" and complete == 4
    with h5py.File(run_file, "r") as f:
        assert list(f["steps/00003_depth_sweep"].attrs["laser_readings_mm"]) == [1500.0, 1500.0]  # the new laser


def robot_campaign(stage_port: str, robot_host: str) -> str:
    """Two materials, each swept by the robot over -10, 0, 10 deg on the emulator's circle; the stage parked."""
    zero_pose = [float(v) for v in (*(1000.0 * np.array(ZERO_POSE_M[:3])), *ZERO_POSE_M[3:])]
    return lab_header("robot-lab", stage_section("zaber", stage_port), home_on_connect=False) + textwrap.dedent(f"""
        [devices.robot]
        host = "{robot_host}"
        circle_center_mm = {[float(v) for v in CENTER_MM]}
        zero_pose = {zero_pose}
        speed_deg_s = 20
        settle_s = 0

        [[procedure]]
        kind = "remission_angle"
        materials = ["ptfe", "molleton"]
        angles_deg = [-10, 10, 10]
        radius_mm = {RADIUS_MM}
        frames = 2
    """)


@pytest.mark.slow
def test_a_lost_robot_connection_aborts_cleanly_and_resume_continues_at_its_new_address(tmp_path: Path) -> None:
    """The RTDE emulator's servers close under the real ur-rtde clients while the run waits at the second
    material's prompt; the next move finds the connection gone.

    The connection drops while no command is under way, and the test waits until ur-rtde has reported it
    lost: the next move finds it gone before sending anything. A connection lost while a command waits for
    the controller's answer is tested in tests/drivers/test_ur_rtde_emulator.py."""
    path, run_file = tmp_path / "campaign.toml", tmp_path / "run.h5"
    with zaber() as stage:
        robot = URControllerProcess(home_q(), robot_mode="RUNNING")
        try:
            path.write_text(robot_campaign(stage.port, robot.host))
            old_host = robot.host

            def drop_the_connection(terminal: Terminal) -> None:
                terminal.expect(r"OPERATOR: mount the ptfe plate.*\n.*Press Enter when done", timeout=120)
                terminal.type("\r")
                terminal.expect(r"OPERATOR: mount the molleton plate.*\n.*Press Enter when done", timeout=120)
                robot.close()
                terminal.expect("RTDEReceiveInterface boost system Exception", timeout=60)
                terminal.expect("Timeout connecting to UR dashboard server", timeout=60)  # its reconnect failed
                terminal.type("\r")

            output = run_to_abort(path, run_file, drop_the_connection)
        finally:
            robot.close()
        assert_stage_stopped(stage)
        assert "Traceback" not in output
        assert f"UR5e at {old_host}: the connection to the controller at {old_host} (RTDE port 30004) was lost" in output
        assert "The other devices are in their safe state" in output
        advice = f"labctl resume {run_file} (add --host robot=NEW_HOST if it came back at another address than {old_host})"
        assert advice in output
        state, reason, complete = status(run_file)
        assert state == "aborted" and f"the connection to the controller at {old_host}" in reason
        assert complete == 3  # the ptfe sweep
        with URControllerProcess(home_q(), robot_mode="RUNNING") as new_robot:
            assert new_robot.host != old_host
            resume(run_file, "--host", f"robot={new_robot.host}")
            pose_m = np.asarray(new_robot.call("pose"), float)
            final = circle().locate(np.concatenate([1000.0 * pose_m[:3], pose_m[3:]]))
    assert final.angle_deg == pytest.approx(-10.0, abs=0.05)  # the molleton sweep runs back: 10, 0, -10 deg
    state, _, complete = status(run_file)
    assert state == "complete" and complete == 6


def camera_stall_campaign(stage_port: str, recording: Path) -> str:
    """The camera playing ``recording``; a sweep of 2 frames a step at 1000 and 1100 mm, then one of
    3 frames a step at 1200 and 1300 mm (reference: the stage's nominal distance)."""
    sweeps = "".join(
        textwrap.dedent(f"""
            [[procedure]]
            kind = "depth_sweep"
            start_mm = {start}
            stop_mm = {start + 100}
            step_mm = 100
            frames = {frames}
        """)
        for start, frames in ((1000, 2), (1200, 3))
    )
    return lab_header("camera-stall", stage_section("zaber", stage_port), backend="d455", playback=recording) + sweeps


def assert_stacks_of_the_scene(run_file: Path, frames_by_step: dict[str, int]) -> None:
    """Every step in ``frames_by_step`` complete, its stack the recorded scene's first frames."""
    with h5py.File(run_file, "r") as f:
        for step_id, frames in frames_by_step.items():
            step = f["steps"][step_id]
            assert step.attrs["complete"] and step["z"].shape == (frames, H, W)
            for k in range(frames):
                depth, _ = scene(k)
                assert np.allclose(step["z"][k][depth > 0], depth[depth > 0], atol=1e-3)


@pytest.mark.slow
def test_a_camera_that_stops_delivering_mid_stack_aborts_cleanly_and_resume_continues_on_the_replugged_camera(
    tmp_path: Path, labctl
) -> None:
    """The real RealSense adapter plays a recording of 2 frames: the first sweep's stacks of 2 complete,
    the first stack of 3 ends after its second frame. The camera "re-plugged" is a recording long enough
    at the same path; resume runs the stack that was cut short again, and the last one."""
    path, run_file, recording = tmp_path / "campaign.toml", tmp_path / "run.h5", tmp_path / "camera.db3"
    write_recording(recording, 2)
    with ZaberEmulator(mm_per_microstep=STEP, travel_mm=400.0, speed_mm_s=2000.0, start_mm=150.0) as stage:
        path.write_text(camera_stall_campaign(stage.port, recording))
        output = run_to_abort(path, run_file, lambda terminal: None)
        assert_stage_stopped(stage)
        assert "Traceback" not in output and output.count("labctl: error:") == 1
        ended = f"RealSense playback of {recording}: the recording ended after 2 frame(s)"
        assert f"run aborted: {ended}" in output and f"Continue with: labctl resume {run_file}" in output
        info = labctl("info", run_file, "--json")
        assert info.returncode == 0, info.stderr
        doc = json.loads(info.stdout)
        assert doc["status"] == "aborted" and ended in doc["status_reason"]
        assert [step["status"] for step in doc["steps"]] == ["complete", "complete", "unfinished", "pending"]
        assert_stacks_of_the_scene(run_file, {"00000_depth_sweep": 2, "00001_depth_sweep": 2})
        recording.unlink()
        write_recording(recording, 3)
        assert "resuming at 00002_depth_sweep" in resume(run_file)
        with stage.lock:
            assert stage.commands.count("home") == 2 and stage.position_mm == pytest.approx(300.0, abs=1e-3)
    state, _, complete = status(run_file)
    assert state == "complete" and complete == 4
    assert_stacks_of_the_scene(
        run_file, {"00000_depth_sweep": 2, "00001_depth_sweep": 2, "00002_depth_sweep": 3, "00003_depth_sweep": 3}
    )
