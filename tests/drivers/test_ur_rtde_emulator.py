"""ur-rtde's own clients against the UR controller emulator over loopback.

The real ``rtde_receive.RTDEReceiveInterface``, ``dashboard_client.DashboardClient`` and
``rtde_control.RTDEControlInterface`` talk RTDE (30004), the dashboard protocol (29999)
and upload their control script (30003) to :mod:`sim.emulators.ur`, which runs in a child
process (ur-rtde keeps the interpreter lock while it waits). Then the UR5e adapter runs
through the same clients: pose, limits refused before motion, motion along the circle,
protective stop and recovery.

Expected values come from the RTDE guide and the dashboard server's command table (mode
numbers and reply texts), from the circle's geometry and from the injected state, never
from the emulator's code.
"""

from __future__ import annotations

import dataclasses
import socket
import threading
import time
from collections.abc import Iterator
from typing import Any

import dashboard_client
import numpy as np
import pytest
import rtde_control
import rtde_receive
from scipy.spatial.transform import Rotation

from drivers.errors import DeviceError, DeviceVanished, LimitViolation, ProtectiveStop
from drivers.protocols import RobotPose
from drivers.robot import MeasurementCircle, UR5eRobot
from drivers.robot.ur5e import LINK_SILENCE_S
from sim.emulators.ur import SafetyPlane, URControllerProcess
from sim.emulators.ur.kinematics import inverse

pytestmark = pytest.mark.realtime  # the emulator's RTDE packets reach the clients within RTDE_LAG_S

CENTER_MM = np.array([200.0, 0.0, 300.0])
RADIUS_MM = 350.0
LOOKING = Rotation.from_matrix(np.column_stack([[0, -1, 0], [0, 0, 1], [-1, 0, 0]]).astype(float)).as_rotvec()
"""Tool z axis along -x: at angle 0 the camera looks from +x back at the centre."""
ZERO_POSE_M = [(CENTER_MM[0] + RADIUS_MM) / 1000.0, 0.0, CENTER_MM[2] / 1000.0, *LOOKING]
SEED_Q = [0.0, -1.2, -1.8, -0.2, 1.57, 0.0]
RTDE_LAG_S = 0.1
"""Time for a state change to reach the clients: several RTDE output periods."""


def home_q() -> list[float]:
    """Joint angles of the 0° pose (the arm jogged there before the session)."""
    q = inverse(ZERO_POSE_M, SEED_Q, max_position_error=1e-10, max_orientation_error=1e-10)
    assert q is not None
    return list(q)


def circle() -> MeasurementCircle:
    return MeasurementCircle(CENTER_MM, (0, 0, 1), [*(1000.0 * np.array(ZERO_POSE_M[:3])), *LOOKING])


@pytest.fixture
def emulator(request: pytest.FixtureRequest) -> Iterator[URControllerProcess]:
    options: dict[str, Any] = {"robot_mode": "RUNNING", "unlock_delay_s": 0.3}
    options.update(getattr(request, "param", {}))
    with URControllerProcess(home_q(), **options) as process:
        yield process


def adapter(host: str, **options: Any) -> UR5eRobot:
    settings: dict[str, Any] = {"speed_deg_s": 90.0, "acceleration_deg_s2": 180.0, "settle_s": 0.05, "poll_interval_s": 0.005}
    settings.update(options)
    return UR5eRobot(host, circle(), connect_timeout_s=2.0, move_timeout_s=10.0, **settings)


class _SaysWhenMoveLReturns:
    """ur-rtde's control client, unchanged, that sets ``returned`` when a ``moveL`` call has returned."""

    def __init__(self, control: Any, returned: threading.Event) -> None:
        self._control = control
        self._returned = returned

    def moveL(self, *args: Any) -> Any:  # ur-rtde's name
        try:
            return self._control.moveL(*args)
        finally:
            self._returned.set()

    def __getattr__(self, name: str) -> Any:
        return getattr(self._control, name)


