"""Turning a campaign into a timed plan, without touching hardware.

The lab-time model: stage moves take |delta| / speed + settle time, robot
moves |delta angle| / speed + 1 s, each laser reading 0.3 s, a stack
frames / frame rate + 0.5 s set-up, and every operator prompt the campaign's
``runner.operator_time_s``. Simulated devices spend exactly these times on
their virtual clock, so a dry run predicts the lab time of the real one.
The expected run-file size is the frames' raw size over the compression's
planning ratio (labctl.run.compression.ESTIMATED_RATIO).
"""

from __future__ import annotations

from dataclasses import dataclass

from drivers.protocols import CameraInfo
from drivers.timing import CAPTURE_SETUP_S, LASER_READING_S, ROBOT_SETTLE_S
from labctl.run.config import Campaign
from labctl.run.diskspace import expected_file_bytes, frame_bytes
from procedures.steps import Step
from sim.profiles import get_profile


@dataclass(frozen=True)
class PlannedStep:
    """A step with its lab-time slot. Steps whose distance is resolved at run time
    (``step.distance_from``) are timed at an estimate and have no stage position yet."""

    step: Step
    stage_position_mm: float | None
    start_s: float
    duration_s: float


def estimated_distance_mm(campaign: Campaign, step: Step) -> float | None:
    """The step's camera-wall distance, or for ``best_focus`` the profile's hyperfocal distance as an estimate."""
    if step.distance_from is None:
        return step.distance_mm
    return get_profile(campaign.devices.camera.sim_profile).hyperfocal_mm + step.distance_offset_mm


def nominal_frame_rate(campaign: Campaign) -> float:
    """Frame rate used for planning: the camera profile's."""
    return get_profile(campaign.devices.camera.sim_profile).frame_rate_hz


def schedule(campaign: Campaign) -> list[PlannedStep]:
    """Every step with its stage position, planned start and duration (seconds of lab time)."""
    devices = campaign.devices
    fps = nominal_frame_rate(campaign)
    stage_pos = devices.stage.travel_mm[0] if devices.stage else None
    angle = 0.0
    t = 0.0
    planned = []
    for step in campaign.steps():
        duration = 0.0
        if step.prompt:
            duration += campaign.runner.operator_time_s
        position = None
        distance = estimated_distance_mm(campaign, step)
        if distance is not None and devices.stage is not None:
            estimate = devices.stage.position_for_distance(distance)
            duration += abs(estimate - stage_pos) / devices.stage.speed_mm_s + devices.stage.settle_s
            stage_pos = estimate
            position = estimate if step.distance_from is None else None
        if step.robot_angle_deg is not None and devices.robot is not None:
            duration += abs(step.robot_angle_deg - angle) / devices.robot.speed_deg_s + ROBOT_SETTLE_S
            angle = step.robot_angle_deg
        if devices.laser is not None:
            duration += devices.laser.readings * LASER_READING_S
        duration += step.frames / fps + CAPTURE_SETUP_S
        planned.append(PlannedStep(step, position, t, duration))
        t += duration
    return planned


def expected_run_bytes(
    campaign: Campaign, compression: str, steps: list[Step] | None = None, camera: CameraInfo | None = None
) -> tuple[int, int]:
    """(raw, stored) bytes of the frames of ``steps`` (default: every step) at the resolution of
    ``camera`` (default: the camera profile's); stored = raw / the compression's planning ratio."""
    if camera is None:
        profile = get_profile(campaign.devices.camera.sim_profile)
        width, height, confidence = profile.width, profile.height, profile.confidence_dtype
    else:
        width, height, confidence = camera.width, camera.height, camera.confidence_dtype
    frames = sum(s.frames for s in (campaign.steps() if steps is None else steps))
    return frames * frame_bytes(width, height, confidence), expected_file_bytes(frames, width, height, confidence,
                                                                               compression)


def format_duration(seconds: float) -> str:
    """``1 h 02 min 03 s`` style."""
    seconds = int(round(seconds))
    h, rest = divmod(seconds, 3600)
    m, s = divmod(rest, 60)
    if h:
        return f"{h} h {m:02d} min {s:02d} s"
    if m:
        return f"{m} min {s:02d} s"
    return f"{s} s"
