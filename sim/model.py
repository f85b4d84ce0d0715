"""Simulation model files (docs/simulation.md).

```toml
camera = "blaze101"              # built-in profile
[camera_overrides]               # any CameraProfile field
width = 64
[lab]                            # the simulated lab's ground truth (sim/lab.py)
camera_mount_error_mm = 6.0
[effects.wiggling]               # an effect present is on, absent is off
amplitude_mm = 4.0
```

Without ``--model`` a run uses the profile's built-in model
(``default_model_text``): the camera with the effects it has by nature.
"""

from __future__ import annotations

import tomllib
from pathlib import Path
from typing import Any, Literal

import tomli_w
from pydantic import ConfigDict, Field, ValidationError, field_serializer, field_validator, model_validator

from procedures.steps import StrictModel
from sim.effects import EffectParams, default_effects, parse_effects
from sim.errors import ModelError
from sim.lab import LabGeometry
from sim.materials import WAVELENGTH_RANGE_NM
from sim.profiles import MAX_SENSOR_PX, PROFILES, CameraProfile, get_profile

#: the least a ToF camera's noise and modulation frequency and a stereo camera's baseline can be: below them the
#: simulator's optical power (eq. 2-9) or disparity leaves the floating-point range
MIN_TOF_NOISE_MM = 0.001
MIN_MODULATION_MHZ = 1.0
MIN_BASELINE_MM = 1.0


class CameraOverrides(StrictModel):
    """``[camera_overrides]``: any :class:`CameraProfile` field, each within what the simulator can compute
    with (positive sizes and rates, angles inside (0, 180) deg, noise >= 0). Numbers must be numbers: a
    quoted ``"160"`` is refused rather than guessed."""

    model_config = ConfigDict(strict=True)

    name: str | None = Field(None, min_length=1)
    vendor: str | None = Field(None, min_length=1)
    model: str | None = Field(None, min_length=1)
    technology: Literal["tof", "stereo"] | None = None
    width: int | None = Field(None, ge=1, le=MAX_SENSOR_PX, description="px")
    height: int | None = Field(None, ge=1, le=MAX_SENSOR_PX, description="px")
    fov_h_deg: float | None = Field(None, gt=0.0, lt=180.0)
    fov_v_deg: float | None = Field(None, gt=0.0, lt=180.0)
    pixel_pitch_um: float | None = Field(None, gt=0.0)
    wavelength_nm: float | None = Field(None, ge=WAVELENGTH_RANGE_NM[0], le=WAVELENGTH_RANGE_NM[1],
                                        description="within the material table's NIR range")
    frame_rate_hz: float | None = Field(None, ge=0.1, le=10000.0)
    exposure_us: float | None = Field(None, gt=0.0)
    noise_mm_at_2m: float | None = Field(None, ge=0.0, le=1000.0, description=f"1 sigma; >= {MIN_TOF_NOISE_MM} on a ToF camera")
    hyperfocal_mm: float | None = Field(None, gt=0.0)
    min_range_mm: float | None = Field(None, ge=0.0)
    max_range_mm: float | None = Field(None, gt=0.0)
    confidence_dtype: Literal["float32", "uint16"] | None = None
    lens_sigma_px: float | None = Field(None, ge=0.0, le=10.0, description="in-focus Gaussian PSF sigma")
    output_step_mm: float | None = Field(None, ge=0.0, le=50.0)
    modulation_mhz: float | None = Field(None, ge=0.0, le=1000.0, description=f">= {MIN_MODULATION_MHZ} on a ToF camera")
    modulation_contrast: float | None = Field(None, ge=0.01, le=1.0)
    ambient_ratio: float | None = Field(None, ge=0.0)
    saturation_ratio: float | None = Field(None, gt=0.0)
    confidence_threshold_ratio: float | None = Field(None, ge=0.0)
    baseline_mm: float | None = Field(None, ge=0.0, le=1000.0, description=f">= {MIN_BASELINE_MM} on a stereo camera")
    disparity_step_px: float | None = Field(None, ge=0.0, le=1.0, description="0: no sub-pixel quantization")
    texture_threshold: float | None = Field(None, ge=0.0)
    angle_noise_gain: float | None = Field(None, ge=0.0, le=100.0)

    def given(self) -> dict[str, Any]:
        """The fields the model file sets."""
        return self.model_dump(exclude_none=True)


