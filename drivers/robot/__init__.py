"""Robots that carry the camera on the measurement circle (:class:`~drivers.protocols.Robot`)."""

from drivers.robot.circle import CirclePosition, MeasurementCircle
from drivers.robot.ur5e import UR5eRobot, probe_controller

__all__ = ["CirclePosition", "MeasurementCircle", "UR5eRobot", "probe_controller"]
