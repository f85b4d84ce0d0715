"""State of an emulated UR e-Series controller: modes, safety, program, motion, registers.

The modes and their numbers are those of the RTDE guide's output table (``robot_mode``,
``safety_mode``, ``safety_status_bits``, ``robot_status_bits``, ``runtime_state``); the
transitions follow the Dashboard Server e-Series (port 29999) commands and the
"Stop recovery" guide: a protective stop halts motion and pauses the program, and
``unlock protective stop`` is refused until 5 s after the stop.

Programs arrive as URScript on the secondary/real-time script ports. The emulator does not
interpret URScript: it recognises ur-rtde's control script and carries out its register
protocol (:mod:`sim.emulators.ur.control_script`). Any other program is recorded and
refused (it never runs); none starts while the arm is not running or in a safety stop.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from sim.emulators.ur import kinematics
from sim.emulators.ur.control_script import ControlScript, is_control_script

ROBOT_MODES = {
    "NO_CONTROLLER": -1, "DISCONNECTED": 0, "CONFIRM_SAFETY": 1, "BOOTING": 2, "POWER_OFF": 3,
    "POWER_ON": 4, "IDLE": 5, "BACKDRIVE": 6, "RUNNING": 7, "UPDATING_FIRMWARE": 8,
}
SAFETY_MODES = {
    "NORMAL": 1, "REDUCED": 2, "PROTECTIVE_STOP": 3, "RECOVERY": 4, "SAFEGUARD_STOP": 5,
    "SYSTEM_EMERGENCY_STOP": 6, "ROBOT_EMERGENCY_STOP": 7, "VIOLATION": 8, "FAULT": 9,
    "VALIDATE_JOINT_ID": 10, "UNDEFINED_SAFETY_MODE": 11, "AUTOMATIC_MODE_SAFEGUARD_STOP": 12,
    "SYSTEM_THREE_POSITION_ENABLING_STOP": 13,
}
RUNTIME_STATES = {"STOPPING": 0, "STOPPED": 1, "PLAYING": 2, "PAUSING": 3, "PAUSED": 4, "RESUMING": 5}
"""``runtime_state`` (RTDE guide)."""

# safety_status_bits (RTDE guide): bit 0 normal, 1 reduced, 2 protective stopped, 3 recovery,
# 4 safeguard stopped, 5 system emergency stopped, 6 robot emergency stopped, 7 emergency
# stopped, 8 violation, 9 fault, 10 stopped due to safety.
_SAFETY_BITS = {1: (0,), 2: (1,), 3: (2, 10), 4: (3,), 5: (4, 10), 6: (5, 7, 10), 7: (6, 7, 10), 8: (8, 10), 9: (9, 10)}

UNLOCK_REFUSED = (
    "Cannot unlock protective stop until 5s after occurrence. Always inspect cause of protective stop before unlocking"
)

ROTATION_SPEED_RAD_S = 1.0
"""Speed of a pure reorientation (moveL's speed is the TCP's linear speed)."""


@dataclass
class _Segment:
    start: np.ndarray
    target: np.ndarray
    speed: float  # m/s


@dataclass
class _Motion:
    segments: list[_Segment]
    started: float
    progress: Callable[[int], None]
    index: int = 0
    done: threading.Event = field(default_factory=threading.Event)


@dataclass(frozen=True)
class SafetyPlane:
    """A safety plane of the installation: the TCP must stay on the side ``normal`` points to,
    ``normal . p >= offset_m`` (base frame)."""

    normal: tuple[float, float, float]
    offset_m: float

    def allows(self, position: Sequence[float]) -> bool:
        return float(np.dot(self.normal, position[:3])) >= self.offset_m - 1e-9


class URController:
    """One emulated UR5e controller. Thread-safe; all servers share it.

    ``q`` is the initial joint position (rad), ``tcp`` the TCP offset from the flange.
    ``safety_planes`` limit the TCP (``is_within_safety_limits`` and motion: crossing one
    is a protective stop). ``unlock_delay_s`` is the controller's 5 s wait before a
    protective stop can be unlocked; ``script_start_s`` the time a received program takes to
    start (None: it never starts); ``time_scale`` runs motions that many times faster than commanded (tests).
    """

    def __init__(
        self,
        q: Sequence[float],
        *,
        tcp: Sequence[float] = (0.0,) * 6,
        robot_mode: str = "POWER_OFF",
        remote_control: bool = True,
        safety_planes: Sequence[SafetyPlane] = (),
        unlock_delay_s: float = 5.0,
        script_start_s: float | None = 0.05,
        time_scale: float = 1.0,
        polyscope_version: tuple[int, int, int, int] = (5, 11, 6, 1107777),
        serial_number: str = "20205500001",
        programs: Sequence[str] = ("calibration.urp",),
    ) -> None:
        self.lock = threading.RLock()
        self.started = time.monotonic()
        self.q = np.array(q, float)
        self.tcp = tuple(float(v) for v in tcp)
        self.pose = kinematics.forward(self.q, self.tcp)
        self.qd = np.zeros(6)
        self.tcp_speed = np.zeros(6)
        self.robot_mode = ROBOT_MODES[robot_mode]
        self.safety_mode = SAFETY_MODES["NORMAL"]
        self.runtime_state = RUNTIME_STATES["STOPPED"]
        self.remote_control = remote_control
        self.safety_planes = list(safety_planes)
        self.unlock_delay_s = unlock_delay_s
        self.script_start_s = script_start_s
        self.time_scale = time_scale
        self.version = polyscope_version
        self.serial_number = serial_number
        self.programs = set(programs)
        self.loaded_program: str | None = None
        self.safety_popup = False
        self.stopped_at = 0.0
        self.inputs: dict[str, float | int] = {}
        self.outputs: dict[str, float | int] = {}
        self.scripts_received: list[str] = []
        self.refused_scripts: list[str] = []
        self.commands_done: list[int] = []
        self._last_tick = time.monotonic()
        self._motion: _Motion | None = None
        self._program: ControlScript | None = None
        self._closed = threading.Event()
        self._ticker = threading.Thread(target=self._tick_loop, name="ur-motion", daemon=True)
        self._ticker.start()

    # -- state read by the RTDE server ------------------------------------------------------
    def safety_status_bits(self) -> int:
        return sum(1 << bit for bit in _SAFETY_BITS.get(self.safety_mode, ()))

    def robot_status_bits(self) -> int:
        """Bit 0 power on, bit 1 program running (RTDE guide)."""
        powered = self.robot_mode in (ROBOT_MODES["POWER_ON"], ROBOT_MODES["IDLE"], ROBOT_MODES["RUNNING"])
        return int(powered) | (int(self.runtime_state == RUNTIME_STATES["PLAYING"]) << 1)

    @property
    def program_playing(self) -> bool:
        return self.runtime_state == RUNTIME_STATES["PLAYING"]

    def program_started(self) -> None:
        self.runtime_state = RUNTIME_STATES["PLAYING"]

    def within_planes(self, pose: Sequence[float]) -> bool:
        """The TCP position of ``pose`` on the allowed side of every safety plane."""
        return all(plane.allows(pose) for plane in self.safety_planes)

    @property
    def moving(self) -> bool:
        return self._motion is not None

    @property
    def protective_stopped(self) -> bool:
        return self.safety_mode == SAFETY_MODES["PROTECTIVE_STOP"]

    # -- faults injected by tests -----------------------------------------------------------
    def protective_stop(self) -> None:
        """A protective stop (as after a collision): motion halts, the program pauses, a
        safety pop-up opens."""
        with self.lock:
            self.safety_mode = SAFETY_MODES["PROTECTIVE_STOP"]
            self.stopped_at = time.monotonic()
            self.safety_popup = True
            self.halt(paused=True)
            if self.runtime_state == RUNTIME_STATES["PLAYING"]:
                self.runtime_state = RUNTIME_STATES["PAUSED"]

    def emergency_stop(self) -> None:
        """The pendant's emergency stop: motion halts, the program stops, the arm loses power."""
        with self.lock:
            self.safety_mode = SAFETY_MODES["ROBOT_EMERGENCY_STOP"]
            self.halt()
            self._end_program()
            self.robot_mode = ROBOT_MODES["POWER_OFF"]

    def hold_programs(self) -> None:
        """Programs received from now on never start (a controller that stops answering): ur-rtde's ``moveL``
        with a path restarts its control script with the path in it, and then waits for that script to run."""
        with self.lock:
            self.script_start_s = None

    # -- dashboard actions ------------------------------------------------------------------
    def power_on(self) -> None:
        with self.lock:
            if self.robot_mode == ROBOT_MODES["POWER_OFF"] and self.safety_mode == SAFETY_MODES["NORMAL"]:
                self.robot_mode = ROBOT_MODES["IDLE"]

    def power_off(self) -> None:
        with self.lock:
            self.halt()
            self._end_program()
            self.robot_mode = ROBOT_MODES["POWER_OFF"]

    def brake_release(self) -> None:
        with self.lock:
            if self.robot_mode == ROBOT_MODES["IDLE"]:
                self.robot_mode = ROBOT_MODES["RUNNING"]

    def unlock_protective_stop(self) -> bool:
        with self.lock:
            if not self.protective_stopped:
                return True
            if time.monotonic() - self.stopped_at < self.unlock_delay_s:
                return False
            self.safety_mode = SAFETY_MODES["NORMAL"]
            return True

    def stop_program(self) -> bool:
        with self.lock:
            self.halt()
            self._end_program()
            return True

    def play(self) -> bool:
        """Start the loaded program (only a loaded .urp file; the emulator does not run its content)."""
        with self.lock:
            if self.loaded_program is None or self.robot_mode != ROBOT_MODES["RUNNING"] or self.safety_mode != 1:
                return False
            self.runtime_state = RUNTIME_STATES["PLAYING"]
            return True

    def pause(self) -> bool:
        with self.lock:
            if self.runtime_state != RUNTIME_STATES["PLAYING"]:
                return False
            self.halt(paused=True)
            self.runtime_state = RUNTIME_STATES["PAUSED"]
            return True

    # -- programs ---------------------------------------------------------------------------
    def run_script(self, script: str) -> None:
        """A program received on a script port: it replaces the running one."""
        with self.lock:
            self.scripts_received.append(script)
            self.halt()
            self._end_program()
            runnable = self.robot_mode == ROBOT_MODES["RUNNING"] and self.safety_mode == SAFETY_MODES["NORMAL"]
            if not (is_control_script(script) and runnable):
                self.refused_scripts.append(script)
                return
            self._program = ControlScript(self, script)

    def close(self) -> None:
        with self.lock:
            self._end_program()
        self._closed.set()
        self._ticker.join(timeout=2.0)

    def _end_program(self) -> None:
        if self._program is not None:
            self._program.stop()
            self._program = None
        if self.runtime_state != RUNTIME_STATES["STOPPED"]:
            self.runtime_state = RUNTIME_STATES["STOPPED"]

    # -- motion -----------------------------------------------------------------------------
    def move(self, path: Sequence[tuple[np.ndarray, float]], progress: Callable[[int], None]) -> threading.Event:
        """Move linearly through every ``(pose, speed m/s)`` waypoint (blends pass through the
        waypoints); ``progress`` gets 0 at the start, the index of each waypoint reached after
        the first and -1 at the end. Returns an event set when the move ends or is stopped."""
        self.halt()
        segments, start = [], self.pose.copy()
        for target, speed in path:
            segments.append(_Segment(start, np.asarray(target, float), max(float(speed), 1e-6)))
            start = np.asarray(target, float)
        self._motion = _Motion(segments, time.monotonic(), progress)
        self._last_tick = time.monotonic()
        progress(0)
        return self._motion.done

    def halt(self, *, paused: bool = False) -> None:
        """Stop the arm. A program paused mid-move (protective stop, ``pause``) does not get to
        signal the end of its move; a stopped move or program does."""
        motion, self._motion = self._motion, None
        self.qd[:] = 0.0
        self.tcp_speed[:] = 0.0
        if motion is not None and not paused:
            motion.done.set()
            motion.progress(-1)

    def _tick_loop(self) -> None:
        while not self._closed.wait(0.004):
            with self.lock:
                if self._motion is not None:
                    self._advance(self._motion)

    def _advance(self, motion: _Motion) -> None:
        now = time.monotonic()
        while True:
            segment = motion.segments[motion.index]
            length = float(np.linalg.norm(segment.target[:3] - segment.start[:3]))
            angle = float(np.linalg.norm(kinematics.pose_error(segment.target, segment.start)[3:]))
            duration = max(length / segment.speed, angle / ROTATION_SPEED_RAD_S) / self.time_scale
            fraction = 1.0 if duration <= 0 else (now - motion.started) / duration
            if fraction < 1.0 or motion.index == len(motion.segments) - 1:
                break
            motion.started += duration
            motion.index += 1
            motion.progress(motion.index)
        fraction = min(max(fraction, 0.0), 1.0)
        rotations = Rotation.from_rotvec([segment.start[3:], segment.target[3:]])
        pose = np.array([*(segment.start[:3] + fraction * (segment.target[:3] - segment.start[:3])),
                         *Slerp([0.0, 1.0], rotations)(fraction).as_rotvec()])
        if not self.within_planes(pose):
            self.protective_stop()  # the safety system stops the arm at the plane
            return
        q = kinematics.inverse(pose, self.q, self.tcp)
        if q is None:
            self.protective_stop()
            return
        dt = max(now - self._last_tick, 1e-3)
        self.tcp_speed = np.r_[(pose[:3] - self.pose[:3]) / dt, np.zeros(3)]
        self.qd = (q - self.q) / dt
        self.pose, self.q, self._last_tick = pose, q, now
        if fraction >= 1.0:
            self._motion = None
            self.qd[:] = 0.0
            self.tcp_speed[:] = 0.0
            motion.done.set()
            motion.progress(-1)


def mode_name(table: dict[str, int], value: int) -> str:
    """The documented name of a mode number."""
    return next((name for name, number in table.items() if number == value), str(value))

