"""Base classes of the device adapters: the part every stage, meter, robot and camera shares.

:class:`BaseDevice` holds what every device has in common: its ``name`` (which every error
names), :meth:`~BaseDevice.identity` as read at connect (before that the one "not connected"
error, :func:`drivers.errors.not_connected`) and the context manager (connect on entry; safe
state, then close, on exit). Subclasses implement ``connect``, ``close``, ``safe_state`` and
``settings`` and the methods of their kind in :mod:`drivers.protocols`.

* :class:`LinkedDevice`: a device reached over one link, a serial port or a network host
  (``connection``); :class:`SerialDevice` adds the serial line itself (port, baud rate,
  :class:`~drivers.serial_line.SerialLine`, :meth:`~SerialDevice.close`).
* :class:`CameraDevice`: a 3D camera, which must also provide ``info``, ``configure`` and
  ``capture`` (:class:`~drivers.protocols.DepthCamera`).

The simulated devices of ``sim/devices.py`` derive from the same classes.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Iterator, Mapping
from types import TracebackType
from typing import Any, Self

from drivers.errors import not_connected
from drivers.protocols import CameraInfo, DeviceIdentity, Frame
from drivers.serial_line import SerialLine


class BaseDevice(ABC):
    """What every device adapter shares (:class:`~drivers.protocols.Device`).

    ``name`` names the device (and its port or host) in every error. A subclass sets
    ``_identity`` when it connects; until then :meth:`identity` raises
    :func:`~drivers.errors.not_connected`.
    """

    def __init__(self, name: str) -> None:
        self.name = name
        self._identity: DeviceIdentity | None = None

    @abstractmethod
    def connect(self) -> None:
        """Open the device and read its identity (idempotent)."""

    @abstractmethod
    def close(self) -> None:
        """Release the device (idempotent)."""

    @abstractmethod
    def safe_state(self) -> None:
        """Stop motion / emission; must be callable at any time, even half-connected, and never raise."""

    @abstractmethod
    def settings(self) -> Mapping[str, Any]:
        """Current settings, recorded as ``settings_json`` in the run file."""

    def identity(self) -> DeviceIdentity:
        """Backend, model, serial number and firmware as read at :meth:`connect`."""
        if self._identity is None:
            raise not_connected(self.name)
        return self._identity

    def __enter__(self) -> Self:
        """Connect."""
        self.connect()
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        """Put the device in its safe state, then close it, also when the block raised."""
        self.safe_state()
        self.close()


class LinkedDevice(BaseDevice):
    """A device reached over one link: ``connection`` is its serial port or network host,
    the one a :class:`~drivers.errors.DeviceVanished` names when the link is lost."""

    def __init__(self, connection: str, name: str) -> None:
        super().__init__(name)
        self.connection = connection


class SerialDevice(LinkedDevice):
    """A device on a serial port: the :class:`~drivers.serial_line.SerialLine` to it (``_line``,
    lines ending in ``terminator``, replies awaited ``timeout_s``; ``options`` such as ``bytesize``
    go to pyserial) is opened by the subclass's ``connect`` and closed by :meth:`close`."""

    def __init__(
        self, port: str, baud: int, name: str, *, terminator: bytes, timeout_s: float, **options: Any
    ) -> None:
        super().__init__(port, name)
        self.baud = baud
        self._line = SerialLine(name, port, baud, terminator=terminator, timeout_s=timeout_s, **options)

    @property
    def port(self) -> str:
        """The serial port, e.g. ``/dev/ttyUSB0``."""
        return self.connection

    def close(self) -> None:
        """Close the port (idempotent)."""
        self._line.close()


class CameraDevice(BaseDevice):
    """A 3D camera (:class:`~drivers.protocols.DepthCamera`)."""

    @abstractmethod
    def info(self) -> CameraInfo:
        """Static description recorded under ``/camera`` of the run file."""

    @abstractmethod
    def configure(self, exposure_us: float | None, settings: Mapping[str, Any]) -> None:
        """Apply exposure (None = camera default) and backend settings."""

    @abstractmethod
    def capture(self, count: int, first_index: int = 0) -> Iterator[Frame]:
        """Yield ``count`` frames, numbered from ``first_index`` within the stack."""

    def temperatures_c(self) -> dict[str, float]:
        """The camera's temperature sensors (name -> degrees Celsius) as it reports them now; a camera whose
        SDK reports none gives an empty mapping (the default)."""
        return {}
