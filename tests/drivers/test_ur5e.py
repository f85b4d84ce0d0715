"""UR5e adapter at the boundary of ur-rtde.

Without a controller: connecting to nothing, to a silent server or to a foreign one over
real sockets; limit checks that refuse before any call. The adapter through ur-rtde's own
clients against the controller emulator is tested in ``test_ur_rtde_emulator.py``; the
tests here that need controller states use :class:`FakeController`, a small stand-in for
ur-rtde's three clients, also for states the emulator does not produce (safeguard stop,
fault, a move that never ends). docs/ursim.md describes the first test against URSim.
"""

from __future__ import annotations

import os
import random
import signal
import socket
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from drivers.errors import DeviceError, DeviceVanished, LimitViolation, OperatorActionRequired, ProtectiveStop
from drivers.protocols import Robot
from drivers.robot import MeasurementCircle, UR5eRobot
from drivers.robot.ur5e import DASHBOARD_GREETING, DASHBOARD_PORT, LINK_SILENCE_S, RTDE_PORT, RTDEInterfaces

CENTER = (400.0, 0.0, 300.0)
RADIUS = 500.0


def circle() -> MeasurementCircle:
    looking = Rotation.from_matrix(np.column_stack([[0, -1, 0], [0, 0, 1], [-1, 0, 0]]).astype(float)).as_rotvec()
    return MeasurementCircle(CENTER, (0, 0, 1), [CENTER[0] + RADIUS, 0.0, CENTER[2], *looking])


def to_m(pose_mm: np.ndarray) -> list[float]:
    return [*(pose_mm[:3] / 1000.0), *pose_mm[3:]]


# ------------------------------------------------------------------ no controller: real sockets
def loopback_host() -> str:
    """A loopback address of its own, so parallel tests can listen on the robot's fixed ports."""
    return f"127.{random.randint(1, 254)}.{random.randint(1, 254)}.{random.randint(2, 254)}"


@pytest.fixture
def serve() -> Iterator[Callable[[str, int, bytes | None], None]]:
    """Start a TCP server on host:port that sends ``greeting`` (None: stays silent) to each client."""
    sockets: list[socket.socket] = []

    def start(host: str, port: int, greeting: bytes | None) -> None:
        server = socket.create_server((host, port))
        sockets.append(server)

        def accept() -> None:
            while True:
                try:
                    client, _ = server.accept()
                except OSError:
                    return
                sockets.append(client)
                if greeting is not None:
                    client.sendall(greeting)

        threading.Thread(target=accept, daemon=True).start()

    yield start
    for s in sockets:
        s.close()


def robot(host: str, **options: Any) -> UR5eRobot:
    return UR5eRobot(host, circle(), connect_timeout_s=0.3, **options)


@pytest.mark.realtime
def test_nothing_listening_is_a_quick_error_naming_the_host() -> None:
    host = loopback_host()
    start = time.monotonic()
    with pytest.raises(DeviceError, match=f"no UR dashboard server answers at {host}:{DASHBOARD_PORT}"):
        robot(host).connect()
    assert time.monotonic() - start < 1.0


@pytest.mark.realtime
def test_a_silent_server_times_out(serve: Callable[[str, int, bytes | None], None]) -> None:
    host = loopback_host()
    serve(host, DASHBOARD_PORT, None)
    start = time.monotonic()
    with pytest.raises(DeviceError, match=f"{host}:{DASHBOARD_PORT} within 0.3 s"):
        robot(host).connect()
    assert time.monotonic() - start < 1.5


def test_a_foreign_server_is_not_taken_for_a_robot(serve: Callable[[str, int, bytes | None], None]) -> None:
    host = loopback_host()
    serve(host, DASHBOARD_PORT, b"SSH-2.0-OpenSSH_9.6\r\n")
    with pytest.raises(DeviceError, match="answered 'SSH-2.0-OpenSSH_9.6', not a UR dashboard server"):
        robot(host).connect()