def inject(emulator: URControllerProcess, fault: str) -> None:
    """Inject a fault and give it time to reach the clients."""
    emulator.call(fault)
    time.sleep(RTDE_LAG_S)


def wait_for(condition: Any, timeout_s: float = 30.0) -> None:
    """Until ``condition()``, within a generous deadline (the emulator is a process of its own, which a loaded
    machine may run late)."""
    deadline = time.monotonic() + timeout_s
    while not condition():
        assert time.monotonic() < deadline, "condition not reached in time"
        time.sleep(0.01)


def still_pose(receive: Any) -> list[float]:
    """The TCP pose once two successive RTDE packets carry the same one (a moving robot's differs)."""
    previous: list[tuple[float, list[float]]] = []

    def unchanged() -> bool:
        sample = (receive.getTimestamp(), receive.getActualTCPPose())
        if previous and sample[0] > previous[-1][0]:
            if sample[1] == pytest.approx(previous[-1][1], abs=1e-9):
                return True
        if not previous or sample[0] > previous[-1][0]:
            previous.append(sample)
        return False

    wait_for(unchanged)
    return previous[-1][1]


# ------------------------------------------------------------------ the clients themselves
@pytest.mark.parametrize("emulator", [{"robot_mode": "POWER_OFF"}], indirect=True)
def test_dashboard_client_and_receive_interface(emulator: URControllerProcess) -> None:
    dashboard = dashboard_client.DashboardClient(emulator.host)
    dashboard.connect(2000)
    receive = rtde_receive.RTDEReceiveInterface(emulator.host)
    try:
        assert dashboard.isConnected()
        assert dashboard.polyscopeVersion() == "5.11.6.1107777"  # ur-rtde extracts a.b.c.d from "URSoftware ..."
        assert dashboard.getRobotModel() == "UR5"
        assert dashboard.isInRemoteControl() is True
        assert receive.getActualTCPPose() == pytest.approx(ZERO_POSE_M, abs=1e-9)
        assert receive.getActualQ() == pytest.approx(home_q(), abs=1e-12)
        # power-up sequence of the dashboard server, seen through RTDE's robot_mode (3, 5, 7)
        assert dashboard.robotmode() == "Robotmode: POWER_OFF" and receive.getRobotMode() == 3
        dashboard.powerOn()
        wait_for(lambda: receive.getRobotMode() == 5)
        assert dashboard.robotmode() == "Robotmode: IDLE"
        dashboard.brakeRelease()
        wait_for(lambda: receive.getRobotMode() == 7)
        assert receive.getSafetyMode() == 1 and dashboard.safetystatus() == "Safetystatus: NORMAL"
        assert not receive.isProtectiveStopped() and not receive.isEmergencyStopped()
        # an injected protective stop: safety_mode 3, bit 2 of safety_status_bits
        emulator.call("protective_stop")
        wait_for(receive.isProtectiveStopped)
        assert receive.getSafetyMode() == 3 and receive.getSafetyStatusBits() & 0b100
        assert dashboard.safetymode() == "Safetymode: PROTECTIVE_STOP"
        with pytest.raises(RuntimeError, match="Cannot unlock protective stop until 5s after occurrence"):
            dashboard.unlockProtectiveStop()
        time.sleep(0.35)
        dashboard.closeSafetyPopup()
        dashboard.unlockProtectiveStop()
        wait_for(lambda: not receive.isProtectiveStopped())
        assert receive.getSafetyMode() == 1
        # programs: load, play, programState, stop
        with pytest.raises(RuntimeError, match="File not found: missing.urp"):
            dashboard.loadURP("missing.urp")
        dashboard.loadURP("calibration.urp")
        dashboard.play()
        assert dashboard.running() and dashboard.programState() == "PLAYING calibration.urp"
        wait_for(lambda: receive.getRuntimeState() == 2)
        dashboard.stop()
        assert not dashboard.running() and dashboard.programState() == "STOPPED calibration.urp"
    finally:
        receive.disconnect()
        dashboard.disconnect()


