"""The simulated lab's state shared by the simulated devices.

The stage and robot move the camera in this world, the laser measures it, the
camera renders it. The runner tells the world which step starts (so every
random stream is keyed by the step, and the operator's target swaps happen).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Protocol

from drivers.protocols import Clock
from procedures.steps import Step
from sim.effects import EffectParams, plate_placement_mm
from sim.faults import FaultInjector
from sim.geometry import Pose
from sim.lab import LabGeometry
from sim.profiles import CameraProfile
from sim.scenes.base import Scene
from sim.scenes.targets import PLATE_MATERIALS, build_scene, plate_scene


class StageSettings(Protocol):
    """What the simulated stage and the world read of a campaign's stage table."""

    protocol: str
    travel_mm: tuple[float, float]
    speed_mm_s: float
    settle_s: float
    distance_at_zero_mm: float
    axis_direction: str


class RobotSettings(Protocol):
    """What the simulated robot reads of a campaign's robot table."""

    radius_max_mm: float
    angle_limits_deg: tuple[float, float]
    speed_deg_s: float


@dataclass
class SimWorld:
    profile: CameraProfile
    effects: dict[str, EffectParams]
    lab: LabGeometry
    seed: int
    faults: FaultInjector
    clock: Clock
    stage_config: StageSettings | None = None
    stage_position_mm: float = 0.0
    robot_angle_deg: float = 0.0
    robot_radius_mm: float = 0.0
    target: str = "wall"
    target_params: dict[str, Any] = field(default_factory=dict)
    step: Step | None = None
    step_start_s: float = 0.0

    def begin_step(self, step: Step, planned_start_s: float) -> None:
        """A step starts: the operator has put ``step.target`` in place."""
        self.step = step
        self.step_start_s = planned_start_s
        self.target = step.target
        self.target_params = dict(step.target_params)
        self.faults.begin_step(step.index, step.frames)

    @property
    def step_index(self) -> int:
        return self.step.index if self.step is not None else -1

    def nominal_distance_mm(self) -> float:
        """Camera-wall distance the stage position stands for (campaign mapping)."""
        cfg = self.stage_config
        if cfg is None:
            return 0.0
        sign = 1.0 if cfg.axis_direction == "away_from_wall" else -1.0
        return cfg.distance_at_zero_mm + sign * self.stage_position_mm

    def camera_distance_mm(self) -> float:
        """True perpendicular distance from the camera's optical centre to the wall."""
        return self.nominal_distance_mm() + self.lab.camera_mount_error_mm

    def laser_true_mm(self) -> float:
        """What a perfect laser would read."""
        return self.camera_distance_mm() + self.lab.laser_offset_mm

    def scene_and_pose(self) -> tuple[Scene, Pose]:
        """What the camera sees now: the target's scene and the camera's pose in it."""
        wavelength = self.profile.wavelength_nm
        if self.target in PLATE_MATERIALS:
            axis_mm, plate_mm = plate_placement_mm(self.effects)
            pose = Pose.on_circle(self.robot_angle_deg, self.robot_radius_mm, axis_mm)
            scene = plate_scene(self.target, wavelength, offset_mm=plate_mm, **self.target_params)
            return scene, pose
        pose = Pose.at_origin(self.lab.tilt_x_deg, self.lab.tilt_y_deg)
        return build_scene(self.target, self.target_params, wavelength, self.camera_distance_mm()), pose
