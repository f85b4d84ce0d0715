"""Campaign files (docs/campaign.md): TOML validated by pydantic.

Everything that can be checked before a device moves is checked here: unknown
keys, value ranges, procedure kinds, and every stage position against the
stage travel. Errors become :class:`~labctl.errors.InputError` with the field
path (``procedure[1].stop_mm``) and what is allowed.
"""

from __future__ import annotations

import tomllib
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any, Literal

from pydantic import Field, ValidationError, field_validator, model_validator

from labctl.errors import InputError
from labctl.run.filekind import describe, is_hdf5
from procedures import PROCEDURES, ProcedureConfig, Step
from procedures.steps import StrictModel
from procedures.targets import with_target_prompts

if TYPE_CHECKING:
    from drivers.robot.circle import MeasurementCircle

#: campaign ``backend`` -> simulation profile name (docs/campaign.md)
SIM_PROFILE_OF_BACKEND = {
    "realsense": "d455",
    "blaze": "blaze101",
    "amt100": "amt100",
    "flexx2": "flexx2",
    "d455": "d455",
    "blaze101": "blaze101",
}


def model_camera_mismatch(backend: str, model_camera: str) -> str | None:
    """Why a simulation model of camera ``model_camera`` does not stand for a campaign's ``backend``
    (None when it does, or when the backend has no simulated profile)."""
    profile = SIM_PROFILE_OF_BACKEND.get(backend)
    if profile is None or profile == model_camera:
        return None
    return (f"the model simulates camera {model_camera!r}, but the campaign's [devices.camera] backend = {backend!r} "
            f"is simulated as {profile!r}")


#: campaign ``backend`` -> real driver name
DRIVER_OF_BACKEND = {
    "realsense": "realsense",
    "blaze": "blaze",
    "amt100": "amt100",
    "flexx2": "flexx2",
    "d455": "realsense",
    "blaze101": "blaze",
}


class CampaignInfo(StrictModel):
    name: str = Field(min_length=1)
    operator: str = ""
    description: str = ""


class CameraConfig(StrictModel):
    backend: Literal["realsense", "blaze", "amt100", "flexx2", "d455", "blaze101"]
    serial: str | None = None
    settings: dict[str, Any] = Field(default_factory=dict)
    playback: str | None = Field(None, description="recording played instead of the live camera (.bag, .db3, .rrf)")
    producer: str | None = Field(None, description="GenTL producer .cti (blaze with sdk = harvesters, amt100)")
    sdk: Literal["pypylon", "harvesters"] = Field("pypylon", description="blaze: pypylon or harvesters")
    frame_timeout_s: float = Field(5.0, gt=0, le=120, description="longest wait for one frame")
    depth_origin_offset_mm: float | None = Field(
        None, ge=-1000.0, le=1000.0, allow_inf_nan=False,
        description="mechanical distance from the laser's zero to the camera's depth origin, positive when the "
                    "depth origin lies nearer the wall (docs/campaign.md, Reference distance); the absolute "
                    "reference is the laser reading minus it",
    )

    @model_validator(mode="after")
    def _real_options_fit_backend(self) -> CameraConfig:
        driver = self.driver
        if self.playback is not None and driver not in ("realsense", "flexx2"):
            raise ValueError(f"playback: backend {self.backend!r} cannot play recordings (realsense and flexx2 can)")
        if self.producer is not None and not (driver == "amt100" or (driver == "blaze" and self.sdk == "harvesters")):
            raise ValueError("producer applies to amt100 and to blaze with sdk = \"harvesters\"")
        if self.sdk != "pypylon" and driver != "blaze":
            raise ValueError(f"sdk applies to the blaze backend only, not to {self.backend!r}")
        return self

    @property
    def sim_profile(self) -> str:
        return SIM_PROFILE_OF_BACKEND[self.backend]

    @property
    def driver(self) -> str:
        return DRIVER_OF_BACKEND[self.backend]