def test_receive_interface_refuses_unknown_variables(emulator: URControllerProcess) -> None:
    """The RTDE server answers NOT_FOUND for a name outside the guide's output table; ur-rtde names it."""
    with pytest.raises(RuntimeError, match=r"not found by the controller: \[actual_teleport_pose\]"):
        rtde_receive.RTDEReceiveInterface(emulator.host, 125.0, ["actual_TCP_pose", "actual_teleport_pose"])


def test_control_interface_moves_stops_and_answers_queries(emulator: URControllerProcess) -> None:
    control = rtde_control.RTDEControlInterface(emulator.host)
    receive = rtde_receive.RTDEReceiveInterface(emulator.host)
    try:
        assert control.isProgramRunning()
        target = list(ZERO_POSE_M)
        target[2] += 0.05
        assert control.isPoseWithinSafetyLimits(target)
        assert not control.isPoseWithinSafetyLimits([1.5, 0.0, 0.3, *LOOKING])  # 1.5 m: beyond the UR5e's 850 mm reach
        q = control.getInverseKinematics(target, receive.getActualQ())
        assert control.getInverseKinematicsHasSolution(target, receive.getActualQ())
        # independent check of the joint solution: it must differ from home, and moving there reaches the target
        assert not np.allclose(q, home_q())
        assert control.moveL([[*target, 0.25, 1.2, 0.0]], False)  # synchronous: returns at the target
        wait_for(lambda: receive.getActualTCPPose() == pytest.approx(target, abs=1e-6))
        assert receive.getActualQ() == pytest.approx(q, abs=1e-4)  # both solved to about 1e-6 m
        # asynchronous path, stopped half way
        far = list(target)
        far[1] += 0.2
        assert control.moveL([[*far, 0.02, 1.2, 0.0]], True)  # 10 s at 0.02 m/s
        wait_for(lambda: control.getAsyncOperationProgressEx().isAsyncOperationRunning())
        wait_for(lambda: receive.getActualTCPPose()[1] > target[1] + 0.01)
        control.stopL(2.0)
        wait_for(lambda: not control.getAsyncOperationProgressEx().isAsyncOperationRunning())
        stopped = still_pose(receive)
        assert target[1] + 0.01 < stopped[1] < far[1] - 0.01  # stopped on the way
    finally:
        control.stopScript()
        control.disconnect()
        receive.disconnect()


def test_a_second_control_interface_finds_the_registers_in_use(emulator: URControllerProcess) -> None:
    """RTDE inputs have one writer: a second RTDEControlInterface (another session) is refused (IN_USE)."""
    control = rtde_control.RTDEControlInterface(emulator.host)
    try:
        with pytest.raises(RuntimeError, match="RTDE input registers are already in use"):
            rtde_control.RTDEControlInterface(emulator.host)
        assert control.isProgramRunning()
    finally:
        control.stopScript()
        control.disconnect()


def test_a_foreign_program_does_not_run(emulator: URControllerProcess) -> None:
    """The emulator does not interpret URScript: a program other than ur-rtde's control script
    (here sent to the secondary port 30002 as a plain socket client would) never starts."""
    program = "def wave():\n  movej([0, -1.57, 0, -1.57, 0, 0])\nend\n"
    with socket.create_connection((emulator.host, 30002), timeout=2.0) as client:
        client.sendall(program.encode())
        wait_for(lambda: emulator.call("scripts_received") == [program])
    assert emulator.call("refused_scripts") == [program]
    assert emulator.call("runtime_state") == 1  # STOPPED
    assert emulator.call("q") == pytest.approx(home_q(), abs=1e-12)


