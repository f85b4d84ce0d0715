"""Simulation model files (CONTRACTS §5).

```toml
camera = "blaze101"              # built-in profile
[camera_overrides]               # any CameraProfile field
width = 64
[lab]                            # the simulated lab's ground truth (sim/lab.py)
camera_mount_error_mm = 6.0
[effects.wiggling]               # an effect present is on, absent is off
amplitude_mm = 4.0
```
"""

from __future__ import annotations

import tomllib
from pathlib import Path
from typing import Any

from pydantic import Field, ValidationError, field_validator

from labctl.errors import InputError
from procedures.steps import StrictModel
from sim.lab import LabGeometry
from sim.profiles import PROFILES, CameraProfile, get_profile

#: the fixed effect vocabulary of CONTRACTS §5
EFFECT_NAMES = (
    "range_offset", "range_scale", "wiggling", "temperature_drift", "intensity_related_error",
    "vignetting", "radial_distortion", "fov_error", "defocus", "quantization", "flying_pixels",
    "multipath", "material_bias", "target_misalignment", "camera_axis_offset",
)
#: effects this version of the simulator implements
IMPLEMENTED_EFFECTS: tuple[str, ...] = ()


class SimModel(StrictModel):
    camera: str
    camera_overrides: dict[str, Any] = Field(default_factory=dict)
    lab: LabGeometry = LabGeometry()
    effects: dict[str, dict[str, Any]] = Field(default_factory=dict)

    @field_validator("camera")
    @classmethod
    def _known_profile(cls, name: str) -> str:
        if name not in PROFILES:
            raise ValueError(f"unknown camera profile {name!r}; known: {', '.join(PROFILES)}")
        return name

    @field_validator("effects")
    @classmethod
    def _known_effects(cls, effects: dict[str, dict[str, Any]]) -> dict[str, dict[str, Any]]:
        for name in effects:
            if name not in EFFECT_NAMES:
                raise ValueError(f"unknown effect {name!r}; the vocabulary is: {', '.join(EFFECT_NAMES)}")
            if name not in IMPLEMENTED_EFFECTS:
                raise ValueError(f"effect {name!r} is not implemented by this simulator version")
        return effects

    def profile(self) -> CameraProfile:
        """The built-in profile with ``[camera_overrides]`` applied."""
        try:
            return get_profile(self.camera).with_overrides(self.camera_overrides)
        except KeyError as exc:
            raise InputError(f"model camera_overrides: unknown profile field(s): {exc.args[0]}") from None
        except TypeError as exc:
            raise InputError(f"model camera_overrides: {exc}") from None


def parse_model(text: str, source: str = "model") -> SimModel:
    """Validate model TOML text; InputError names the bad field."""
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise InputError(f"{source}: not valid TOML: {exc}") from None
    try:
        model = SimModel.model_validate(data)
    except ValidationError as exc:
        problems = "; ".join(
            f"{'.'.join(str(p) for p in e['loc']) or 'model'}: {e['msg'].removeprefix('Value error, ')}"
            for e in exc.errors()
        )
        raise InputError(f"{source} is not a valid simulation model: {problems}") from None
    model.profile()
    return model


def load_model(path: str | Path) -> tuple[SimModel, str]:
    """Read a model file; returns the model and its text (recorded under /sim)."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"cannot read model file {path}: {exc}") from None
    return parse_model(text, str(path)), text


def default_model_text(profile: str) -> str:
    """Model text for a built-in profile with no effects."""
    return f'camera = "{profile}"\n'
