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


def not_connected(device: str) -> DeviceError:
    """The error for a command given to ``device`` (its name, which names its port or host)
    before it was connected."""
    return DeviceError(device, "not connected: call connect() first")


class DeviceVanished(DeviceError):
    """The connection to the device is gone: an unplugged or failed USB-serial adapter, a dropped
    network link. Fatal for the run; ``connection`` is the port or host it was on, so the next
    session can be pointed at the device again (it may come back under another name)."""

    def __init__(self, device: str, message: str, connection: str) -> None:
        super().__init__(device, message)
        self.connection = connection


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
