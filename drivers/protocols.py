"""Device protocols: what the runner needs from every stage, meter, robot and camera.

Real adapters (``drivers/<kind>/...``) and simulated fakes (``sim/devices.py``)
implement the same protocols, so procedures and the runner never know which
one they drive; both derive from the base classes in ``drivers/device.py``.
Units: millimetres, degrees, seconds, microseconds for exposure.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass, field
from typing import Any, Protocol, runtime_checkable

import numpy as np


@dataclass(frozen=True)
class DeviceIdentity:
    """What the run file records under ``/devices/<role>``."""

    backend: str
    model: str
    serial: str
    firmware: str


@dataclass(frozen=True)
class CameraInfo:
    """Static camera description recorded under ``/camera`` of the run file."""

    width: int
    height: int
    fov_deg: tuple[float, float]
    pixel_pitch_um: float
    frame_rate_hz: float
    wavelength_nm: float
    confidence_dtype: str = "float32"


@dataclass(frozen=True)
class RobotPose:
    """Where the robot holds the camera, as read back from it: the angle and radius on the measurement
    circle and, where the robot reports it, the tool centre point's position in its base frame (mm)."""

    angle_deg: float
    radius_mm: float
    tcp_mm: tuple[float, float, float] | None = None


@dataclass
class Frame:
    """One depth frame: organized point cloud plus intensity and confidence.

    ``x``, ``y``, ``z`` are (H, W) float32 in millimetres in the camera frame
    (z along the optical axis), NaN where the camera reports no valid point.
    """

    x: np.ndarray
    y: np.ndarray
    z: np.ndarray
    intensity: np.ndarray
    confidence: np.ndarray
    timestamp: float
    meta: dict[str, Any] = field(default_factory=dict)


@runtime_checkable
class Clock(Protocol):
    """Time source of a lab: real for hardware, virtual for a simulated dry run."""

    def now(self) -> float: ...

    def sleep(self, seconds: float) -> None: ...


class RealClock:
    """Monotonic wall-clock time."""

    def now(self) -> float:
        return time.monotonic()

    def sleep(self, seconds: float) -> None:
        if seconds > 0:
            time.sleep(seconds)


@runtime_checkable
class Device(Protocol):
    """Common part of every device."""

    def connect(self) -> None: ...

    def close(self) -> None: ...

    def safe_state(self) -> None:
        """Stop motion / emission; must be callable at any time, even half-connected."""

    def identity(self) -> DeviceIdentity: ...

    def settings(self) -> Mapping[str, Any]:
        """Current settings, recorded as ``settings_json`` in the run file."""


@runtime_checkable
class LinearStage(Device, Protocol):
    """A single-axis translation stage carrying the camera towards the wall."""

    def home(self) -> None: ...

    def move_to(self, position_mm: float) -> None:
        """Absolute move; returns when the stage is idle at the target."""

    def position_mm(self) -> float: ...

    def stop(self) -> None: ...


@runtime_checkable
class RangeMeter(Device, Protocol):
    """A laser distance meter giving the reference distance."""

    def measure_mm(self) -> float: ...


@runtime_checkable
class Robot(Device, Protocol):
    """A robot that carries the camera on a circle around a target."""

    def move_on_circle(
        self, angle_deg: float, radius_mm: float, watch: Callable[[RobotPose], None] | None = None
    ) -> None:
        """Move to ``angle_deg`` on the measurement circle; returns when settled. ``watch``, if given, is
        called with the pose read back while the robot moves (and once it has arrived); it must return at once."""

    def angle_deg(self) -> float: ...

    def pose(self) -> RobotPose:
        """The pose read back from the robot now."""

    def recover(self) -> None:
        """Clear a protective stop (only after an operator confirmed the cell is safe)."""


@runtime_checkable
class DepthCamera(Device, Protocol):
    """A 3D camera delivering stacks of organized point clouds."""

    def info(self) -> CameraInfo: ...

    def configure(self, exposure_us: float | None, settings: Mapping[str, Any]) -> None:
        """Apply exposure (None = camera default) and backend settings."""

    def capture(self, count: int, first_index: int = 0) -> Iterator[Frame]:
        """Yield ``count`` frames, numbered from ``first_index`` within the stack.

        A transient failure raises after the frames already yielded, so the
        caller can continue with ``first_index`` = frames received so far.
        """

    def temperatures_c(self) -> dict[str, float]:
        """The camera's temperature sensors as it reports them now (sensor name -> degrees Celsius); empty
        when it reports none."""