# ------------------------------------------------------------------ the UR5e adapter through ur-rtde
def test_adapter_reads_identity_pose_and_joints(emulator: URControllerProcess) -> None:
    with adapter(emulator.host) as robot:
        identity = robot.identity()
        assert (identity.model, identity.serial, identity.firmware) == ("UR5", "20205500001", "5.11.6.1107777")
        assert robot.pose_mm() == pytest.approx([*(1000.0 * np.array(ZERO_POSE_M[:3])), *LOOKING], abs=1e-6)
        assert robot.angle_deg() == pytest.approx(0.0, abs=1e-6)
        assert robot.joints_deg() == pytest.approx(np.degrees(home_q()), abs=1e-9)


def test_adapter_moves_along_the_circle(emulator: URControllerProcess) -> None:
    with adapter(emulator.host) as robot:
        robot.move_on_circle(20.0, RADIUS_MM)
        assert robot.angle_deg() == pytest.approx(20.0, abs=0.01)
        expected = CENTER_MM + RADIUS_MM * np.array([np.cos(np.radians(20.0)), np.sin(np.radians(20.0)), 0.0])
        assert robot.pose_mm()[:3] == pytest.approx(expected, abs=0.01)
        robot.move_on_circle(-10.0, 300.0)
        assert robot.angle_deg() == pytest.approx(-10.0, abs=0.01)
        assert np.linalg.norm(robot.pose_mm()[:2] - CENTER_MM[:2]) == pytest.approx(300.0, abs=0.01)
    # the path went through the waypoints on the arc (every 5°), not along the chord
    scripts = emulator.call("scripts_received")
    paths = [s for s in scripts if "movel(p[" in s]
    assert len(paths) == 2 and paths[0].count("movel(p[") == 4


def test_adapter_reports_the_pose_it_reads_back_while_it_moves(emulator: URControllerProcess) -> None:
    """The watch sees the arm pass through the arc (read back through ur-rtde's receive interface), not only the
    commanded end: angles between start and target, rising, on the circle's radius and plane."""
    seen: list[RobotPose] = []
    with adapter(emulator.host, speed_deg_s=40.0, acceleration_deg_s2=160.0) as robot:
        robot.move_on_circle(40.0, RADIUS_MM, seen.append)
        final = robot.pose()
    angles = [pose.angle_deg for pose in seen]
    assert sum(1.0 < a < 39.0 for a in angles) >= 2, angles  # a 1 s move, watched every 0.1 s
    assert all(b >= a - 0.01 for a, b in zip(angles, angles[1:])), angles
    assert angles[-1] == pytest.approx(40.0, abs=0.01) and final.angle_deg == pytest.approx(40.0, abs=0.01)
    for pose in seen:
        assert pose.radius_mm == pytest.approx(RADIUS_MM, abs=2.0)  # blended between waypoints 5° apart
        assert pose.tcp_mm is not None
        assert pose.tcp_mm[2] == pytest.approx(CENTER_MM[2], abs=0.01)
        bearing = np.degrees(np.arctan2(pose.tcp_mm[1] - CENTER_MM[1], pose.tcp_mm[0] - CENTER_MM[0]))
        assert bearing == pytest.approx(pose.angle_deg, abs=0.01)


