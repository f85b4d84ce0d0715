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
from typing import Any

import tomli_w
from pydantic import Field, ValidationError, field_validator, model_validator

from procedures.steps import StrictModel
from sim.effects import EffectParams, parse_effects
from sim.lab import LabGeometry
from sim.profiles import PROFILES, CameraProfile, default_effects, get_profile


class ModelError(ValueError):
    """A simulation model (file or text) is invalid; the message names the file and the field."""

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

    @model_validator(mode="after")
    def _valid_effects(self) -> SimModel:
        parse_effects(self.effects, PROFILES[self.camera].technology)
        return self

    def profile(self) -> CameraProfile:
        """The built-in profile with ``[camera_overrides]`` applied."""
        try:
            return get_profile(self.camera).with_overrides(self.camera_overrides)
        except KeyError as exc:
            raise ModelError(f"model camera_overrides: unknown profile field(s): {exc.args[0]}") from None
        except TypeError as exc:
            raise ModelError(f"model camera_overrides: {exc}") from None

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
        problems = "; ".join(
            f"{'.'.join(str(p) for p in e['loc']) or 'model'}: {e['msg'].removeprefix('Value error, ')}"
            for e in exc.errors()
        )
        raise ModelError(f"{source} is not a valid simulation model: {problems}") from None
    model.profile()
    return model


def load_model(path: str | Path) -> tuple[SimModel, str]:
    """Read a model file; returns the model and its text (recorded under /sim)."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise ModelError(f"cannot read model file {path}: {exc}") from None
    return parse_model(text, str(path)), text


def default_model_text(profile: str) -> str:
    """The built-in model of a profile: the camera plus the effects it has by nature (defocus, quantization)."""
    return tomli_w.dumps({"camera": profile, "effects": default_effects(get_profile(profile))})