@pytest.mark.realtime
@pytest.mark.parametrize("rtde_listens", [False, True])
def test_a_dashboard_without_an_rtde_server(serve: Callable[[str, int, bytes | None], None], rtde_listens: bool) -> None:
    """ur-rtde itself would wait forever for a silent RTDE server; the probe does not."""
    host = loopback_host()
    serve(host, DASHBOARD_PORT, DASHBOARD_GREETING.encode() + b"\n")
    if rtde_listens:
        serve(host, RTDE_PORT, None)
    start = time.monotonic()
    with pytest.raises(DeviceError, match=f"no RTDE server answers at {host}:{RTDE_PORT}"):
        robot(host).connect()
    assert time.monotonic() - start < 1.5


@pytest.mark.parametrize(
    ("angle", "radius", "message"),
    [(95.0, 400.0, "angle 95.0 deg lies outside"), (float("nan"), 400.0, "angle nan deg"),
     (10.0, 0.0, r"radius 0.0 mm lies outside \(0, 850.0\]"), (10.0, 900.0, "radius 900.0 mm")],
)
def test_limits_are_checked_before_anything_else(angle: float, radius: float, message: str) -> None:
    """Not connected at all: the limit check comes first, so nothing can have been sent."""
    with pytest.raises(LimitViolation, match=f"{message}.*nothing moved"):
        robot("192.0.2.1").move_on_circle(angle, radius)


def test_safe_state_and_close_without_connection_are_harmless() -> None:
    unconnected = robot("192.0.2.1")
    unconnected.safe_state()
    unconnected.close()
    assert isinstance(unconnected, Robot)


# ------------------------------------------------------------------ controller states: FakeController
@dataclass
class FakeController:
    """Stand-in for ur-rtde's RTDEControlInterface, RTDEReceiveInterface and DashboardClient of one
    controller (poses in m and rad, as ur-rtde's). ``moveL`` jumps to the path's end after
    ``motion_polls`` progress polls, unless ``stop_during_motion`` names a safety stop."""

    tcp: list[float]
    calls: list[tuple[str, Any]] = field(default_factory=list)
    protective: bool = False
    emergency: bool = False
    safety_mode: int = 1
    robot_mode: int = 7
    motion_polls: int = 2
    stop_during_motion: str | None = None
    unlock_refusals: int = 0
    connected: bool = True
    pose_ok: Callable[[list[float]], bool] = lambda pose: True
    ik: Callable[[list[float]], list[float] | None] = lambda pose: [0.1, -1.2, 1.5, -0.3, 1.57, 0.0]
    _polls: int = 0
    _target: list[float] | None = None

    def interfaces(self, host: str, timeout_s: float) -> RTDEInterfaces:
        self.calls.append(("connect", host))
        return RTDEInterfaces(control=self, receive=self, dashboard=self)

    def names(self) -> list[str]:
        return [name for name, _ in self.calls]

    def isConnected(self) -> bool:  # noqa: N802 - ur-rtde's names (receive and control)
        return self.connected

    def getTimestamp(self) -> float:  # noqa: N802
        """The controller's clock, which a live controller's packages carry forward."""
        return time.monotonic()

    # control
    def moveL(self, path: list[list[float]], asynchronous: bool) -> bool:  # noqa: N802 - ur-rtde's names
        self.calls.append(("moveL", path))
        self._target, self._polls = list(path[-1][:6]), self.motion_polls
        return True

    def getAsyncOperationProgressEx(self) -> Any:  # noqa: N802
        running = self._polls > 0
        self._polls -= 1
        if running and self._polls == 0 and self.stop_during_motion:
            setattr(self, self.stop_during_motion, True)
            return type("Status", (), {"isAsyncOperationRunning": lambda _: True})()
        if not running and self._target is not None:
            self.tcp, self._target = self._target, None
        return type("Status", (), {"isAsyncOperationRunning": lambda _: running})()

    def isPoseWithinSafetyLimits(self, pose: list[float]) -> bool:  # noqa: N802
        self.calls.append(("isPoseWithinSafetyLimits", pose))
        return self.pose_ok(pose)

    def getInverseKinematicsHasSolution(self, pose: list[float], q_near: list[float]) -> bool:  # noqa: N802
        return self.ik(pose) is not None

    def getInverseKinematics(self, pose: list[float], q_near: list[float]) -> list[float]:  # noqa: N802
        return list(self.ik(pose) or [])

    def stopL(self) -> None:  # noqa: N802
        self.calls.append(("stopL", None))

    def stopJ(self) -> None:  # noqa: N802
        self.calls.append(("stopJ", None))

    def reuploadScript(self) -> None:  # noqa: N802
        self.calls.append(("reuploadScript", None))

    def isProgramRunning(self) -> bool:  # noqa: N802
        return True

    def stopScript(self) -> None:  # noqa: N802
        self.calls.append(("stopScript", None))

    def disconnect(self) -> None:
        self.calls.append(("disconnect", None))

    # receive
    def getActualTCPPose(self) -> list[float]:  # noqa: N802
        return list(self.tcp)

    def getActualQ(self) -> list[float]:  # noqa: N802
        return [0.0] * 6

    def isProtectiveStopped(self) -> bool:  # noqa: N802
        return self.protective

    def isEmergencyStopped(self) -> bool:  # noqa: N802
        return self.emergency

    def getSafetyMode(self) -> int:  # noqa: N802
        return 3 if self.protective else self.safety_mode

    def getRobotMode(self) -> int:  # noqa: N802
        return self.robot_mode

    # dashboard
    def getRobotModel(self) -> str:  # noqa: N802
        return "UR5"

    def getSerialNumber(self) -> str:  # noqa: N802
        return "20235500001"

    def polyscopeVersion(self) -> str:  # noqa: N802
        return "5.15.0.12345"  # ur-rtde returns the a.b.c.d part of "URSoftware 5.15.0.12345 (...)"

    def closeSafetyPopup(self) -> None:  # noqa: N802
        self.calls.append(("closeSafetyPopup", None))

    def unlockProtectiveStop(self) -> None:  # noqa: N802
        self.calls.append(("unlockProtectiveStop", None))
        if self.unlock_refusals:
            self.unlock_refusals -= 1
            raise RuntimeError("Cannot unlock protective stop until 5s after occurrence")
        self.protective = False


