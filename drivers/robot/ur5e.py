"""A Universal Robots UR5e (e-Series) carrying the camera on the measurement circle, via ur-rtde.

ur-rtde (SDU Robotics, https://sdurobotics.gitlab.io/ur_rtde/) gives three clients:
``RTDEReceiveInterface`` (state: ``getActualTCPPose``, ``getActualQ``,
``isProtectiveStopped``, ``isEmergencyStopped``, ``getSafetyMode``, ``getRobotMode``),
``RTDEControlInterface`` (``moveL`` along a path, ``stopL``/``stopJ``,
``isPoseWithinSafetyLimits``, ``getInverseKinematics``, ``reuploadScript``) and
``DashboardClient`` (port 29999: ``unlockProtectiveStop``, ``closeSafetyPopup``,
``isInRemoteControl``, robot model, serial number, PolyScope version). The SDK is
imported only when a robot connects.

Poses on the controller are in m and rad; this module speaks mm and degrees and
converts at the boundary. Every motion is planned as waypoints on the circle, and
every waypoint is checked against the configured TCP box and joint limits and the
controller's ``isPoseWithinSafetyLimits`` before anything moves. Every control command runs with a watch
on the link (:meth:`UR5eRobot._command`): a connection lost while ur-rtde waits for the controller's answer
raises :class:`DeviceVanished` within :data:`LINK_SILENCE_S`.
"""

from __future__ import annotations

import contextlib
import math
import socket
import struct
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from drivers.device import LinkedDevice
from drivers.errors import DeviceError, DeviceVanished, LimitViolation, MissingSDKError, ProtectiveStop, not_connected
from drivers.protocols import DeviceIdentity, RobotPose
from drivers.robot.circle import MeasurementCircle

DASHBOARD_PORT = 29999
RTDE_PORT = 30004
DASHBOARD_GREETING = "Connected: Universal Robots Dashboard Server"
"""First line the dashboard server sends (UR "Dashboard Server e-Series, port 29999")."""
RTDE_REQUEST_PROTOCOL_VERSION = 86
"""Package type 'V' (UR "Real-Time Data Exchange (RTDE) Guide": header uint16 size, uint8 type)."""

SAFETY_MODES: dict[int, str] = {
    1: "normal",
    2: "reduced",
    3: "protective stop",
    4: "recovery",
    5: "safeguard stop",
    6: "system emergency stop",
    7: "robot emergency stop",
    8: "violation",
    9: "fault",
    10: "validate joint id",
    11: "undefined safety mode",
    12: "automatic mode safeguard stop",
    13: "system three-position enabling stop",
}
"""``safety_mode`` of the RTDE guide's output list (ur-rtde ``getSafetyMode``)."""

ROBOT_MODES: dict[int, str] = {
    -1: "no controller",
    0: "disconnected",
    1: "confirm safety",
    2: "booting",
    3: "power off",
    4: "power on",
    5: "idle",
    6: "backdrive",
    7: "running",
    8: "updating firmware",
}
"""``robot_mode`` of the RTDE guide's output list (ur-rtde ``getRobotMode``)."""

ARRIVAL_LAG_S = 2.0
"""How long the receive stream may lag the control stream after a path ends. The wait ends as soon as the
pose has arrived, so only a move that really stopped short waits this long; 0.25 s was exceeded on a loaded
2-core machine (the emulated controller's stream arrived late, the arm had reached its target)."""

LINK_SILENCE_S = 3.0
"""How long the controller's RTDE stream may stay silent while a ur-rtde call waits for the controller before
the robot counts as vanished. A controller sends a package every 2 ms (500 Hz; 8 ms at 125 Hz), so 3 s without
one is no late package but a lost link, even on a loaded lab computer; ur-rtde 1.6.5 itself drops a connection
that stayed silent for about 2.5 s (then ``isConnected`` is false, which the watch sees at once), and a
connection the controller closed is seen at once."""

WATCH_INTERVAL_S = 0.1
"""How often a move hands the pose it read back to its ``watch`` (a live console shows it a few times a second)."""

