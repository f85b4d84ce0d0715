"""Exceptions raised by device adapters (real and simulated).

The runner distinguishes three kinds of failure:

* :class:`TransientDeviceError` — worth retrying with a bounded backoff
  (a serial timeout, a garbled reply, a dropped frame, a camera that
  disconnected and can be reopened);
* :class:`OperatorActionRequired` — the device stopped itself for safety
  (a robot protective stop); it may only continue after an operator has
  confirmed that the cell is safe;
* every other :class:`DeviceError` — fatal for the run: devices go to their
  safe state and the run is marked ``aborted``.
"""

from __future__ import annotations


class DeviceError(RuntimeError):
    """A device failed in a way that the run cannot recover from by itself."""

    def __init__(self, device: str, message: str) -> None:
        super().__init__(f"{device}: {message}")
        self.device = device
        self.message = message


class MissingSDKError(DeviceError):
    """The vendor SDK or GenTL producer a backend needs is not installed."""


class TransientDeviceError(DeviceError):
    """A fault that a retry may cure."""

    kind = "transient"


class SerialTimeout(TransientDeviceError):
    """No (complete) reply within the serial timeout."""

    kind = "serial_timeout"


class SerialGarbage(TransientDeviceError):
    """A reply that does not parse as the documented protocol."""

    kind = "serial_garbage"


class DroppedFrame(TransientDeviceError):
    """The camera delivered no frame (or an incomplete one) for a trigger."""

    kind = "dropped_frame"


class CameraDisconnected(TransientDeviceError):
    """The camera vanished; it has to be closed and connected again."""

    kind = "camera_disconnect"


class OperatorActionRequired(DeviceError):
    """The device stopped for safety; continue only after operator confirmation."""

    kind = "operator_action"


class ProtectiveStop(OperatorActionRequired):
    """The robot controller entered a protective stop."""

    kind = "robot_protective_stop"


class LimitViolation(DeviceError):
    """A commanded position lies outside the configured limits; nothing moved."""
