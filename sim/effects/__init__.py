"""The effect library (docs/simulation.md): one module per effect, names fixed.

Every module of this package that declares ``EFFECT`` (an :class:`Effect`) is
part of the vocabulary: adding an effect is adding its module. ``registered``
adds an effect defined elsewhere for the duration of a ``with`` block.
"""

from __future__ import annotations

import importlib
import pkgutil
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

import numpy as np
from pydantic import ValidationError

from sim.effects.base import Corners, Effect, EffectParams, Observed, PhasorStage, RangeStage, valid_range

__all__ = ["EFFECTS", "Corners", "Effect", "EffectParams", "Observed", "PhasorStage", "RangeStage", "acting", "background_level",
           "default_effects", "frame_offset_mm", "output_step_mm", "parse_effects", "plate_placement_mm", "registered",
           "valid_range", "warm_up_s"]


def _discover() -> dict[str, Effect]:
    """The ``EFFECT`` of every module of this package, by name (module order)."""
    found: dict[str, Effect] = {}
    for info in sorted(pkgutil.iter_modules(__path__), key=lambda m: m.name):
        effect = getattr(importlib.import_module(f"{__name__}.{info.name}"), "EFFECT", None)
        if isinstance(effect, Effect):
            found[effect.name] = effect
    return found


EFFECTS: dict[str, Effect] = _discover()


@contextmanager
def registered(effect: Effect) -> Iterator[Effect]:
    """``effect`` is part of the vocabulary inside the ``with`` block (a name already taken is refused)."""
    if effect.name in EFFECTS:
        raise ValueError(f"effect {effect.name!r} exists already")
    EFFECTS[effect.name] = effect
    try:
        yield effect
    finally:
        del EFFECTS[effect.name]


def acting(effects: dict[str, EffectParams], hook: str) -> list[tuple[Callable[..., Any], EffectParams]]:
    """(hook, parameters) of the effects present in ``effects`` that act through ``hook``, by ``order``."""
    present = sorted((EFFECTS[name] for name in effects), key=lambda e: e.order)
    return [(getattr(e, hook), effects[e.name]) for e in present if getattr(e, hook) is not None]


def shading_factor(effects: dict[str, EffectParams], cos_alpha: np.ndarray) -> np.ndarray | float:
    """The factor the effects' ``shading`` puts on the light at rays of the given cosines to the optical axis (1
    without)."""
    factor: np.ndarray | float = 1.0
    for hook, params in acting(effects, "shading"):
        factor = factor * hook(cos_alpha, params)
    return factor


def frame_offset_mm(effects: dict[str, EffectParams], t_s: float) -> float:
    """The effects' range offset (``frame_offset_mm``) of a frame taken at device time ``t_s`` (0 without)."""
    offset = 0.0
    for hook, params in acting(effects, "frame_offset_mm"):
        offset = offset + hook(t_s, params)
    return offset


def warm_up_s(effects: dict[str, EffectParams]) -> float | None:
    """The time constant of the camera's warm-up the effects state (``warm_up_s``; None without)."""
    return next((float(hook(params)) for hook, params in acting(effects, "warm_up_s")), None)


def background_level(effects: dict[str, EffectParams]) -> float:
    """The effects' background light (``background``) in units of the reference signal (0 without)."""
    return float(sum(hook(params) for hook, params in acting(effects, "background")))


def output_step_mm(effects: dict[str, EffectParams]) -> float:
    """The step the camera stores its coordinates in (the coarsest of the effects' ``step_mm``; 0: not stored in
    steps)."""
    return max((hook(params) for hook, params in acting(effects, "step_mm")), default=0.0)


def plate_placement_mm(effects: dict[str, EffectParams]) -> tuple[float, float]:
    """Robot lab: how far the camera's optical axis passes the robot axis to the side and how far the target plate
    stands behind the robot circle's centre (the effects' ``axis_offset_mm`` and ``plate_offset_mm``; 0 without)."""
    axis = plate = 0.0
    for hook, params in acting(effects, "axis_offset_mm"):
        axis = axis + hook(params)
    for hook, params in acting(effects, "plate_offset_mm"):
        plate = plate + hook(params)
    return axis, plate


def default_effects(profile: Any) -> dict[str, dict[str, Any]]:
    """The effects a built-in camera profile has by nature (each effect's ``built_in``; e.g. its defocus and its
    output quantization)."""
    found = {e.name: e.built_in(profile) for e in EFFECTS.values() if e.built_in is not None}
    return {name: dict(params) for name, params in found.items() if params is not None}


def _got(error: Any) -> str:
    """`` (got VALUE)`` for an error about one value; nothing for a missing field or a whole table."""
    value = error.get("input")
    return "" if error["type"] in {"missing", "model_type", "value_error"} or isinstance(value, dict) else f" (got {value!r})"


def parse_effects(raw: dict[str, dict[str, Any]], technology: str) -> dict[str, EffectParams]:
    """Validate an ``[effects]`` table; ValueError names the effect and the bad parameter."""
    parsed: dict[str, EffectParams] = {}
    for name, params in raw.items():
        effect = EFFECTS.get(name)
        if effect is None:
            raise ValueError(f"unknown effect {name!r}; the vocabulary is: {', '.join(EFFECTS)}")
        if technology not in effect.technologies:
            raise ValueError(f"effect {name!r} applies to {'/'.join(effect.technologies)} cameras, not {technology}")
        try:
            parsed[name] = effect.params.model_validate(params or {})
        except ValidationError as exc:
            problems = "; ".join(
                f"unknown parameter {'.'.join(str(p) for p in e['loc'])!r}" if e["type"] == "extra_forbidden"
                else f"{'.'.join(str(p) for p in e['loc']) or name}: {e['msg'].removeprefix('Value error, ')}{_got(e)}"
                for e in exc.errors()
            )
            raise ValueError(f"effects.{name}: {problems}") from None
    return parsed