class StageConfig(StrictModel):
    protocol: Literal["zaber", "grbl"]
    port: str | None = None
    baud: int | None = Field(None, gt=0)
    travel_mm: tuple[float, float] = (0.0, 4000.0)
    speed_mm_s: float = Field(50.0, gt=0, le=2000)
    settle_s: float = Field(0.5, ge=0, le=60)
    distance_at_zero_mm: float = Field(
        0.0, description="camera-wall distance when the stage is at position 0"
    )
    axis_direction: Literal["away_from_wall", "towards_wall"] = "away_from_wall"
    home_on_connect: bool = Field(False, description="home the stage when a real run connects")
    mm_per_microstep: float | None = Field(None, gt=0, description="Zaber: microstep size (stage datasheet)")
    device: int = Field(1, ge=1, le=99, description="Zaber: device number on the daisy chain")
    axis: int | str | None = Field(None, description="Zaber: axis number (default 1); Grbl: axis letter (default X)")
    checksums: bool = Field(False, description="Zaber: send a checksum with every command")

    @model_validator(mode="after")
    def _protocol_options(self) -> StageConfig:
        if self.protocol == "zaber" and self.axis is not None and not isinstance(self.axis, int):
            raise ValueError(f"axis: a Zaber axis is a number, got {self.axis!r}")
        if self.protocol == "grbl":
            if self.axis is not None and (not isinstance(self.axis, str) or self.axis.upper() not in "XYZABC"):
                raise ValueError(f"axis: a Grbl axis is one of X, Y, Z, A, B, C, got {self.axis!r}")
            if self.mm_per_microstep is not None or self.device != 1 or self.checksums:
                raise ValueError("mm_per_microstep, device and checksums apply to Zaber stages only")
        return self

    @field_validator("travel_mm")
    @classmethod
    def _travel_ordered(cls, value: tuple[float, float]) -> tuple[float, float]:
        if value[1] <= value[0]:
            raise ValueError(f"travel_mm must be [min, max] with min < max, got {list(value)}")
        return value

    def position_for_distance(self, distance_mm: float) -> float:
        """Stage coordinate that puts the camera ``distance_mm`` from the wall."""
        sign = 1.0 if self.axis_direction == "away_from_wall" else -1.0
        return sign * (distance_mm - self.distance_at_zero_mm)


class LaserConfig(StrictModel):
    port: str | None = None
    baud: int = Field(19200, gt=0)
    device_id: int = Field(0, ge=0, le=9, description="Dimetix device ID (ID switch)")
    readings: int = Field(5, ge=1, le=100, description="readings averaged per step")
    offset_mm: float | None = Field(
        None, description="known camera-laser offset, used until an offset_calibration step measures it"
    )


class RobotConfig(StrictModel):
    host: str = "127.0.0.1"
    radius_max_mm: float = Field(850.0, gt=0)
    angle_limits_deg: tuple[float, float] = (-90.0, 90.0)
    speed_deg_s: float = Field(10.0, gt=0, le=180)
    acceleration_deg_s2: float = Field(20.0, gt=0, le=720)
    settle_s: float = Field(0.5, ge=0, le=60)
    circle_center_mm: tuple[float, float, float] | None = Field(None, description="target point, robot base frame")
    rotation_axis: tuple[float, float, float] = (0.0, 0.0, 1.0)
    zero_pose: tuple[float, float, float, float, float, float] | None = Field(
        None, description="camera TCP pose at 0 deg: x, y, z in mm, rx, ry, rz rotation vector in rad"
    )
    tcp_box_mm: tuple[tuple[float, float], tuple[float, float], tuple[float, float]] | None = None
    joint_limits_deg: list[tuple[float, float]] | None = Field(None, min_length=6, max_length=6)

    @model_validator(mode="after")
    def _circle_consistent(self) -> RobotConfig:
        if (self.circle_center_mm is None) != (self.zero_pose is None):
            raise ValueError("circle_center_mm and zero_pose go together")
        if self.circle_center_mm is not None:
            self.circle()  # raises ValueError naming what does not fit
        return self

    def circle(self) -> MeasurementCircle:
        """The measurement circle of ``circle_center_mm``, ``rotation_axis`` and ``zero_pose``
        (imported here: scipy's rotations are slow to import and only real robots need them)."""
        from drivers.robot.circle import MeasurementCircle

        return MeasurementCircle(self.circle_center_mm, self.rotation_axis, self.zero_pose)


