"""Plausibility flags on the key figures (metrics/plausibility.py): which figure measures something else.

Each flag is ``{"check": NAME, "message": TEXT}`` in the figure's ``flags``
list of ``keyfigures.json`` and beside the figure in the report:

* ``above_nyquist``: the intensity resolution comes from an SFR10 above
  0.5 cy/px at best focus;
* ``quantization_limited``: a spread or error in mm below one quantization
  step of the coordinate it is computed from (x, y or z). A figure of stack
  means (trueness, surface Sq) is exempt when that coordinate's per-pixel
  noise is at least half a step: the noise then dithers the quantizer and a
  mean of many frames resolves below the step (Widrow & Kollar, Quantization
  Noise, 2008, ch. 4-5);
* ``near_axis``: an x or y repeatability taken at a pixel whose coordinate is
  ~0 (within 1 % of the distance), where the depth noise does not reach it.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field

from labctl.evaluation.sharpness import SharpnessResult
from metrics.plausibility import NYQUIST_CY_PX, above_nyquist, at_quantization_step, near_axis
from metrics.xy_error import XYPrecision

#: mm figures of the depth (z) channel: spreads and errors, not distances
Z_FIGURE_PREFIXES = ("z_", "surface_", "repeatability_skin_", "plane_fit_rms_", "spatial_precision_",
                     "temporal_precision_")


@dataclass
class PlausibilityInputs:
    """What the checks need besides the figures."""

    sharpness: SharpnessResult | None = None
    #: quantization step (mm) of the x, y and z output, NaN where continuous
    quantization_mm: dict[str, float] = field(default_factory=dict)
    #: the wall steps' x/y noise: (step id, distance mm, precision)
    xy_noise: list[tuple[str, float, XYPrecision]] = field(default_factory=list)
    #: per coordinate, the median per-pixel noise (mm) where the stack-mean figures are taken
    noise_mm: dict[str, float] = field(default_factory=dict)


def _of_stack_means(name: str) -> bool:
    return "trueness" in name or name.startswith("surface_")


def _channel(name: str) -> str | None:
    if not name.endswith("_mm"):
        return None
    if name.startswith(("x_", "y_")):
        return name[0]
    return "z" if name.startswith(Z_FIGURE_PREFIXES) else None


def _nyquist_flags(sharpness: SharpnessResult) -> dict[str, dict[str, str]]:
    best = next((p for p in sharpness.positions if p.distance_mm == sharpness.best_focus_mm), None)
    flags = {}
    for name, edge in (("intensity_resolution_h_deg", best.horizontal if best else None),
                       ("intensity_resolution_v_deg", best.vertical if best else None)):
        if edge is not None and above_nyquist(edge.sfr10):
            flags[name] = {"check": "above_nyquist", "message": (
                f"SFR10 {edge.sfr10:.2f} cy/px at best focus is above the Nyquist frequency ({NYQUIST_CY_PX} cy/px): "
                "aliasing, sharpening or a noisy edge, so the figure is better than the pixel grid allows")}
    return flags


def _near_axis_flags(xy_noise: Iterable[tuple[str, float, XYPrecision]]) -> dict[str, dict[str, str]]:
    flags = {}
    for where, attr in (("center", "center_xy_mm"), ("off_axis", "off_axis_xy_mm")):
        for index, axis in enumerate("xy"):
            on_axis = [(sid, getattr(p, attr)[index]) for sid, distance, p in xy_noise
                       if near_axis(getattr(p, attr)[index], distance)]
            if on_axis:
                sid, value = on_axis[0]
                flags[f"{axis}_repeatability_{where}_mm"] = {"check": "near_axis", "message": (
                    f"taken where {axis} = {value:.2f} mm ({sid}, {len(on_axis)} step(s)): on the principal axis "
                    f"the depth noise does not reach {axis}, only lateral jitter shows")}
    return flags


def plausibility_flags(values: Mapping[str, float | None], inputs: PlausibilityInputs) -> dict[str, list[dict[str, str]]]:
    """Per figure name, the plausibility checks it fails (names without a flag are left out)."""
    flags: dict[str, list[dict[str, str]]] = {}

    def add(found: Mapping[str, dict[str, str]]) -> None:
        for name, flag in found.items():
            flags.setdefault(name, []).append(flag)

    if inputs.sharpness is not None:
        add(_nyquist_flags(inputs.sharpness))
    add(_near_axis_flags(inputs.xy_noise))
    for name, value in values.items():
        channel = _channel(name)
        step = inputs.quantization_mm.get(channel, math.nan) if channel else math.nan
        dithered = _of_stack_means(name) and inputs.noise_mm.get(channel or "", math.nan) >= step / 2
        if value is not None and at_quantization_step(value, step) and not dithered:
            add({name: {"check": "quantization_limited", "message": (
                f"{value:.3g} mm is below the {channel} output's quantization step ({step:g} mm): rounding to "
                "whole steps (variance step^2 / 12, jumps of a step) is a large part of the figure")}})
    return flags
