"""ur-rtde's control script, as the controller emulator carries it out.

ur-rtde's ``RTDEControlInterface`` uploads a URScript program (``def rtde_control():``)
whose main loop reads a command from ``input_int_register_0`` and its arguments from the
input registers, and answers in ``output_int_register_0`` (1 ready, 2 done with the
command), ``output_int_register_1`` (boolean results), ``output_int_register_2`` (progress
of an asynchronous move) and ``output_double_register_0..5`` (joint or pose results); the
registers may be offset by 24 (``# int register offset`` in the script). The emulator
does not interpret URScript; this module implements that register protocol as ur-rtde
1.6.5's script defines it, including the ``movel(p[...], a=, v=, r=)`` path ``moveL(path)``
injects into ``exec_move_path()``.
"""

from __future__ import annotations

import re
import threading
from collections.abc import Callable, Sequence
from typing import Protocol

import numpy as np

from sim.emulators.ur import kinematics

_MOVEL = re.compile(r"movel\(p\[([^\]]*)\],\s*a=([-+0-9.eE]+),\s*v=([-+0-9.eE]+),\s*r=([-+0-9.eE]+)\)")
_OFFSET = re.compile(r"global reg_offset_int\s*=\s*(\d+)")

# ur-rtde control-script commands (input_int_register_0) that the emulator carries out
CMD_MOVEL, CMD_PROTECTIVE_STOP, CMD_STOPL, CMD_STOPJ = 3, 31, 33, 34
CMD_IK_ARGS, CMD_IK_DEFAULT, CMD_POSE_SAFE = 30, 46, 36
CMD_MOVE_PATH, CMD_IK_HAS_SOLUTION_DEFAULT, CMD_IK_HAS_SOLUTION_ARGS, CMD_STOP_SCRIPT = 45, 60, 61, 255
READY, DONE = 1, 2


def is_control_script(script: str) -> bool:
    """Whether a received program is ur-rtde's control script."""
    return script.startswith("def rtde_control():") and "def rtde_cmd():" in script


class Robot(Protocol):
    """What the control script uses of the controller it runs on (the controller emulator's ``URController``);
    the caller holds ``lock`` around every other access."""

    lock: threading.RLock
    inputs: dict[str, float | int]
    outputs: dict[str, float | int]
    script_start_s: float | None
    q: np.ndarray
    tcp: tuple[float, ...]
    refused_scripts: list[str]
    commands_done: list[int]

    @property
    def program_playing(self) -> bool: ...
    def program_started(self) -> None: ...
    def stop_program(self) -> bool: ...
    def protective_stop(self) -> None: ...
    def within_planes(self, pose: Sequence[float]) -> bool: ...
    def move(self, path: Sequence[tuple[np.ndarray, float]], progress: Callable[[int], None]) -> threading.Event: ...
    def halt(self, *, paused: bool = False) -> None: ...