class DevicesConfig(StrictModel):
    camera: CameraConfig
    stage: StageConfig | None = None
    laser: LaserConfig | None = None
    robot: RobotConfig | None = None


class FaultRates(StrictModel):
    """Probability per step that each fault kind strikes once (simulation only)."""

    serial_timeout: float = Field(0.0, ge=0, le=1)
    serial_garbage: float = Field(0.0, ge=0, le=1)
    camera_disconnect: float = Field(0.0, ge=0, le=1)
    dropped_frame: float = Field(0.0, ge=0, le=1)
    robot_protective_stop: float = Field(0.0, ge=0, le=1)


class SimConfig(StrictModel):
    seed: int = Field(0, ge=0)
    faults: FaultRates = FaultRates()


class RunnerConfig(StrictModel):
    max_attempts: int = Field(5, ge=1, le=50, description="attempts per operation")
    backoff_s: float = Field(0.5, ge=0, le=60, description="first retry delay, doubled each time")
    backoff_max_s: float = Field(10.0, ge=0, le=600)
    operator_time_s: float = Field(60.0, ge=0, description="lab time planned per operator prompt")
    compression: Literal["blosc-lz4", "none"] = Field("blosc-lz4", description="how run files store frames")


ProcedureEntry = Annotated[ProcedureConfig, Field(discriminator="kind")]


class Campaign(StrictModel):
    campaign: CampaignInfo
    devices: DevicesConfig
    procedure: list[ProcedureEntry] = Field(min_length=1)
    runner: RunnerConfig = RunnerConfig()
    sim: SimConfig = SimConfig()

    @field_validator("procedure", mode="before")
    @classmethod
    def _known_kinds(cls, entries: Any) -> Any:
        if isinstance(entries, list):
            for i, entry in enumerate(entries):
                kind = entry.get("kind") if isinstance(entry, dict) else None
                if kind is None:
                    raise ValueError(f"procedure[{i}] has no 'kind'")
                if not isinstance(kind, str) or kind not in PROCEDURES:
                    raise ValueError(
                        f"procedure[{i}].kind = {kind!r} is not available; "
                        f"known kinds: {', '.join(PROCEDURES)}"
                    )
        return entries

    @model_validator(mode="after")
    def _devices_reach_positions(self) -> Campaign:
        stage = self.devices.stage
        for i, proc in enumerate(self.procedure):
            distances = proc.stage_distances_mm()
            if distances and stage is None:
                raise ValueError(f"procedure[{i}] ({proc.kind}) moves the stage but [devices.stage] is missing")
            if proc.kind == "offset_calibration" and self.devices.laser is None:
                raise ValueError(f"procedure[{i}] (offset_calibration) needs [devices.laser]")
            for distance in distances:
                position = stage.position_for_distance(distance)
                lo, hi = stage.travel_mm
                if not lo <= position <= hi:
                    raise ValueError(
                        f"procedure[{i}] ({proc.kind}): distance {distance:g} mm needs stage position "
                        f"{position:g} mm, outside devices.stage.travel_mm [{lo:g}, {hi:g}]"
                    )
        return self

    @model_validator(mode="after")
    def _offset_known_in_time(self) -> Campaign:
        laser = self.devices.laser
        if laser is None or laser.offset_mm is not None:
            return self
        for i, proc in enumerate(self.procedure):
            if proc.kind == "offset_calibration":
                break
            if proc.needs_reference:
                raise ValueError(
                    f"procedure[{i}] ({proc.kind}) needs the camera-laser offset: put an offset_calibration "
                    "before it or set devices.laser.offset_mm"
                )
        return self

    @model_validator(mode="after")
    def _robot_reaches_poses(self) -> Campaign:
        """Every planned robot pose inside the robot's angle and radius limits, before anything moves."""
        robot = self.devices.robot
        for i, proc in enumerate(self.procedure):
            poses = proc.robot_positions() if hasattr(proc, "robot_positions") else []
            if poses and robot is None:
                raise ValueError(f"procedure[{i}] ({proc.kind}) moves the robot but [devices.robot] is missing")
            for angle, radius in poses:
                lo, hi = robot.angle_limits_deg
                if not lo <= angle <= hi:
                    raise ValueError(f"procedure[{i}] ({proc.kind}): angle {angle:g} deg outside "
                                     f"devices.robot.angle_limits_deg [{lo:g}, {hi:g}]")
                if radius > robot.radius_max_mm:
                    raise ValueError(f"procedure[{i}] ({proc.kind}): radius {radius:g} mm beyond "
                                     f"devices.robot.radius_max_mm {robot.radius_max_mm:g}")
        return self

    @model_validator(mode="after")
    def _best_focus_after_slanted_edge(self) -> Campaign:
        seen = False
        for i, proc in enumerate(self.procedure):
            seen = seen or proc.kind == "slanted_edge"
            if getattr(proc, "distance_mm", None) == "best_focus" and not seen:
                raise ValueError(
                    f"procedure[{i}] ({proc.kind}) takes distance_mm = \"best_focus\" from an earlier slanted_edge: "
                    "put a slanted_edge before it or give distance_mm in mm"
                )
        return self

    def steps(self) -> list[Step]:
        """The whole plan, steps numbered in execution order, a prompt at every change of target."""
        steps: list[Step] = []
        for proc in self.procedure:
            steps.extend(proc.steps(len(steps)))
        return with_target_prompts(steps)