SAFE_MODES = frozenset({1, 2})
ROBOT_RUNNING = 7


@dataclass(frozen=True)
class RTDEInterfaces:
    """The three ur-rtde clients of one controller."""

    control: Any
    receive: Any
    dashboard: Any


def _recv_exactly(sock: socket.socket, size: int) -> bytes:
    data = b""
    while len(data) < size:
        chunk = sock.recv(size - len(data))
        if not chunk:
            raise ConnectionError("connection closed by the peer")
        data += chunk
    return data


def probe_controller(host: str, timeout_s: float) -> str:
    """Check within ``timeout_s`` per server that ``host`` runs a UR dashboard server (it greets
    with :data:`DASHBOARD_GREETING`) and an RTDE server (it answers a protocol-version request).

    ur-rtde's constructors wait without limit for a server that accepts but never answers;
    this probe turns "nothing there" into a prompt :class:`DeviceError` naming host and port.
    Returns the dashboard's greeting.
    """
    name = f"UR5e at {host}"
    try:
        with socket.create_connection((host, DASHBOARD_PORT), timeout=timeout_s) as sock:
            sock.settimeout(timeout_s)
            greeting = sock.makefile("rb").readline(200).decode("ascii", "replace").strip()
    except OSError as exc:
        raise DeviceError(
            name, f"no UR dashboard server answers at {host}:{DASHBOARD_PORT} within {timeout_s:g} s ({exc})"
        ) from exc
    if not greeting.startswith(DASHBOARD_GREETING):
        raise DeviceError(name, f"{host}:{DASHBOARD_PORT} answered {greeting!r}, not a UR dashboard server")
    try:
        with socket.create_connection((host, RTDE_PORT), timeout=timeout_s) as sock:
            sock.settimeout(timeout_s)
            sock.sendall(struct.pack(">HBH", 5, RTDE_REQUEST_PROTOCOL_VERSION, 2))
            size, kind = struct.unpack(">HB", _recv_exactly(sock, 3))
            _recv_exactly(sock, max(size - 3, 0))
    except OSError as exc:
        raise DeviceError(
            name, f"no RTDE server answers at {host}:{RTDE_PORT} within {timeout_s:g} s ({exc})"
        ) from exc
    if kind != RTDE_REQUEST_PROTOCOL_VERSION:
        raise DeviceError(name, f"{host}:{RTDE_PORT} does not speak RTDE (reply package type {kind})")
    return greeting


def connect_ur_rtde(host: str, timeout_s: float) -> RTDEInterfaces:
    """Probe ``host`` (:func:`probe_controller`), then open ur-rtde's dashboard, receive and
    control interfaces. The control interface uploads ur-rtde's control script, which an
    e-Series controller only accepts in Remote Control mode."""
    name = f"UR5e at {host}"
    try:
        import dashboard_client
        import rtde_control
        import rtde_receive
    except ImportError as exc:
        raise MissingSDKError(name, f"ur-rtde is not installed ({exc}): pip install ur-rtde") from exc
    probe_controller(host, timeout_s)
    try:
        dashboard = dashboard_client.DashboardClient(host)
        dashboard.connect(round(timeout_s * 1000))
        if not dashboard.isInRemoteControl():
            raise DeviceError(
                name, "the robot is in Local Control: switch it to Remote Control on the teach pendant "
                "(Settings > System > Remote Control, then the mode icon at the top right)"
            )
        receive = rtde_receive.RTDEReceiveInterface(host)
        control = rtde_control.RTDEControlInterface(host)
    except RuntimeError as exc:
        raise DeviceError(name, f"ur-rtde could not connect: {exc}") from exc
    return RTDEInterfaces(control=control, receive=receive, dashboard=dashboard)


def _link_up(rtde: RTDEInterfaces) -> bool:
    """Whether both RTDE connections are up (ur-rtde ``isConnected``)."""
    try:
        return bool(rtde.receive.isConnected() and rtde.control.isConnected())
    except RuntimeError:
        return False


