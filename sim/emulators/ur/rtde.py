"""The RTDE protocol (version 2) of the controller emulator, port 30004.

From Universal Robots' "Real-Time Data Exchange (RTDE) Guide": every package is a header
``uint16 size`` (header included), ``uint8 type`` and a payload, big-endian. Types:
``V`` request protocol version (uint16 → uint8 accepted), ``v`` get URControl version
(→ 4 × uint32), ``O`` setup outputs (v2: double frequency + comma-separated names →
uint8 recipe id + comma-separated types, ``NOT_FOUND`` for an unknown name), ``I`` setup
inputs (names → recipe id + types, ``IN_USE`` for a field another client writes, recipe
id 0 if any field failed), ``S`` start and ``P`` pause (→ uint8 accepted), ``U`` data
package (uint8 recipe id + the recipe's values), ``M`` text message (v2: uint8 length,
message, uint8 length, source, uint8 warning level).
"""

from __future__ import annotations

import socket
import struct
import threading
import time
from collections.abc import Callable

import numpy as np

from sim.emulators.ur.controller import URController

REQUEST_PROTOCOL_VERSION, GET_URCONTROL_VERSION, TEXT_MESSAGE = ord("V"), ord("v"), ord("M")
DATA_PACKAGE, SETUP_OUTPUTS, SETUP_INPUTS, START, PAUSE = ord("U"), ord("O"), ord("I"), ord("S"), ord("P")

FORMATS = {
    "BOOL": "?", "UINT8": "B", "UINT32": "I", "UINT64": "Q", "INT32": "i", "DOUBLE": "d",
    "VECTOR3D": "3d", "VECTOR6D": "6d", "VECTOR6INT32": "6i", "VECTOR6UINT32": "6I",
}
"""Struct codes of the RTDE guide's data types."""

MAX_FREQUENCY_HZ = 500.0
"""e-Series output frequency limit (RTDE guide)."""

ZERO6 = (0.0,) * 6
Getter = Callable[[URController], object]

OUTPUTS: dict[str, tuple[str, Getter]] = {
    "timestamp": ("DOUBLE", lambda r: time.monotonic() - r.started),
    "target_q": ("VECTOR6D", lambda r: r.q),
    "target_qd": ("VECTOR6D", lambda r: r.qd),
    "target_qdd": ("VECTOR6D", lambda r: ZERO6),
    "target_current": ("VECTOR6D", lambda r: ZERO6),
    "target_moment": ("VECTOR6D", lambda r: ZERO6),
    "actual_q": ("VECTOR6D", lambda r: r.q),
    "actual_qd": ("VECTOR6D", lambda r: r.qd),
    "actual_current": ("VECTOR6D", lambda r: ZERO6),
    "joint_control_output": ("VECTOR6D", lambda r: ZERO6),
    "actual_TCP_pose": ("VECTOR6D", lambda r: r.pose),
    "actual_TCP_speed": ("VECTOR6D", lambda r: r.tcp_speed),
    "actual_TCP_force": ("VECTOR6D", lambda r: ZERO6),
    "target_TCP_pose": ("VECTOR6D", lambda r: r.pose),
    "target_TCP_speed": ("VECTOR6D", lambda r: r.tcp_speed),
    "actual_digital_input_bits": ("UINT64", lambda r: 0),
    "joint_temperatures": ("VECTOR6D", lambda r: (30.0,) * 6),
    "actual_execution_time": ("DOUBLE", lambda r: 0.1),
    "robot_mode": ("INT32", lambda r: r.robot_mode),
    "joint_mode": ("VECTOR6INT32", lambda r: (255 if r.robot_mode == 7 else 253,) * 6),
    "safety_mode": ("INT32", lambda r: r.safety_mode),
    "safety_status": ("INT32", lambda r: r.safety_mode),
    "actual_tool_accelerometer": ("VECTOR3D", lambda r: (0.0, 0.0, 9.81)),
    "speed_scaling": ("DOUBLE", lambda r: 1.0),
    "target_speed_fraction": ("DOUBLE", lambda r: 1.0),
    "actual_momentum": ("DOUBLE", lambda r: 0.0),
    "actual_main_voltage": ("DOUBLE", lambda r: 48.0),
    "actual_robot_voltage": ("DOUBLE", lambda r: 48.0 if r.robot_status_bits() & 1 else 0.0),
    "actual_robot_current": ("DOUBLE", lambda r: 0.0),
    "actual_joint_voltage": ("VECTOR6D", lambda r: ZERO6),
    "actual_digital_output_bits": ("UINT64", lambda r: 0),
    "runtime_state": ("UINT32", lambda r: r.runtime_state),
    "standard_analog_input0": ("DOUBLE", lambda r: 0.0),
    "standard_analog_input1": ("DOUBLE", lambda r: 0.0),
    "standard_analog_output0": ("DOUBLE", lambda r: 0.0),
    "standard_analog_output1": ("DOUBLE", lambda r: 0.0),
    "robot_status_bits": ("UINT32", lambda r: r.robot_status_bits()),
    "safety_status_bits": ("UINT32", lambda r: r.safety_status_bits()),
    "ft_raw_wrench": ("VECTOR6D", lambda r: ZERO6),
    "payload": ("DOUBLE", lambda r: 0.0),
    "payload_cog": ("VECTOR3D", lambda r: (0.0, 0.0, 0.0)),
    "payload_inertia": ("VECTOR6D", lambda r: ZERO6),
    "output_bit_registers0_to_31": ("UINT32", lambda r: 0),
    "output_bit_registers32_to_63": ("UINT32", lambda r: 0),
}
for _k in range(48):
    OUTPUTS[f"output_int_register_{_k}"] = ("INT32", lambda r, name=f"output_int_register_{_k}": r.outputs.get(name, 0))
    OUTPUTS[f"output_double_register_{_k}"] = (
        "DOUBLE", lambda r, name=f"output_double_register_{_k}": r.outputs.get(name, 0.0)
    )

