"""Real device adapters from a campaign's ``[devices]`` (the non-simulated lab).

Each adapter is only constructed here; the runner connects it. Settings a real device
needs but a simulated run does not (ports, the Zaber microstep size, the robot's circle)
are checked here and reported as input errors naming the campaign field.
"""

from __future__ import annotations

from typing import Any

from drivers.camera import open_camera
from drivers.laser import DimetixLaser
from drivers.protocols import DepthCamera, LinearStage
from drivers.robot import UR5eRobot
from drivers.stage import GrblStage, ZaberStage
from labctl.errors import InputError
from labctl.run.config import CameraConfig, DevicesConfig, LaserConfig, RobotConfig, StageConfig


def _required(value: Any, field: str, why: str) -> Any:
    if value is None:
        raise InputError(f"devices.{field} is required for a run on real hardware: {why} (or run with --sim)")
    return value


def stage_from_config(config: StageConfig) -> LinearStage:
    """A :class:`ZaberStage` or :class:`GrblStage` on ``config.port``; Grbl moves at ``speed_mm_s``."""
    port = _required(config.port, "stage.port", "the serial port of the stage controller")
    options: dict[str, Any] = {"travel_mm": config.travel_mm, "home_on_connect": config.home_on_connect}
    if config.baud is not None:
        options["baud"] = config.baud
    if config.protocol == "zaber":
        step = _required(config.mm_per_microstep, "stage.mm_per_microstep", "the Zaber stage's microstep size in mm")
        return ZaberStage(
            port,
            mm_per_microstep=step,
            device=config.device,
            axis=int(config.axis or 1),
            checksums=config.checksums,
            **options,
        )
    return GrblStage(port, axis=str(config.axis or "X"), feed_mm_min=config.speed_mm_s * 60.0, **options)


def laser_from_config(config: LaserConfig) -> DimetixLaser:
    """A :class:`DimetixLaser` on ``config.port``."""
    port = _required(config.port, "laser.port", "the serial port of the Dimetix sensor")
    return DimetixLaser(port, config.baud, device_id=config.device_id)


def robot_from_config(config: RobotConfig) -> UR5eRobot:
    """A :class:`UR5eRobot` at ``config.host`` on the configured measurement circle."""
    _required(config.circle_center_mm, "robot.circle_center_mm", "the circle's centre (target point) in the base frame")
    return UR5eRobot(
        config.host,
        config.circle(),
        angle_limits_deg=config.angle_limits_deg,
        radius_max_mm=config.radius_max_mm,
        speed_deg_s=config.speed_deg_s,
        acceleration_deg_s2=config.acceleration_deg_s2,
        tcp_box_mm=config.tcp_box_mm,
        joint_limits_deg=config.joint_limits_deg,
        settle_s=config.settle_s,
    )


def camera_from_config(config: CameraConfig) -> DepthCamera:
    """The camera backend's adapter, live or playing ``config.playback``."""
    try:
        return open_camera(
            config.driver,
            serial=config.serial,
            playback=config.playback,
            producers=[config.producer] if config.producer else None,
            sdk=config.sdk,
            timeout_s=config.frame_timeout_s,
        )
    except ValueError as exc:
        raise InputError(f"devices.camera: {exc}") from None


def real_devices(devices: DevicesConfig) -> dict[str, Any]:
    """Adapters by role (``camera``, ``stage``, ``laser``, ``robot``) for the devices the campaign names."""
    return {
        "camera": camera_from_config(devices.camera),
        "stage": stage_from_config(devices.stage) if devices.stage else None,
        "laser": laser_from_config(devices.laser) if devices.laser else None,
        "robot": robot_from_config(devices.robot) if devices.robot else None,
    }
