"""The effect library (docs/simulation.md): one module per effect, names fixed."""

from __future__ import annotations

from types import ModuleType
from typing import Any

import numpy as np
from pydantic import ValidationError

from sim.effects import (
    camera_axis_offset,
    defocus,
    disparity_bias,
    empirical_pixel_map,
    empirical_range,
    fixed_pattern,
    floor_multipath,
    flying_pixels,
    fov_error,
    intensity_related_error,
    material_bias,
    multipath,
    quantization,
    radial_distortion,
    range_offset,
    range_scale,
    target_misalignment,
    temperature_drift,
    vignetting,
    wiggling,
)
from sim.effects.base import EffectParams

__all__ = ["EFFECTS", "EffectParams", "apply_empirical", "parse_effects"]

EFFECTS: dict[str, ModuleType] = {
    m.NAME: m
    for m in (
        range_offset, range_scale, wiggling, temperature_drift, intensity_related_error, vignetting,
        radial_distortion, fov_error, defocus, quantization, flying_pixels, multipath, material_bias,
        target_misalignment, camera_axis_offset, fixed_pattern, floor_multipath, disparity_bias, empirical_range,
        empirical_pixel_map,
    )
}


def apply_empirical(values: np.ndarray, effects: dict[str, EffectParams]) -> np.ndarray:
    """``values`` (ToF range or stereo z, an (H, W) map) with the model's empirical corrections added
    (``empirical_range``, then ``empirical_pixel_map``); unchanged without them."""
    if "empirical_range" in effects:
        values = empirical_range.apply(values, effects["empirical_range"])
    if "empirical_pixel_map" in effects:
        values = empirical_pixel_map.apply(values, effects["empirical_pixel_map"])
    return values


def _got(error: Any) -> str:
    """`` (got VALUE)`` for an error about one value; nothing for a missing field or a whole table."""
    value = error.get("input")
    return "" if error["type"] in {"missing", "model_type", "value_error"} or isinstance(value, dict) else f" (got {value!r})"


def parse_effects(raw: dict[str, dict[str, Any]], technology: str) -> dict[str, EffectParams]:
    """Validate an ``[effects]`` table; ValueError names the effect and the bad parameter."""
    parsed: dict[str, EffectParams] = {}
    for name, params in raw.items():
        module = EFFECTS.get(name)
        if module is None:
            raise ValueError(f"unknown effect {name!r}; the vocabulary is: {', '.join(EFFECTS)}")
        if technology not in module.TECHNOLOGIES:
            raise ValueError(f"effect {name!r} applies to {'/'.join(module.TECHNOLOGIES)} cameras, not {technology}")
        try:
            parsed[name] = module.Params.model_validate(params or {})
        except ValidationError as exc:
            problems = "; ".join(
                f"unknown parameter {'.'.join(str(p) for p in e['loc'])!r}" if e["type"] == "extra_forbidden"
                else f"{'.'.join(str(p) for p in e['loc']) or name}: {e['msg'].removeprefix('Value error, ')}{_got(e)}"
                for e in exc.errors()
            )
            raise ValueError(f"effects.{name}: {problems}") from None
    return parsed