@pytest.fixture
def controller() -> FakeController:
    return FakeController(tcp=to_m(circle().pose(0.0, RADIUS)))


def connected(controller: FakeController, **options: Any) -> UR5eRobot:
    device = UR5eRobot("ursim", circle(), settle_s=0.0, poll_interval_s=0.001, interfaces=controller.interfaces, **options)
    device.connect()
    return device


def test_identity_and_protocol(controller: FakeController) -> None:
    device = connected(controller)
    assert device.identity().model == "UR5" and device.identity().firmware == "5.15.0.12345"
    assert device.angle_deg() == pytest.approx(0.0)
    assert device.settings()["zero_radius_mm"] == pytest.approx(RADIUS)


def test_connect_refuses_an_arm_that_is_not_running(controller: FakeController) -> None:
    controller.robot_mode = 3
    with pytest.raises(DeviceError, match="robot mode is 'power off'"):
        connected(controller)
    assert controller.names()[-1] == "disconnect"


def test_move_follows_the_arc_with_checked_waypoints(controller: FakeController) -> None:
    device = connected(controller, arc_step_deg=5.0)
    device.move_on_circle(-12.0, RADIUS)
    path = next(args for name, args in controller.calls if name == "moveL")
    assert len(path) == 3  # -4, -8, -12 deg
    geometry = circle()
    assert [geometry.locate([*(np.array(p[:3]) * 1000), *p[3:6]]).angle_deg for p in path] == pytest.approx([-4, -8, -12])
    speed = RADIUS / 1000 * np.radians(10.0)
    assert [p[6] for p in path] == pytest.approx([speed] * 3)
    assert path[-1][8] == 0.0 and path[0][8] > 0.0  # blended through, stops at the end
    checked = [args for name, args in controller.calls if name == "isPoseWithinSafetyLimits"]
    assert checked == [p[:6] for p in path]
    assert controller.names().index("isPoseWithinSafetyLimits") < controller.names().index("moveL")
    assert device.angle_deg() == pytest.approx(-12.0)


