"""Building the set of devices a campaign needs: simulated fakes or real adapters."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from drivers.protocols import Clock, DepthCamera, LinearStage, RangeMeter, RealClock, Robot
from labctl.run.config import Campaign
from procedures.steps import Step
from sim.devices import SimCamera, SimLaser, SimRobot, SimStage
from sim.faults import FaultInjector
from sim.model import SimModel, default_model_text, parse_model
from sim.world import SimWorld


@dataclass
class Lab:
    """The devices of one run and the clock they share."""

    camera: DepthCamera
    stage: LinearStage | None = None
    laser: RangeMeter | None = None
    robot: Robot | None = None
    clock: Clock = field(default_factory=RealClock)
    simulated: bool = False
    step_hook: Callable[[Step, float], None] | None = None
    sim_record: tuple[str, int] | None = None
    """A simulated lab's model text and seed, recorded in the run file's /sim group (what resume rebuilds it from)."""

    def devices(self) -> dict[str, Any]:
        """Present devices by role, in the order they are connected."""
        roles = {"stage": self.stage, "laser": self.laser, "robot": self.robot, "camera": self.camera}
        return {role: dev for role, dev in roles.items() if dev is not None}

    def begin_step(self, step: Step, planned_start_s: float) -> None:
        """Tell a simulated world which step starts (a no-op for real hardware)."""
        if self.step_hook is not None:
            self.step_hook(step, planned_start_s)


def build_sim_lab(campaign: Campaign, model: SimModel, seed: int) -> Lab:
    """Every device of the campaign replaced by its simulated fake, sharing one virtual clock."""
    from sim.clock import VirtualClock

    clock = VirtualClock()
    devices = campaign.devices
    world = SimWorld(
        profile=model.profile(),
        effects=model.effect_params(),
        lab=model.lab,
        seed=seed,
        faults=FaultInjector(campaign.sim.faults.model_dump(), seed),
        clock=clock,
        stage_config=devices.stage,
    )
    return Lab(
        camera=SimCamera(world),
        stage=SimStage(world, devices.stage) if devices.stage else None,
        laser=SimLaser(world) if devices.laser else None,
        robot=SimRobot(world, devices.robot) if devices.robot else None,
        clock=clock,
        simulated=True,
        step_hook=world.begin_step,
    )


def simulated_lab(campaign: Campaign, model_text: str | None = None, *, seed: int | None = None,
                  source: str = "model") -> Lab:
    """The campaign on simulated devices, from a model's TOML text (default: the built-in model of the campaign's
    camera) and ``seed`` (default: the campaign's ``[sim] seed``); both are kept for the run file (``sim_record``).
    ``source`` names the text in a ModelError."""
    if model_text is None:
        model_text, source = default_model_text(campaign.devices.camera.sim_profile), "built-in profile"
    seed = campaign.sim.seed if seed is None else seed
    lab = build_sim_lab(campaign, parse_model(model_text, source), seed)
    lab.sim_record = (model_text, seed)
    return lab


def build_real_lab(campaign: Campaign) -> Lab:
    """Real adapters for every device of the campaign (:func:`labctl.run.hardware.real_devices`)."""
    from labctl.run.hardware import real_devices  # the real drivers load only for real runs

    return Lab(**real_devices(campaign.devices))