def _to_controller(pose_mm: np.ndarray) -> list[float]:
    return [*(float(v) / 1000.0 for v in pose_mm[:3]), *(float(v) for v in pose_mm[3:])]


def _from_controller(pose_m: Sequence[float]) -> np.ndarray:
    return np.array([*(1000.0 * v for v in pose_m[:3]), *pose_m[3:]], float)


class UR5eRobot(LinkedDevice):
    """A UR5e as a :class:`~drivers.protocols.Robot` moving the camera on a :class:`MeasurementCircle`.

    Limits: ``angle_limits_deg`` and ``radius_max_mm`` on the circle; ``tcp_box_mm``
    ([[x_min, x_max], [y_min, y_max], [z_min, z_max]] in the base frame) for every
    waypoint; ``joint_limits_deg`` (six [min, max] pairs) for the inverse-kinematics
    solution of every waypoint. Motions run at ``speed_deg_s`` along the circle and
    wait ``settle_s`` after arriving. ``interfaces`` opens the ur-rtde clients
    (default :func:`connect_ur_rtde`).
    """

    def __init__(
        self,
        host: str,
        circle: MeasurementCircle,
        *,
        angle_limits_deg: tuple[float, float] = (-90.0, 90.0),
        radius_max_mm: float = 850.0,
        speed_deg_s: float = 10.0,
        acceleration_deg_s2: float = 20.0,
        tcp_box_mm: Sequence[Sequence[float]] | None = None,
        joint_limits_deg: Sequence[Sequence[float]] | None = None,
        arc_step_deg: float = 5.0,
        settle_s: float = 0.5,
        tolerance_mm: float = 2.0,
        tolerance_deg: float = 1.0,
        connect_timeout_s: float = 2.0,
        move_timeout_s: float = 120.0,
        poll_interval_s: float = 0.02,
        interfaces: Callable[[str, float], RTDEInterfaces] = connect_ur_rtde,
    ) -> None:
        if joint_limits_deg is not None and len(joint_limits_deg) != 6:
            raise ValueError(f"joint_limits_deg needs six [min, max] pairs, got {len(joint_limits_deg)}")
        if tcp_box_mm is not None and len(tcp_box_mm) != 3:
            raise ValueError("tcp_box_mm needs three [min, max] pairs (x, y, z)")
        super().__init__(host, f"UR5e at {host}")
        self.circle = circle
        self.angle_limits_deg = angle_limits_deg
        self.radius_max_mm = radius_max_mm
        self.speed_deg_s = speed_deg_s
        self.acceleration_deg_s2 = acceleration_deg_s2
        self.tcp_box_mm = tcp_box_mm
        self.joint_limits_deg = joint_limits_deg
        self.arc_step_deg = arc_step_deg
        self.settle_s = settle_s
        self.tolerance_mm = tolerance_mm
        self.tolerance_deg = tolerance_deg
        self.connect_timeout_s = connect_timeout_s
        self.move_timeout_s = move_timeout_s
        self.poll_interval_s = poll_interval_s
        self._open_interfaces = interfaces
        self._rtde: RTDEInterfaces | None = None
        self._link_lost = False
        self._pending: tuple[str, threading.Event] | None = None

    @property
    def host(self) -> str:
        """The controller's network host (name or IP address)."""
        return self.connection

    # -- Robot --------------------------------------------------------------------

    def connect(self) -> None:
        """Open the ur-rtde clients, read model, serial and PolyScope version from the dashboard
        and refuse to continue if the arm is not running or is stopped for safety."""
        if self._rtde is not None:
            return
        self._rtde = self._open_interfaces(self.host, self.connect_timeout_s)
        self._link_lost, self._pending = False, None
        try:
            dashboard = self._rtde.dashboard
            self._identity = DeviceIdentity(
                backend="ur_rtde",
                model=str(dashboard.getRobotModel()),
                serial=str(dashboard.getSerialNumber()),
                firmware=str(dashboard.polyscopeVersion()),
            )
            self._check_safety("connect")
            mode = int(self._rtde.receive.getRobotMode())
            if mode != ROBOT_RUNNING:
                raise DeviceError(
                    self.name,
                    f"robot mode is '{ROBOT_MODES.get(mode, mode)}', not 'running': power the arm on and "
                    "release the brakes on the teach pendant",
                )
        except Exception:
            self.close()
            raise

    def close(self) -> None:
        """Stop ur-rtde's control script and disconnect all clients (idempotent, never raises).
        Over a lost connection the script cannot be stopped (ur-rtde would wait for it forever)."""
        rtde, self._rtde = self._rtde, None
        if rtde is None:
            return
        with contextlib.suppress(Exception):
            if self._link_alive(rtde):
                self._command(rtde, "stopScript")
        for action in (rtde.control.disconnect, rtde.receive.disconnect, rtde.dashboard.disconnect):
            with contextlib.suppress(Exception):
                action()

    def safe_state(self) -> None:
        """Decelerate any motion to a stop (``stopL``, then ``stopJ``); never raises. Over a lost
        connection nothing can be sent (ur-rtde would wait for the answer forever): a path under way is
        not stopped from here, so check the cell (the pendant's stop) before going near the arm."""
        rtde = self._rtde
        if rtde is None or not self._link_alive(rtde):
            return
        for stop in ("stopL", "stopJ"):
            with contextlib.suppress(Exception):  # a lost connection must not stop the safe-state sweep
                self._command(rtde, stop)

    def settings(self) -> Mapping[str, Any]:
        """Circle geometry, limits and motion parameters."""
        return {
            "host": self.host,
            "circle_center_mm": self.circle.center.tolist(),
            "rotation_axis": self.circle.axis.tolist(),
            "zero_radius_mm": self.circle.zero_radius_mm,
            "angle_limits_deg": list(self.angle_limits_deg),
            "radius_max_mm": self.radius_max_mm,
            "speed_deg_s": self.speed_deg_s,
            "acceleration_deg_s2": self.acceleration_deg_s2,
            "tcp_box_mm": [list(pair) for pair in self.tcp_box_mm] if self.tcp_box_mm else None,
            "joint_limits_deg": [list(pair) for pair in self.joint_limits_deg] if self.joint_limits_deg else None,
        }

    def move_on_circle(
        self, angle_deg: float, radius_mm: float, watch: Callable[[RobotPose], None] | None = None
    ) -> None:
        """Move along the circle to ``angle_deg`` at ``radius_mm`` (ur-rtde ``moveL`` with a path of
        blended waypoints, asynchronous, watched for safety stops); returns when settled. ``watch`` gets
        the pose read back (``getActualTCPPose``) every ``WATCH_INTERVAL_S`` while the path runs, and at arrival.

        Raises :class:`LimitViolation` before any motion if the target or any waypoint lies
        outside the configured limits or the controller's safety limits.
        """
        low, high = self.angle_limits_deg
        if not low <= angle_deg <= high:
            raise LimitViolation(
                self.name, f"angle {angle_deg} deg lies outside angle_limits_deg [{low}, {high}]; nothing moved"
            )
        if not 0.0 < radius_mm <= self.radius_max_mm:
            raise LimitViolation(
                self.name, f"radius {radius_mm} mm lies outside (0, {self.radius_max_mm}] mm; nothing moved"
            )
        rtde = self._connected()
        self._check_safety("before moving")
        here = self.circle.locate(_from_controller(rtde.receive.getActualTCPPose()))
        if here.off_plane_mm > self.tolerance_mm or here.aim_error_deg > self.tolerance_deg or here.radius_mm < 1.0:
            raise DeviceError(
                self.name,
                f"the TCP is not on the measurement circle ({here.off_plane_mm:.1f} mm off its plane, orientation "
                f"{here.aim_error_deg:.1f}° off): move it to the 0° pose first; nothing moved",
            )
        waypoints = []
        if abs(here.radius_mm - radius_mm) > self.tolerance_mm:
            waypoints.append(self.circle.pose(here.angle_deg, radius_mm))
        if abs(here.angle_deg - angle_deg) > 1e-6:
            waypoints += self.circle.arc(here.angle_deg, angle_deg, radius_mm, self.arc_step_deg)
        if not waypoints:
            if watch is not None:
                watch(self.pose())
            return
        what = f"move to {angle_deg} deg at {radius_mm} mm"
        self._check_waypoints(rtde, waypoints)
        self._run_path(rtde, waypoints, radius_mm, what, watch)
        # RTDEReceiveInterface has its own RTDE stream, which can lag the control stream that
        # reported the end of the path by a few output periods: allow it ARRIVAL_LAG_S to catch up
        # (and to show a safety stop that ended the path).
        deadline = time.monotonic() + ARRIVAL_LAG_S
        while True:
            self._check_safety(what)
            reached = self.circle.locate(_from_controller(rtde.receive.getActualTCPPose()))
            arrived = (
                abs(reached.angle_deg - angle_deg) <= self.tolerance_deg
                and abs(reached.radius_mm - radius_mm) <= self.tolerance_mm
            )
            if arrived or time.monotonic() > deadline:
                break
            time.sleep(self.poll_interval_s)
        if not arrived:
            raise DeviceError(
                self.name,
                f"stopped at {reached.angle_deg:.2f} deg / {reached.radius_mm:.1f} mm instead of "
                f"{angle_deg} deg / {radius_mm} mm",
            )
        time.sleep(self.settle_s)
        if watch is not None:
            watch(self.pose())

    def angle_deg(self) -> float:
        """Current angle on the circle from the actual TCP pose (``getActualTCPPose``)."""
        return self.pose().angle_deg

    def pose(self) -> RobotPose:
        """Angle and radius on the circle and the TCP position, from the actual TCP pose (``getActualTCPPose``)."""
        pose = self.pose_mm()
        where = self.circle.locate(pose)
        return RobotPose(where.angle_deg, where.radius_mm, (float(pose[0]), float(pose[1]), float(pose[2])))

    def pose_mm(self) -> np.ndarray:
        """Actual TCP pose ``[x, y, z (mm), rx, ry, rz (rad)]`` in the base frame."""
        return _from_controller(self._connected().receive.getActualTCPPose())

    def joints_deg(self) -> np.ndarray:
        """Actual joint positions in degrees (``getActualQ``)."""
        return np.degrees(np.asarray(self._connected().receive.getActualQ(), float))

    def recover(self) -> None:
        """Clear a protective stop through the dashboard server (``closeSafetyPopup``,
        ``unlockProtectiveStop``) and restart ur-rtde's control script (``reuploadScript``).

        Call only after an operator confirmed the cell is safe. The controller refuses to
        unlock within 5 s of the stop, so this retries for up to 10 s; it returns when the
        control script runs again. An emergency stop cannot be cleared in software.
        """
        rtde = self._connected()
        if rtde.receive.isEmergencyStopped():
            raise DeviceError(self.name, "emergency stop is engaged: release the button and reset it on the pendant")
        rtde.dashboard.closeSafetyPopup()
        deadline = time.monotonic() + 10.0
        while rtde.receive.isProtectiveStopped():
            try:
                rtde.dashboard.unlockProtectiveStop()
            except RuntimeError as exc:
                if time.monotonic() > deadline:
                    raise DeviceError(self.name, f"could not unlock the protective stop: {exc}") from exc
                time.sleep(0.5)
        self._command(rtde, "reuploadScript")
        self._wait_for_control_script(rtde, "after recovery")

    # -- helpers ------------------------------------------------------------------

    def _connected(self) -> RTDEInterfaces:
        """The clients, checked before every use: a command over a lost connection would wait forever."""
        if self._rtde is None:
            raise not_connected(self.name)
        if not self._link_alive(self._rtde):
            raise self._vanished("")
        return self._rtde

    def _link_alive(self, rtde: RTDEInterfaces) -> bool:
        """Both RTDE connections up, and no watched call gave up on them."""
        return not self._link_lost and _link_up(rtde)

    def _vanished(self, when: str) -> DeviceVanished:
        return DeviceVanished(
            self.name, f"the connection to the controller at {self.host} (RTDE port {RTDE_PORT}) was lost{when}: check "
            "the network cable and that the controller is on and in Remote Control", self.host,
        )

    def _command(self, rtde: RTDEInterfaces, name: str, *args: Any) -> Any:
        """ur-rtde's control command ``name`` with ``args``, which waits for the controller's answer, with a
        watch on the link: :class:`DeviceVanished` once it is lost (``isConnected`` false, or the receive stream
        silent for :data:`LINK_SILENCE_S`).

        ur-rtde's own wait polls the state its receive thread last stored, which a lost link no longer
        changes: it ends only at its time limit (300 s, or none at all while ``moveL`` with a path waits for
        its script to start). ur-rtde releases Python's interpreter lock while it waits, so the command runs
        in a thread of its own and this one watches. A command given up on is left to end in its thread when
        ur-rtde gives up; nothing more is sent to the controller. Commands go one at a time: one whose wait
        was interrupted (a second Ctrl-C) is answered before the next is sent."""
        if self._pending is not None:
            self._watch(rtde, *self._pending)
        outcome: list[tuple[bool, Any]] = []
        answered = threading.Event()

        def run() -> None:
            try:
                outcome.append((True, getattr(rtde.control, name)(*args)))
            except BaseException as exc:  # handed to the caller
                outcome.append((False, exc))
            finally:
                answered.set()

        self._pending = (name, answered)
        threading.Thread(target=run, name=f"ur-rtde {name} ({self.host})", daemon=True).start()
        self._watch(rtde, name, answered)
        self._pending = None
        succeeded, value = outcome[0]
        if not succeeded:
            raise value
        return value

    def _watch(self, rtde: RTDEInterfaces, name: str, answered: threading.Event) -> None:
        """Until ``answered`` is set; :class:`DeviceVanished` once the link is lost meanwhile."""
        stamp, heard = rtde.receive.getTimestamp(), time.monotonic()
        while not answered.wait(self.poll_interval_s):
            up = _link_up(rtde)
            if up and (latest := rtde.receive.getTimestamp()) != stamp:
                stamp, heard = latest, time.monotonic()
            if not up or time.monotonic() - heard > LINK_SILENCE_S:
                self._link_lost = True
                raise self._vanished(f" while ur-rtde waited for the controller's answer to {name}")

    def _check_safety(self, context: str) -> None:
        """ProtectiveStop for a protective stop; a fatal DeviceError for any other safety stop."""
        receive = self._connected().receive
        if receive.isEmergencyStopped():
            raise DeviceError(self.name, f"{context}: emergency stop is engaged; release and reset it on the pendant")
        if receive.isProtectiveStopped():
            raise ProtectiveStop(self.name, f"{context}: the controller is in a protective stop")
        mode = int(receive.getSafetyMode())
        if mode not in SAFE_MODES:
            raise DeviceError(
                self.name, f"{context}: safety mode is '{SAFETY_MODES.get(mode, mode)}'; clear it on the pendant"
            )

    def _wait_for_control_script(self, rtde: RTDEInterfaces, context: str, timeout_s: float = 5.0) -> None:
        """Wait until ur-rtde's control script runs (runtime state PLAYING): ``reuploadScript``
        returns as soon as the script is sent, and commands sent before it runs fail."""
        deadline = time.monotonic() + timeout_s
        while not rtde.control.isProgramRunning():
            if time.monotonic() > deadline:
                raise DeviceError(self.name, f"{context}: ur-rtde's control script did not start within {timeout_s:g} s")
            time.sleep(self.poll_interval_s)

    def _refused(self, rtde: RTDEInterfaces, context: str) -> None:
        """ur-rtde answers False also when the controller could not run the query (a safety stop,
        or its control script not running): raise that instead of a limit violation."""
        self._check_safety(context)
        if not rtde.control.isProgramRunning():
            raise DeviceError(self.name, f"{context}: ur-rtde's control script is not running on the controller; nothing moved")

    def _check_waypoints(self, rtde: RTDEInterfaces, waypoints: list[np.ndarray]) -> None:
        """Every waypoint inside the TCP box (checked first, for all), then within the controller's
        safety limits and with an inverse-kinematics solution (seeded by the previous one) inside
        the joint limits."""

        def where(k: int) -> str:
            return f"waypoint {k + 1}/{len(waypoints)} at {np.round(waypoints[k][:3], 1).tolist()} mm"

        if self.tcp_box_mm is not None:
            for k, pose in enumerate(waypoints):
                for axis, value, (low, high) in zip("xyz", pose[:3], self.tcp_box_mm):
                    if not low <= value <= high:
                        raise LimitViolation(
                            self.name, f"{where(k)}: {axis} = {value:.1f} mm outside tcp_box_mm [{low}, {high}]; nothing moved"
                        )
        q_near = list(rtde.receive.getActualQ())
        for k, pose in enumerate(waypoints):
            rtde = self._connected()
            target = _to_controller(pose)
            if not self._command(rtde, "isPoseWithinSafetyLimits", target):
                self._refused(rtde, f"checking {where(k)}")
                raise LimitViolation(self.name, f"{where(k)} violates the controller's safety limits; nothing moved")
            if not self._command(rtde, "getInverseKinematicsHasSolution", target, q_near):
                self._refused(rtde, f"checking {where(k)}")
                raise LimitViolation(self.name, f"{where(k)} is out of reach (no inverse kinematics); nothing moved")
            q_near = list(self._command(rtde, "getInverseKinematics", target, q_near))
            if self.joint_limits_deg is not None:
                for joint, (value, (low, high)) in enumerate(zip(np.degrees(q_near), self.joint_limits_deg)):
                    if not low <= value <= high:
                        raise LimitViolation(
                            self.name,
                            f"{where(k)}: joint {joint} would be at {value:.1f} deg, outside [{low}, {high}]; nothing moved",
                        )

    def _run_path(
        self, rtde: RTDEInterfaces, waypoints: list[np.ndarray], radius_mm: float, what: str,
        watch: Callable[[RobotPose], None] | None,
    ) -> None:
        """Run the path asynchronously and watch it: a safety stop raises at once, a path that
        does not finish within ``move_timeout_s`` is stopped; ``watch`` gets the pose every ``WATCH_INTERVAL_S``."""
        radius_m = radius_mm / 1000.0
        speed = radius_m * math.radians(self.speed_deg_s)
        acceleration = radius_m * math.radians(self.acceleration_deg_s2)
        path = []
        for k, pose in enumerate(waypoints):
            last = k == len(waypoints) - 1
            chord_m = radius_m * math.radians(self.arc_step_deg)
            path.append([*_to_controller(pose), speed, acceleration, 0.0 if last else 0.25 * chord_m])
        if not self._command(rtde, "moveL", path, True):
            self._check_safety(what)
            raise DeviceError(self.name, f"{what}: the controller did not accept the path")
        deadline = time.monotonic() + self.move_timeout_s
        watched = -math.inf
        while True:
            try:
                self._check_safety(what)  # the connection first: a query over a lost one never returns
            except DeviceError:
                self.safe_state()
                raise
            if not rtde.control.getAsyncOperationProgressEx().isAsyncOperationRunning():
                break
            if watch is not None and time.monotonic() - watched >= WATCH_INTERVAL_S:
                watched = time.monotonic()
                watch(self.pose())
            if time.monotonic() > deadline:
                self.safe_state()
                raise DeviceError(self.name, f"{what}: still moving after {self.move_timeout_s} s; stopped")
            time.sleep(self.poll_interval_s)
        self._check_safety(what)