def test_a_radius_change_moves_radially_first(controller: FakeController) -> None:
    device = connected(controller)
    device.move_on_circle(5.0, 300.0)
    path = next(args for name, args in controller.calls if name == "moveL")
    first = circle().locate([*(np.array(path[0][:3]) * 1000), *path[0][3:6]])
    assert (first.angle_deg, first.radius_mm) == pytest.approx((0.0, 300.0))
    assert circle().locate(device.pose_mm()).radius_mm == pytest.approx(300.0)


def test_controller_safety_limits_refuse_before_motion(controller: FakeController) -> None:
    controller.pose_ok = lambda pose: pose[1] > -0.2  # a safety plane at y = -200 mm
    device = connected(controller)
    with pytest.raises(LimitViolation, match="waypoint .* violates the controller's safety limits; nothing moved"):
        device.move_on_circle(-45.0, RADIUS)
    assert "moveL" not in controller.names()


def test_tcp_box_refuses_before_asking_the_controller(controller: FakeController) -> None:
    device = connected(controller, tcp_box_mm=[[0, 1000], [-100, 1000], [0, 1000]])
    with pytest.raises(LimitViolation, match=r"y = -\d+.\d mm outside tcp_box_mm \[-100, 1000\]; nothing moved"):
        device.move_on_circle(-30.0, RADIUS)
    assert "isPoseWithinSafetyLimits" not in controller.names() and "moveL" not in controller.names()


def test_joint_limits_and_reach(controller: FakeController) -> None:
    device = connected(controller, joint_limits_deg=[[-360, 360]] * 5 + [[-10, 10]])
    controller.ik = lambda pose: [0.0] * 5 + [np.radians(45.0)]
    with pytest.raises(LimitViolation, match=r"joint 5 would be at 45.0 deg, outside \[-10, 10\]; nothing moved"):
        device.move_on_circle(10.0, RADIUS)
    controller.ik = lambda pose: None
    with pytest.raises(LimitViolation, match="out of reach"):
        device.move_on_circle(10.0, RADIUS)
    assert "moveL" not in controller.names()


def test_a_tcp_off_the_circle_is_not_moved(controller: FakeController) -> None:
    controller.tcp[2] += 0.05
    device = connected(controller)
    with pytest.raises(DeviceError, match="not on the measurement circle .*50.0 mm off its plane.*nothing moved"):
        device.move_on_circle(10.0, RADIUS)
    assert "moveL" not in controller.names()


def test_protective_stop_before_and_during_a_move(controller: FakeController) -> None:
    device = connected(controller)
    controller.protective = True
    with pytest.raises(ProtectiveStop, match="before moving"):
        device.move_on_circle(10.0, RADIUS)
    assert "moveL" not in controller.names()
    controller.protective = False
    controller.stop_during_motion = "protective"
    with pytest.raises(ProtectiveStop, match="protective stop") as caught:
        device.move_on_circle(10.0, RADIUS)
    assert isinstance(caught.value, OperatorActionRequired)
    assert "stopL" in controller.names()


@pytest.mark.parametrize(("state", "value", "message"), [("emergency", True, "emergency stop is engaged"),
                                                         ("safety_mode", 5, "safety mode is 'safeguard stop'")])
def test_other_safety_stops_are_fatal(controller: FakeController, state: str, value: Any, message: str) -> None:
    device = connected(controller)
    setattr(controller, state, value)
    with pytest.raises(DeviceError, match=message) as caught:
        device.move_on_circle(10.0, RADIUS)
    assert not isinstance(caught.value, OperatorActionRequired)


def test_recover_unlocks_through_the_dashboard(controller: FakeController) -> None:
    device = connected(controller)
    controller.protective, controller.unlock_refusals = True, 1
    device.recover()
    names = controller.names()
    assert names.count("unlockProtectiveStop") == 2  # refused within 5 s of the stop, then released
    assert names.index("closeSafetyPopup") < names.index("unlockProtectiveStop") < names.index("reuploadScript")
    assert not controller.protective
    device.move_on_circle(3.0, RADIUS)
    controller.emergency = True
    with pytest.raises(DeviceError, match="emergency stop"):
        device.recover()