@pytest.mark.parametrize("emulator", [{"safety_planes": [SafetyPlane((0.0, 1.0, 0.0), -0.1)]}], indirect=True)
def test_adapter_refuses_poses_outside_the_limits_before_motion(emulator: URControllerProcess) -> None:
    """A safety plane y >= -100 mm in the controller: -30° (y = -175 mm) is refused by
    ``isPoseWithinSafetyLimits``; a reach beyond 850 mm and a joint limit likewise; nothing moves."""
    with adapter(emulator.host, joint_limits_deg=[[-360, 20]] + [[-360, 360]] * 5, radius_max_mm=1000.0) as robot:
        before = robot.pose_mm()
        with pytest.raises(LimitViolation, match=r"waypoint \d+/\d+ .* violates the controller's safety limits; nothing moved"):
            robot.move_on_circle(-30.0, RADIUS_MM)
        with pytest.raises(LimitViolation, match="violates the controller's safety limits; nothing moved"):
            robot.move_on_circle(0.0, 900.0)  # 1100 mm from the base
        with pytest.raises(LimitViolation, match=r"joint 0 would be at 2[0-9.]* deg, outside \[-360, 20\]; nothing moved"):
            robot.move_on_circle(20.0, RADIUS_MM)  # the base turns by about 25° (TCP bearing 12.7° plus the shoulder offset)
        assert robot.pose_mm() == pytest.approx(before, abs=1e-9)
    assert not [s for s in emulator.call("scripts_received") if "movel(p[" in s]
    assert emulator.call("commands_done").count(45) == 0


def test_adapter_protective_stop_before_a_move_and_recovery(emulator: URControllerProcess) -> None:
    with adapter(emulator.host) as robot:
        inject(emulator, "protective_stop")
        with pytest.raises(ProtectiveStop, match="before moving: the controller is in a protective stop"):
            robot.move_on_circle(10.0, RADIUS_MM)
        assert robot.angle_deg() == pytest.approx(0.0, abs=1e-6)
        started = time.monotonic()
        robot.recover()  # the first unlock is refused (within the controller's wait), then it goes through
        assert time.monotonic() - started >= 0.3
        assert not emulator.call("safety_popup")
        robot.move_on_circle(10.0, RADIUS_MM)
        assert robot.angle_deg() == pytest.approx(10.0, abs=0.01)


def test_adapter_protective_stop_during_a_move(emulator: URControllerProcess) -> None:
    def stop_on_the_way() -> None:  # once the TCP is 3 deg along the circle (its chord from the start)
        start = np.array(emulator.call("pose")[:3])
        chord_m = 2 * RADIUS_MM / 1000 * np.sin(np.radians(3.0) / 2)
        wait_for(lambda: emulator.call("moving") and np.linalg.norm(np.array(emulator.call("pose")[:3]) - start) > chord_m)
        emulator.call("protective_stop")

    with adapter(emulator.host, speed_deg_s=5.0) as robot:  # 8 s to 40 deg: stopped on the way, however late
        stopper = threading.Thread(target=stop_on_the_way)
        stopper.start()
        try:
            with pytest.raises(ProtectiveStop, match="move to 40.0 deg .* protective stop"):
                robot.move_on_circle(40.0, RADIUS_MM)
        finally:
            stopper.join()
        time.sleep(RTDE_LAG_S)
        stopped = robot.angle_deg()
        assert 2.0 < stopped < 38.0  # stopped on the way to 40°
        time.sleep(0.2)
        assert robot.angle_deg() == pytest.approx(stopped, abs=1e-9)
        robot.recover()
        robot.move_on_circle(0.0, RADIUS_MM)
        assert robot.angle_deg() == pytest.approx(0.0, abs=0.01)


def test_adapter_emergency_stop_is_fatal(emulator: URControllerProcess) -> None:
    with adapter(emulator.host) as robot:
        inject(emulator, "emergency_stop")
        with pytest.raises(DeviceError, match="emergency stop is engaged"):
            robot.move_on_circle(10.0, RADIUS_MM)
        with pytest.raises(DeviceError, match="emergency stop is engaged"):
            robot.recover()