INPUTS: dict[str, str] = {
    "speed_slider_mask": "UINT32", "speed_slider_fraction": "DOUBLE",
    "standard_digital_output_mask": "UINT8", "standard_digital_output": "UINT8",
    "configurable_digital_output_mask": "UINT8", "configurable_digital_output": "UINT8",
    "tool_digital_output_mask": "UINT8", "tool_digital_output": "UINT8",
    "standard_analog_output_mask": "UINT8", "standard_analog_output_type": "UINT8",
    "standard_analog_output_0": "DOUBLE", "standard_analog_output_1": "DOUBLE",
    "input_bit_registers0_to_31": "UINT32", "input_bit_registers32_to_63": "UINT32",
    "external_force_torque": "VECTOR6D",
    **{f"input_int_register_{k}": "INT32" for k in range(48)},
    **{f"input_double_register_{k}": "DOUBLE" for k in range(48)},
}


def package(kind: int, payload: bytes = b"") -> bytes:
    """One RTDE package: header (uint16 size, uint8 type) and payload."""
    return struct.pack(">HB", len(payload) + 3, kind) + payload


def text_message(message: str, source: str = "RTDE", level: int = 0) -> bytes:
    """An ``M`` package (protocol version 2); level 0 exception, 1 error, 2 warning, 3 info."""
    text, origin = message.encode()[:255], source.encode()[:255]
    return package(TEXT_MESSAGE, bytes([len(text)]) + text + bytes([len(origin)]) + origin + bytes([level]))


def _flatten(value: object) -> list:
    return list(np.ravel(value)) if isinstance(value, (list, tuple, np.ndarray)) else [value]


