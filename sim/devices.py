"""Simulated stage, laser, robot and camera behind the real device protocols.

They run on the world's virtual clock and spend exactly the lab time that
the campaign planner plans for (motion at the configured speeds; measurement and
set-up from ``drivers.timing``; all without sleeping), draw their noise from per-step random streams and
raise the same exceptions as real adapters when the fault injector says so.
They derive from the adapters' base classes (``drivers/device.py``), so they offer
the same interface.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator, Mapping
from typing import Any

from drivers.device import BaseDevice, CameraDevice
from drivers.errors import (
    CameraDisconnected,
    DroppedFrame,
    LimitViolation,
    ProtectiveStop,
    SerialGarbage,
    SerialTimeout,
)
from drivers.protocols import CameraInfo, DeviceIdentity, Frame, RobotPose
from drivers.timing import CAPTURE_SETUP_S, LASER_READING_S, ROBOT_SETTLE_S
from sim import shared_renders
from sim.effects import warm_up_s
from sim.seeding import stream
from sim.stereo import StereoSensor
from sim.tof import ToFSensor
from sim.world import RobotSettings, SimWorld, StageSettings

SERIAL_TIMEOUT_S = 1.0
ROOM_C = 23.0  # assumption: the lab's air temperature
WARM_UP_K = 20.0  # assumption: a camera's sensor settles this far above the room once warm
WARM_UP_TAU_S = 600.0  # assumption: the sensor's warm-up time constant where no effect states one


def _serial_exchange(world: SimWorld, device: str) -> None:
    """One serial request/reply: may time out or return garbage per the fault schedule."""
    if world.faults.strike("serial_timeout"):
        world.clock.sleep(SERIAL_TIMEOUT_S)
        raise SerialTimeout(device, f"no reply within {SERIAL_TIMEOUT_S:g} s")
    if world.faults.strike("serial_garbage"):
        raise SerialGarbage(device, "reply does not parse: b'\\x8fg1g+00\\x03'")


class SimDevice(BaseDevice):
    """A simulated device in ``world``: nothing to open, close or stop, its identity known from the start."""

    def __init__(self, world: SimWorld, name: str, identity: DeviceIdentity) -> None:
        super().__init__(name)
        self.world = world
        self._identity = identity

    def connect(self) -> None:
        """Nothing to open."""

    def close(self) -> None:
        """Nothing to release."""

    def safe_state(self) -> None:
        """Nothing moves or emits between commands."""


class SimStage(SimDevice):
    """Linear stage with travel limits and a constant speed."""

    def __init__(self, world: SimWorld, config: StageSettings) -> None:
        identity = DeviceIdentity("sim", f"simulated {config.protocol} stage", "SIM-STAGE", "sim")
        super().__init__(world, f"stage (simulated {config.protocol})", identity)
        self.config = config

    def connect(self) -> None:
        """The stage starts at the low end of its travel."""
        self.world.stage_position_mm = self.config.travel_mm[0]

    def settings(self) -> Mapping[str, Any]:
        return {"speed_mm_s": self.config.speed_mm_s, "travel_mm": list(self.config.travel_mm)}

    def home(self) -> None:
        self.move_to(self.config.travel_mm[0])

    def move_to(self, position_mm: float) -> None:
        lo, hi = self.config.travel_mm
        if not lo <= position_mm <= hi:
            raise LimitViolation(self.name, f"position {position_mm:g} mm outside travel [{lo:g}, {hi:g}] mm")
        _serial_exchange(self.world, self.name)
        distance = abs(position_mm - self.world.stage_position_mm)
        self.world.clock.sleep(distance / self.config.speed_mm_s + self.config.settle_s)
        self.world.stage_position_mm = float(position_mm)

    def position_mm(self) -> float:
        _serial_exchange(self.world, self.name)
        return self.world.stage_position_mm

    def stop(self) -> None:
        """A simulated move has ended when :meth:`move_to` returns: nothing to stop."""


class SimLaser(SimDevice):
    """Laser distance meter: true distance + constant bias + Gaussian repeatability, 0.1 mm steps."""

    def __init__(self, world: SimWorld) -> None:
        identity = DeviceIdentity("sim", "simulated DAN-10-150", "SIM-LASER", "sim")
        super().__init__(world, "laser (simulated Dimetix)", identity)
        self._readings = 0
        self._step = -1

    def settings(self) -> Mapping[str, Any]:
        return {"resolution_mm": self.world.lab.laser_resolution_mm}

    def measure_mm(self) -> float:
        _serial_exchange(self.world, self.name)
        if self._step != self.world.step_index:
            self._step, self._readings = self.world.step_index, 0
        rng = stream(self.world.seed, self._step, "laser", self._readings)
        self._readings += 1
        self.world.clock.sleep(LASER_READING_S)
        lab = self.world.lab
        value = self.world.laser_true_mm() + lab.laser_bias_mm + lab.laser_noise_mm * rng.standard_normal()
        return round(value / lab.laser_resolution_mm) * lab.laser_resolution_mm


class SimRobot(SimDevice):
    """Robot carrying the camera on a circle; may enter a protective stop."""

    def __init__(self, world: SimWorld, config: RobotSettings) -> None:
        super().__init__(world, "robot (simulated UR5e)", DeviceIdentity("sim", "simulated UR5e", "SIM-ROBOT", "sim"))
        self.config = config
        self.stopped = False

    def settings(self) -> Mapping[str, Any]:
        return {"speed_deg_s": self.config.speed_deg_s}

    def move_on_circle(
        self, angle_deg: float, radius_mm: float, watch: Callable[[RobotPose], None] | None = None
    ) -> None:
        lo, hi = self.config.angle_limits_deg
        if not lo <= angle_deg <= hi or not 0 < radius_mm <= self.config.radius_max_mm:
            raise LimitViolation(self.name, f"angle {angle_deg:g} deg / radius {radius_mm:g} mm outside limits")
        if self.stopped:
            raise ProtectiveStop(self.name, "protective stop active")
        if self.world.faults.strike("robot_protective_stop"):
            self.stopped = True
            raise ProtectiveStop(self.name, "protective stop during motion")
        self.world.clock.sleep(abs(angle_deg - self.world.robot_angle_deg) / self.config.speed_deg_s + ROBOT_SETTLE_S)
        self.world.robot_angle_deg, self.world.robot_radius_mm = float(angle_deg), float(radius_mm)
        if watch is not None:  # the simulated move is one sleep of the clock: only its end is seen
            watch(self.pose())

    def angle_deg(self) -> float:
        return self.world.robot_angle_deg

    def pose(self) -> RobotPose:
        """The circle position; the simulated lab has no robot base frame, so no TCP position."""
        return RobotPose(self.world.robot_angle_deg, self.world.robot_radius_mm)

    def recover(self) -> None:
        self.stopped = False


class SimCamera(SimDevice, CameraDevice):
    """Physical camera model: the world's scene seen through ToF or stereo sensor physics."""

    def __init__(self, world: SimWorld) -> None:
        profile = world.profile
        identity = DeviceIdentity("sim", f"{profile.vendor} {profile.model} (simulated)", "SIM-CAMERA", "sim")
        super().__init__(world, f"camera (simulated {profile.model})", identity)
        self.profile = profile
        if profile.technology == "tof":
            self.sensor: ToFSensor | StereoSensor = ToFSensor(profile, world.effects)
        else:
            self.sensor = StereoSensor(profile, world.effects)
        self.connected = False
        self.exposure_us = profile.exposure_us
        self._settings: dict[str, Any] = {}
        self._cache_key: tuple[Any, ...] | None = None
        self._prepared: Any = None
        #: what a step's noise-free maps depend on besides the step (sim/shared_renders.py)
        self._model_key = repr((profile, sorted(world.effects.items()), world.lab))

    def connect(self) -> None:
        """Capture works until :meth:`close` or a simulated disconnect."""
        self.connected = True

    def close(self) -> None:
        """Capture fails until the next :meth:`connect`."""
        self.connected = False

    def settings(self) -> Mapping[str, Any]:
        return {"exposure_us": self.exposure_us, **self._settings}

    def info(self) -> CameraInfo:
        p = self.profile
        return CameraInfo(
            width=p.width, height=p.height, fov_deg=(p.fov_h_deg, p.fov_v_deg),
            pixel_pitch_um=p.pixel_pitch_um, frame_rate_hz=p.frame_rate_hz,
            wavelength_nm=p.wavelength_nm, confidence_dtype=p.confidence_dtype,
        )

    def configure(self, exposure_us: float | None, settings: Mapping[str, Any]) -> None:
        self.exposure_us = self.profile.exposure_us if exposure_us is None else float(exposure_us)
        self._settings = dict(settings)
        self.world.clock.sleep(CAPTURE_SETUP_S)

    def temperatures_c(self) -> dict[str, float]:
        """The simulated sensor's temperature, a first-order warm-up from the room since the camera started,
        ROOM_C + WARM_UP_K (1 - exp(-t / tau)), tau the warm-up time constant the model's effects state (the
        same lumped thermal node that moves the range in a drift; ``sim.effects.warm_up_s``) or
        ``WARM_UP_TAU_S``."""
        tau = warm_up_s(self.world.effects) or WARM_UP_TAU_S
        t = max(self.world.clock.now(), 0.0)
        return {"sensor": round(ROOM_C + WARM_UP_K * (1.0 - math.exp(-t / tau)), 2)}

    @property
    def projector(self) -> bool:
        """Stereo dot projector (``projector`` or ``emitter`` setting, default on)."""
        return bool(self._settings.get("projector", self._settings.get("emitter", True)))

    def _prepare(self) -> Any:
        world = self.world
        scene, pose = world.scene_and_pose()
        key = (world.step_index, world.target, repr(sorted(world.target_params.items())), pose.key(),
               world.camera_distance_mm(), self.exposure_us, self.projector)
        if key != self._cache_key:
            shared = (self._model_key, *key) if shared_renders.active() else None
            prepared = shared_renders.take(shared, world.seed) if shared is not None else None
            if prepared is None:
                args = (scene, pose, self.exposure_us, world.seed, world.step_index)
                if isinstance(self.sensor, StereoSensor):
                    prepared = self.sensor.prepare(*args, projector=self.projector)
                else:
                    prepared = self.sensor.prepare(*args)
                if shared is not None:
                    shared_renders.keep(shared, prepared)
            self._prepared = prepared
            self._cache_key = key
        return self._prepared

    def capture(self, count: int, first_index: int = 0) -> Iterator[Frame]:
        if not self.connected:
            raise CameraDisconnected(self.name, "camera is not connected")
        prepared = self._prepare()
        period = 1.0 / self.profile.frame_rate_hz
        world = self.world
        for k in range(first_index, first_index + count):
            if world.faults.strike("camera_disconnect"):
                self.connected = False
                raise CameraDisconnected(self.name, f"device lost during frame {k}")
            if world.faults.strike("dropped_frame"):
                world.clock.sleep(period)
                raise DroppedFrame(self.name, f"frame {k} incomplete")
            timestamp = world.step_start_s + k * period
            x, y, z, intensity, confidence = self.sensor.frame(prepared, k, timestamp)
            world.clock.sleep(period)
            yield Frame(x, y, z, intensity, confidence, timestamp=timestamp)