def test_adapter_a_dropped_connection_during_a_move_is_a_vanished_robot(emulator: URControllerProcess) -> None:
    """The controller's servers close (a pulled network cable, a controller restart) while the arm moves:
    ur-rtde's clients report the connection down, and the adapter raises at once instead of sending over
    it (ur-rtde then waits for an answer forever); safe_state and close return. The cable is pulled once
    ur-rtde has accepted the path (``moveL`` returned); the next test pulls it while ur-rtde itself still waits
    for the controller's answer."""
    accepted = threading.Event()

    def pull_the_cable() -> None:
        assert accepted.wait(10.0), "moveL did not return within 10 s"
        wait_for(lambda: emulator.call("moving"), 10.0)
        emulator.close()

    robot = adapter(emulator.host, speed_deg_s=10.0)  # 4 s to 40°
    robot.connect()
    robot._rtde = dataclasses.replace(robot._rtde, control=_SaysWhenMoveLReturns(robot._rtde.control, accepted))
    cable = threading.Thread(target=pull_the_cable)
    cable.start()
    try:
        with pytest.raises(DeviceVanished, match=f"the connection to the controller at {emulator.host} .* was lost") as caught:
            robot.move_on_circle(40.0, RADIUS_MM)
    finally:
        cable.join()
    assert caught.value.connection == emulator.host
    with pytest.raises(DeviceVanished):
        robot.pose_mm()  # no stale pose from the last package received
    started = time.monotonic()
    robot.safe_state()
    robot.close()
    assert time.monotonic() - started < 30.0


@pytest.mark.parametrize("link", ["closed", "silent"])
def test_adapter_a_connection_lost_while_ur_rtde_waits_in_move_l_is_a_vanished_robot(
    emulator: URControllerProcess, link: str
) -> None:
    """``moveL`` with a path restarts ur-rtde's control script with the path in it and waits for it to run; the
    controller holds it, and the link is lost during that wait: the controller's servers close (a controller
    restart), or its connections fall silent (a pulled cable: the process frozen, nothing more arrives, no FIN
    either). ur-rtde would go on waiting (its wait polls the state it last received); the adapter's watch on
    the link raises DeviceVanished, while ur-rtde's ``moveL`` has still not returned."""
    returned = threading.Event()
    pulled_at: list[float] = []

    def pull_the_cable_during_the_wait() -> None:
        wait_for(lambda: any("movel(p[" in script for script in emulator.call("scripts_received")))
        pulled_at.append(time.monotonic())  # ur-rtde sent the path's script: its moveL waits for it to run
        if link == "closed":
            emulator.close()
        else:
            emulator.go_silent()

    robot = adapter(emulator.host)
    robot.connect()
    robot._rtde = dataclasses.replace(robot._rtde, control=_SaysWhenMoveLReturns(robot._rtde.control, returned))
    emulator.call("hold_programs")
    cable = threading.Thread(target=pull_the_cable_during_the_wait)
    cable.start()
    try:
        with pytest.raises(DeviceVanished, match=f"the connection to the controller at {emulator.host} .* was lost "
                           "while ur-rtde waited for the controller's answer to moveL") as caught:
            robot.move_on_circle(40.0, RADIUS_MM)
        raised_at = time.monotonic()
    finally:
        cable.join()
    assert not returned.is_set()  # the adapter gave up on ur-rtde's moveL, which still waits
    assert caught.value.connection == emulator.host
    assert raised_at - pulled_at[0] < 10 * LINK_SILENCE_S  # generous for a loaded machine; ur-rtde waits 300 s or more
    with pytest.raises(DeviceVanished):
        robot.pose_mm()
    started = time.monotonic()
    robot.safe_state()
    robot.close()
    assert time.monotonic() - started < 30.0


@pytest.mark.parametrize("emulator", [{"remote_control": False}], indirect=True)
def test_adapter_refuses_a_robot_in_local_control(emulator: URControllerProcess) -> None:
    with pytest.raises(DeviceError, match="Local Control"):
        adapter(emulator.host).connect()


def test_emulator_leaves_no_listener(emulator: URControllerProcess) -> None:
    """After close, the robot's ports on the emulator's address are free again."""
    host = emulator.host
    emulator.close()
    for port in (29999, 30002, 30003, 30004):
        with socket.socket() as probe:
            probe.settimeout(0.5)
            assert probe.connect_ex((host, port)) != 0