def test_a_move_that_does_not_finish_is_stopped(controller: FakeController) -> None:
    controller.motion_polls = 10**9
    device = connected(controller, move_timeout_s=0.05)
    with pytest.raises(DeviceError, match="still moving after 0.05 s; stopped"):
        device.move_on_circle(10.0, RADIUS)
    assert {"stopL", "stopJ"} <= set(controller.names())


def test_a_lost_connection_sends_nothing_more(controller: FakeController) -> None:
    """ur-rtde waits forever for the answer to a command sent over a lost connection: nothing is sent."""
    device = connected(controller)
    controller.connected = False
    sent = len(controller.calls)
    with pytest.raises(DeviceVanished, match="the connection to the controller at ursim .* was lost") as caught:
        device.move_on_circle(10.0, RADIUS)
    assert caught.value.connection == "ursim"
    device.safe_state()
    device.close()
    assert controller.names()[sent:] == ["disconnect"] * 3  # control, receive, dashboard; no stop, no stopScript


def test_a_controller_that_falls_silent_while_ur_rtde_waits_is_a_vanished_robot(controller: FakeController) -> None:
    """No package arrives while ur-rtde's ``moveL`` waits for the controller's answer, and ur-rtde still counts
    the connection as up: the adapter gives up after LINK_SILENCE_S, not when ur-rtde does (300 s or never),
    and sends nothing more."""
    device = connected(controller)
    answer = threading.Event()

    def move_l(path: list[list[float]], asynchronous: bool) -> bool:  # an answer that never comes
        answer.wait(60.0)
        return False

    controller.moveL = move_l  # type: ignore[method-assign]
    controller.getTimestamp = lambda: 12.5  # type: ignore[method-assign]  # the last package: nothing newer arrives
    started = time.monotonic()
    try:
        with pytest.raises(DeviceVanished, match="at ursim .* was lost while ur-rtde waited for the controller's "
                           "answer to moveL: check the network cable"):
            device.move_on_circle(10.0, RADIUS)
        waited = time.monotonic() - started
        sent = len(controller.calls)
        device.safe_state()
        device.close()
    finally:
        answer.set()
    assert LINK_SILENCE_S <= waited < 10 * LINK_SILENCE_S
    assert controller.names()[sent:] == ["disconnect"] * 3  # control, receive, dashboard; no stop, no stopScript


def test_a_command_interrupted_while_ur_rtde_waits_is_answered_before_the_next_is_sent(
    controller: FakeController,
) -> None:
    """A signal (a second Ctrl-C) interrupts the adapter while ur-rtde's ``moveL`` waits for the controller's
    answer; the ``stopL`` that ``safe_state`` sends next waits for that answer first, as ur-rtde's commands go
    one at a time over the same registers."""
    device = connected(controller)
    answer = threading.Event()
    order: list[str] = []

    class Interrupted(Exception):
        pass

    def interrupt(signum: int, frame: Any) -> None:
        raise Interrupted

    def move_l(path: list[list[float]], asynchronous: bool) -> bool:  # waiting for the controller
        os.kill(os.getpid(), signal.SIGUSR1)  # the signal reaches the adapter's thread during the wait
        answer.wait(60.0)
        order.append("moveL answered")
        return True

    def timestamp() -> float:  # the watch asks for the stream's time while it waits; the answer comes then
        if order == ["safe_state"]:
            answer.set()
        return time.monotonic()

    controller.moveL = move_l  # type: ignore[method-assign]
    controller.stopL = lambda: order.append("stopL")  # type: ignore[method-assign]
    previous = signal.signal(signal.SIGUSR1, interrupt)
    try:
        with pytest.raises(Interrupted):
            device.move_on_circle(10.0, RADIUS)
        controller.getTimestamp = timestamp  # type: ignore[method-assign]
        order.append("safe_state")
        device.safe_state()
    finally:
        signal.signal(signal.SIGUSR1, previous)
        answer.set()
    assert order == ["safe_state", "moveL answered", "stopL"]


def test_safe_state_never_raises(controller: FakeController) -> None:
    device = connected(controller)

    def broken() -> None:
        raise RuntimeError("RTDE connection lost")

    controller.stopL = broken  # type: ignore[method-assign]
    device.safe_state()
    assert controller.names()[-1] == "stopJ"
    device.close()
    assert "stopScript" in controller.names()