def _format_location(loc: tuple[Any, ...]) -> str:
    parts: list[str] = []
    for i, item in enumerate(loc):
        if isinstance(item, int):
            parts[-1] = f"{parts[-1]}[{item}]" if parts else f"[{item}]"
        elif i > 0 and loc[i - 1] == item:
            continue
        elif i > 0 and isinstance(loc[i - 1], int) and item in PROCEDURES:
            continue  # discriminator tag inserted by pydantic
        else:
            parts.append(str(item))
    return ".".join(parts)


def _describe(error: dict[str, Any]) -> str:
    where = _format_location(tuple(error["loc"]))
    kind = error["type"]
    if kind == "extra_forbidden":
        section, _, key = where.rpartition(".")
        return f"unknown key '{key}'" + (f" in [{section}]" if section else " at top level")
    message = error["msg"].removeprefix("Value error, ")
    if kind in {"value_error", "assertion_error"} and not where:
        return message
    got = error.get("input")
    shown = "" if kind in {"missing", "model_type"} or isinstance(got, dict) else f" (got {got!r})"
    return f"{where or 'campaign'}: {message}{shown}"


def parse_campaign(text: str, source: str = "campaign") -> Campaign:
    """Parse and validate campaign TOML text; raise InputError naming every bad field."""
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise InputError(f"{source}: not valid TOML: {exc}") from None
    try:
        return Campaign.model_validate(data)
    except ValidationError as exc:
        problems = "\n  - ".join(_describe(e) for e in exc.errors())
        raise InputError(f"{source} is not a valid campaign:\n  - {problems}") from None


def load_campaign(path: str | Path) -> tuple[Campaign, str]:
    """Read a campaign file; returns the validated campaign and its text (stored in the run file)."""
    path = Path(path)
    if is_hdf5(path):
        raise InputError(not_a_campaign(path))
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise InputError(f"campaign file {path} does not exist") from None
    except UnicodeDecodeError:
        raise InputError(f"{path} is {describe(path)}, not a campaign file: a campaign is a TOML text file "
                         "(docs/campaign.md; examples/*.toml)") from None
    except OSError as exc:
        raise InputError(f"cannot read campaign file {path}: {exc.strerror or exc}") from None
    return parse_campaign(text, str(path)), text


def not_a_campaign(path: Path) -> str:
    """The message for an HDF5 file given as the campaign: a run file points to the commands that take one."""
    import h5py

    from labctl.run.store import FORMAT

    try:
        with h5py.File(path, "r") as f:
            is_run = f.attrs.get("format") == FORMAT
    except OSError:
        is_run = False
    if is_run:
        return (f"{path} is a labctl run file, not a campaign; did you mean 'labctl resume {path}' or "
                f"'labctl evaluate {path} -o DIR'?")
    return f"{path} is an HDF5 file, not a campaign file: a campaign is a TOML text file (docs/campaign.md)"
