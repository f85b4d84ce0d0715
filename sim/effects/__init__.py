"""The effect library (CONTRACTS §5): one module per effect, names fixed."""

from __future__ import annotations

from types import ModuleType
from typing import Any

from pydantic import ValidationError

from sim.effects import (
    camera_axis_offset,
    defocus,
    disparity_bias,
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

__all__ = ["EFFECTS", "EffectParams", "parse_effects"]

EFFECTS: dict[str, ModuleType] = {
    m.NAME: m
    for m in (
        range_offset, range_scale, wiggling, temperature_drift, intensity_related_error, vignetting,
        radial_distortion, fov_error, defocus, quantization, flying_pixels, multipath, material_bias,
        target_misalignment, camera_axis_offset, fixed_pattern, floor_multipath, disparity_bias,
    )
}


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
                else f"{'.'.join(str(p) for p in e['loc']) or name}: {e['msg'].removeprefix('Value error, ')}"
                for e in exc.errors()
            )
            raise ValueError(f"effects.{name}: {problems}") from None
    return parsed