class InputClaims:
    """Which connection writes which input field: a field has one writer at a time."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.owner: dict[str, int] = {}

    def claim(self, names: list[str], who: int) -> list[bool]:
        with self.lock:
            free = [self.owner.get(name, who) == who for name in names]
            if all(free):
                self.owner.update({name: who for name in names})
            return free

    def release(self, who: int) -> None:
        with self.lock:
            self.owner = {name: owner for name, owner in self.owner.items() if owner != who}


class RTDESession:
    """One client connection of the RTDE server."""

    def __init__(self, sock: socket.socket, robot: URController, claims: InputClaims, max_rate_hz: float) -> None:
        self.sock = sock
        self.robot = robot
        self.claims = claims
        self.max_rate_hz = max_rate_hz
        self.send_lock = threading.Lock()
        self.outputs: list[str] = []
        self.output_format = ""
        self.frequency = MAX_FREQUENCY_HZ
        self.inputs: dict[int, tuple[list[str], str]] = {}
        self.streaming = threading.Event()
        self.closed = threading.Event()

    def send(self, data: bytes) -> None:
        with self.send_lock:
            self.sock.sendall(data)

    def serve(self) -> None:
        streamer = threading.Thread(target=self._stream, name="rtde-stream", daemon=True)
        streamer.start()
        try:
            while True:
                header = self._read(3)
                if header is None:
                    return
                size, kind = struct.unpack(">HB", header)
                payload = self._read(size - 3) if size > 3 else b""
                if payload is None:
                    return
                self._handle(kind, payload)
        except OSError:
            return
        finally:
            self.closed.set()
            self.streaming.clear()
            self.claims.release(id(self))
            streamer.join(timeout=1.0)

    def _read(self, size: int) -> bytes | None:
        data = b""
        while len(data) < size:
            chunk = self.sock.recv(size - len(data))
            if not chunk:
                return None
            data += chunk
        return data

    def _handle(self, kind: int, payload: bytes) -> None:
        if kind == REQUEST_PROTOCOL_VERSION:
            (version,) = struct.unpack(">H", payload[:2])
            self.send(package(kind, bytes([version in (1, 2)])))
        elif kind == GET_URCONTROL_VERSION:
            self.send(package(kind, struct.pack(">IIII", *self.robot.version)))
        elif kind == SETUP_OUTPUTS:
            self._setup_outputs(payload)
        elif kind == SETUP_INPUTS:
            self._setup_inputs(payload)
        elif kind == START:
            self.streaming.set()
            self.send(package(kind, b"\x01"))
        elif kind == PAUSE:
            self.streaming.clear()
            self.send(package(kind, b"\x01"))
        elif kind == DATA_PACKAGE:
            self._receive_inputs(payload)
        else:
            self.send(text_message(f"unknown package type {kind}", level=1))

    def _setup_outputs(self, payload: bytes) -> None:
        (frequency,) = struct.unpack(">d", payload[:8])
        names = [name for name in payload[8:].decode("ascii", "replace").split(",") if name]
        types = [OUTPUTS[name][0] if name in OUTPUTS else "NOT_FOUND" for name in names]
        ok = "NOT_FOUND" not in types and names and 0.0 < frequency <= MAX_FREQUENCY_HZ
        if ok and not self.streaming.is_set():
            self.outputs = names
            self.output_format = ">B" + "".join(FORMATS[t] for t in types)
            self.frequency = frequency
        self.send(package(SETUP_OUTPUTS, bytes([1 if ok else 0]) + ",".join(types).encode()))

    def _setup_inputs(self, payload: bytes) -> None:
        names = [name for name in payload.decode("ascii", "replace").split(",") if name]
        known = [name in INPUTS for name in names]
        free = self.claims.claim(names, id(self)) if all(known) else [True] * len(names)
        types = [INPUTS[n] if k and f else ("NOT_FOUND" if not k else "IN_USE") for n, k, f in zip(names, known, free)]
        recipe = 0
        if names and all(known) and all(free):
            recipe = len(self.inputs) + 1
            self.inputs[recipe] = (names, ">" + "".join(FORMATS[t] for t in types))
        self.send(package(SETUP_INPUTS, bytes([recipe]) + ",".join(types).encode()))

    def _receive_inputs(self, payload: bytes) -> None:
        recipe = self.inputs.get(payload[0]) if payload else None
        if recipe is None:
            self.send(text_message(f"data package for unknown input recipe {payload[:1].hex()}", level=1))
            return
        names, fmt = recipe
        values = struct.unpack(fmt, payload[1 : 1 + struct.calcsize(fmt)])
        with self.robot.lock:
            position = 0
            for name in names:
                width = 6 if name == "external_force_torque" else 1
                self.robot.inputs[name] = values[position] if width == 1 else values[position : position + width]
                position += width

    def _stream(self) -> None:
        next_at = time.monotonic()
        while not self.closed.is_set():
            if not self.streaming.wait(0.05):
                continue
            with self.robot.lock:
                values: list = []
                for name in self.outputs:
                    values += _flatten(OUTPUTS[name][1](self.robot))
            try:
                self.send(package(DATA_PACKAGE, struct.pack(self.output_format, 1, *values)))
            except OSError:
                return
            next_at = max(next_at + 1.0 / min(self.frequency, self.max_rate_hz), time.monotonic() - 0.1)
            time.sleep(max(0.0, next_at - time.monotonic()))