def _profile_problems(profile: CameraProfile) -> list[str]:
    """What a profile with overrides applied cannot simulate (fields that only make sense together)."""
    p, problems = profile, []
    if p.max_range_mm <= p.min_range_mm:
        problems.append(f"max_range_mm = {p.max_range_mm:g} is not above min_range_mm = {p.min_range_mm:g}: "
                        "give a range with min_range_mm < max_range_mm")
    if p.confidence_threshold_ratio >= p.saturation_ratio:
        problems.append(f"confidence_threshold_ratio = {p.confidence_threshold_ratio:g} is not below "
                        f"saturation_ratio = {p.saturation_ratio:g}: no amplitude would be valid")
    if p.technology == "tof":
        if p.modulation_mhz < MIN_MODULATION_MHZ:
            problems.append(f"modulation_mhz = {p.modulation_mhz:g} on a ToF camera ({p.name}): give its modulation "
                            f"frequency, >= {MIN_MODULATION_MHZ:g} MHz (range and noise follow from it)")
        if p.noise_mm_at_2m < MIN_TOF_NOISE_MM:
            problems.append(f"noise_mm_at_2m = {p.noise_mm_at_2m:g} on a ToF camera ({p.name}): give a noise >= "
                            f"{MIN_TOF_NOISE_MM:g} mm (it sets the optical power through eq. 2-9; a noiseless ToF camera "
                            "has infinite power)")
    elif p.baseline_mm < MIN_BASELINE_MM:
        problems.append(f"baseline_mm = {p.baseline_mm:g} on a stereo camera ({p.name}): give the baseline, "
                        f">= {MIN_BASELINE_MM:g} mm")
    return problems


class SimModel(StrictModel):
    camera: str
    camera_overrides: CameraOverrides = CameraOverrides()
    lab: LabGeometry = LabGeometry()
    effects: dict[str, dict[str, Any]] = Field(default_factory=dict)

    @field_validator("camera")
    @classmethod
    def _known_profile(cls, name: str) -> str:
        if name not in PROFILES:
            raise ValueError(f"unknown camera profile {name!r}; known: {', '.join(PROFILES)}")
        return name

    @field_serializer("camera_overrides")
    def _only_given(self, overrides: CameraOverrides) -> dict[str, Any]:
        return overrides.given()

    @model_validator(mode="after")
    def _valid_profile_and_effects(self) -> SimModel:
        problems = _profile_problems(self.profile())
        if problems:
            raise ValueError("camera_overrides: " + "; ".join(problems))
        parse_effects(self.effects, self.profile().technology)
        return self

    def profile(self) -> CameraProfile:
        """The built-in profile with ``[camera_overrides]`` applied."""
        return get_profile(self.camera).with_overrides(self.camera_overrides.given())

    def effect_params(self) -> dict[str, EffectParams]:
        """Validated parameters of every effect that is on."""
        return parse_effects(self.effects, self.profile().technology)


def parse_model(text: str, source: str = "model") -> SimModel:
    """Validate model TOML text; ModelError names the bad field."""
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ModelError(f"{source}: not valid TOML: {exc}") from None
    try:
        model = SimModel.model_validate(data)
    except ValidationError as exc:
        problems = "; ".join(_describe(e) for e in exc.errors())
        raise ModelError(f"{source} is not a valid simulation model: {problems}") from None
    return model


def _describe(error: Any) -> str:
    """One pydantic error as ``field: what is wrong (got VALUE)``; unknown keys with the table they are in."""
    where = ".".join(str(p) for p in error["loc"])
    if error["type"] == "extra_forbidden":
        table, _, key = where.rpartition(".")
        if table == "camera_overrides":
            return f"camera_overrides: unknown profile field {key!r}; the fields are: {', '.join(CameraOverrides.model_fields)}"
        return f"unknown key {key!r}" + (f" in [{table}]" if table else " at top level")
    message = error["msg"].removeprefix("Value error, ")
    if error["type"] == "value_error" and not where:
        return message  # a check of the whole model names its fields itself
    got = error.get("input")
    shown = "" if error["type"] in {"missing", "model_type", "value_error"} or isinstance(got, dict) else f" (got {got!r})"
    return f"{where or 'model'}: {message}{shown}"


HDF5_SIGNATURE = b"\x89HDF\r\n\x1a\n"
"""The first bytes of an HDF5 file (HDF5 File Format Specification, "Format Signature"): a run file given as a model."""


def load_model(path: str | Path) -> tuple[SimModel, str]:
    """Read a model file; returns the model and its text (recorded under /sim)."""
    path = Path(path)
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise ModelError(f"cannot read model file {path}: {exc.strerror or exc}") from None
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError:
        kind = "an HDF5 file (a run file?)" if raw.startswith(HDF5_SIGNATURE) else "not text"
        raise ModelError(f"model file {path} is {kind}, it begins with the bytes {raw[:8].hex(' ')}: a model file is "
                         "TOML text (docs/simulation.md, Model files)") from None
    return parse_model(text, str(path)), text


def default_model_text(profile: str) -> str:
    """The built-in model of a profile: the camera plus the effects it has by nature (defocus, quantization)."""
    return tomli_w.dumps({"camera": profile, "effects": default_effects(get_profile(profile))})