class ControlScript:
    """One run of ur-rtde's control script on ``robot``; it starts after ``robot.script_start_s``
    (the controller compiles the program first) and ends with :meth:`stop`."""

    def __init__(self, robot: Robot, script: str) -> None:
        self.robot = robot
        offset = _OFFSET.search(script)
        self.offset = int(offset.group(1)) if offset else 0
        body = script.split("def exec_move_path():", 1)[-1].split("\n    end", 1)[0]
        self.path = [
            (np.array([float(v) for v in m.group(1).split(",")]), float(m.group(3)))
            for m in _MOVEL.finditer(body)
        ]
        self.stopped = threading.Event()
        self._writes = 0
        self._operation = 0
        self._thread = threading.Thread(target=self._loop, name="ur-control-script", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        self.stopped.set()

    # -- registers -------------------------------------------------------------------------
    def _in_int(self, k: int) -> int:
        return int(self.robot.inputs.get(f"input_int_register_{k + self.offset}", 0))

    def _in_doubles(self, first: int, count: int) -> np.ndarray:
        return np.array(
            [float(self.robot.inputs.get(f"input_double_register_{first + k + self.offset}", 0.0)) for k in range(count)]
        )

    def _out_int(self, k: int, value: int) -> None:
        self.robot.outputs[f"output_int_register_{k + self.offset}"] = int(value)

    def _out_doubles(self, values: Sequence[float]) -> None:
        for k, value in enumerate(values):
            self.robot.outputs[f"output_double_register_{k + self.offset}"] = float(value)

    def progress(self, value: int) -> None:
        """``write_async_progress_register``: bits 24-30 operation id (counted up when ``value``
        is 0, a new operation), 16-23 write count, bit 15 running (``value`` >= 0), bits 0-14
        ``value``; a negative value is a finished operation."""
        self._writes = (self._writes + 1) % 128
        if value == 0:
            self._operation = (self._operation + 1) % 128
        register = self._writes * 65536 + self._operation * 16777216
        if value >= 0:
            register += min(value, 32767) + 32768
        self._out_int(2, register)

    # -- main loop -------------------------------------------------------------------------
    def _loop(self) -> None:
        robot = self.robot
        if self.stopped.wait(robot.script_start_s):
            return
        with robot.lock:
            if self.stopped.is_set():
                return
            robot.program_started()
            self.progress(-1)
            self._out_int(0, READY)
        executing = False
        while not self.stopped.wait(0.002):
            with robot.lock:
                if not robot.program_playing:
                    continue  # paused by a protective stop: the loop waits
                command = self._in_int(0)
                if command == 0:
                    executing = False
                    self._out_int(0, READY)
                    continue
                if executing:
                    continue
                executing = True
            if not self._execute(command):
                return

    def _execute(self, command: int) -> bool:
        """Carry out one command; False when the program ends."""
        robot = self.robot
        motion = None
        with robot.lock:
            if command == CMD_STOP_SCRIPT:
                robot.stop_program()
                return False
            if command in (CMD_MOVE_PATH, CMD_MOVEL):
                if command == CMD_MOVEL:
                    values = self._in_doubles(0, 8)  # pose, speed, acceleration
                    path = [(values[:6], values[6])]
                else:
                    path = self.path
                motion = robot.move(path, self.progress)
                if self._in_int(1) == 1:  # asynchronous: done at once
                    motion = None
            elif command in (CMD_STOPL, CMD_STOPJ):
                robot.halt()
            elif not self._query(command):
                robot.refused_scripts.append(f"command {command} is not emulated")
                robot.stop_program()
                return False
        if motion is not None:
            while not motion.wait(0.005):
                if self.stopped.is_set():
                    return False
        with robot.lock:
            if self.stopped.is_set():
                return False
            robot.commands_done.append(command)
            self._out_int(0, DONE)
        return True

    def _query(self, command: int) -> bool:
        """Commands answered from the registers at once; False for one the emulator lacks."""
        robot = self.robot
        if command == CMD_PROTECTIVE_STOP:
            robot.protective_stop()
            return True
        if command in (CMD_IK_ARGS, CMD_IK_HAS_SOLUTION_ARGS):
            values = self._in_doubles(0, 14)
            solution = kinematics.inverse(
                values[:6], values[6:12], robot.tcp,
                max_position_error=max(values[12], 1e-9), max_orientation_error=max(values[13], 1e-9),
            )
        elif command in (CMD_IK_DEFAULT, CMD_IK_HAS_SOLUTION_DEFAULT, CMD_POSE_SAFE):
            solution = kinematics.inverse(self._in_doubles(0, 6), robot.q, robot.tcp)
        else:
            return False
        if command in (CMD_IK_ARGS, CMD_IK_DEFAULT):
            if solution is None:  # get_inverse_kin raises a runtime error: the program stops
                robot.stop_program()
            else:
                self._out_doubles(solution)
        elif command == CMD_POSE_SAFE:
            self._out_int(1, int(solution is not None and robot.within_planes(self._in_doubles(0, 6))))
        else:
            self._out_int(1, int(solution is not None))
        return True
