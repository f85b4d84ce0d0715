"""What every effect module declares: one :class:`Effect`, named ``EFFECT``.

An effect owns its facts in one place: its name (the docs/simulation.md
name), the technologies it applies to (``tof`` and/or ``stereo``), where its
formula comes from, its parameters (``Params``: a strict pydantic model with
units in the field names, defaults and valid ranges), how ``labctl
reconcile`` can see it in a run (:class:`Observed`) and the hooks through
which it acts on the sensor's noise-free maps. The sensors (sim/tof.py,
sim/stereo.py) call the hooks of the effects present in a model's
``[effects]`` table at the stage where each acts; an effect present is on,
absent is off. The registry (sim/effects/__init__.py) finds every module of
this package that declares ``EFFECT``.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from procedures.steps import StrictModel


class EffectParams(StrictModel):
    """Base of every effect's parameters (unknown keys are refused)."""


@dataclass(frozen=True)
class RangeStage:
    """What a range hook may use: the sensor it acts in and, on a ToF sensor, the returned light.

    ``sensor`` is the :class:`~sim.tof.ToFSensor` (``profile``, ``geometry``,
    ``wavenumber``, ``a_ref``) or :class:`~sim.stereo.StereoSensor`
    (``profile``, ``geometry``, ``matching_focal_baseline``).
    """

    sensor: Any
    light: np.ndarray | None = None  # ToF: the returned light before vignetting (amplitude units)


@dataclass(frozen=True)
class Observed:
    """How ``labctl reconcile`` can tell the effect from a measured run (docs/reconcile.md).

    ``signature`` names the form of the change the effect makes to the
    prediction (labctl/reconcile/candidates.py builds the candidate from it
    and from the parameters' valid ranges); ``None`` means the comparison
    cannot see it, and ``why_not`` says why.
    """

    signature: str | None = None
    why_not: str = ""
    fitted: tuple[str, ...] = ()  # the parameters the fit determines, in the signature's order
    fixed: Mapping[str, Any] = field(default_factory=dict)  # parameters set to these values, not fitted
    steps: str = "all"  # which measured steps show it: "all", "translucent" (materials), "robot_plates"
    min_steps: int = 1  # tested only when the run holds at least this many such steps
    probe: float = 1.0  # "resimulated": the fitted parameter's value the effect is switched on with
    solver_bounds: Mapping[str, tuple[float, float]] = field(default_factory=dict)  # where the solver's bounds
    # differ from the valid range (an angle searched over two turns and wrapped, a log-scaled time's lower end)
    formula: Callable[..., Any] | None = None  # the effect's own formula, where the signature form needs it
    families: tuple[str, ...] = ("depth", "intensity")  # the residual families it changes ("resimulated": the
    # noise, validity and correlation families are re-simulated only for an effect that names them)


@dataclass(frozen=True)
class Effect:
    """One effect of the library: its facts and the hooks the sensors call (``None``: it does not act there).

    Hooks, in the order a sensor calls them:

    * ``subsurface_scale(p)``: multiplies every material's sub-surface bias (ToF render);
    * ``mixes_returns``: the ToF render keeps each pixel's correlation phasor;
      ``mixed_pixels``: the depth comes from the blurred phasor of every return
      (else from the dominant surface's own);
    * ``shading(cos_alpha, p)``: factor on the light after the blur (amplitude, IR image);
    * ``phasor(phasor, p, sensor)``: the ToF pixel's phasor before its phase gives the range;
    * ``on_range(values, p, stage)``: the noise-free ToF range or stereo depth map, in increasing ``order``;
    * ``background(p)``: background light the pixels collect besides the camera's own signal (ambient light),
      in units of the reference signal (ToF: A_ref, the amplitude of the 90 % wall at 2 m; stereo: the
      projector's dot light on that wall); it adds shot noise and lowers the contrast the stereo matcher sees;
    * ``frame_offset_mm(t_s, p)``: a range offset of the frame taken at device time ``t_s``;
    * ``step_mm(p)``: the step the coordinates are stored in.
    """

    name: str
    technologies: tuple[str, ...]
    params: type[EffectParams]
    source: str
    observed: Observed | None = None  # None: reconcile neither tests nor mentions it (the empirical corrections)
    order: int = 0  # where several effects act on the range, lower acts first
    subsurface_scale: Callable[[Any], float] | None = None
    mixes_returns: bool = False
    mixed_pixels: bool = False
    shading: Callable[[np.ndarray, Any], np.ndarray] | None = None
    phasor: Callable[[np.ndarray, Any, Any], np.ndarray] | None = None
    on_range: Callable[[np.ndarray, Any, RangeStage], np.ndarray] | None = None
    background: Callable[[Any], float] | None = None
    frame_offset_mm: Callable[[float, Any], float] | None = None
    step_mm: Callable[[Any], float] | None = None
