"""What every effect module declares: one :class:`Effect`, named ``EFFECT``.

An effect owns its facts in one place: its name (the docs/simulation.md
name), the technologies it applies to (``tof`` and/or ``stereo``), where its
formula comes from, its parameters (``Params``: a strict pydantic model with
units in the field names, defaults and valid ranges), whether a camera's
built-in model has it, how ``labctl reconcile`` can see it in a run
(:class:`Observed`) and the hooks through which it acts on the camera: its
optics, the robot lab's placement, the render, the blur and the sensor's
noise-free maps. The simulator (sim/sensor.py, sim/tof.py, sim/stereo.py,
sim/world.py) and reconcile's prediction call the hooks of the effects present
in a model's ``[effects]`` table at the stage where each acts; an effect
present is on, absent is off. No module of the simulator or of reconcile
names an effect or states its parameters' bounds (tests/test_architecture.py).
The registry (sim/effects/__init__.py) finds every module
of this package that declares ``EFFECT``.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

from procedures.steps import StrictModel


class EffectParams(StrictModel):
    """Base of every effect's parameters (unknown keys are refused)."""


def valid_range(params: type[EffectParams], key: str) -> tuple[float, float]:
    """The (lower, upper) bound the field ``key`` of ``params`` declares (``ge``/``gt``, ``le``/``lt``;
    infinite where it declares none)."""
    lo, hi = -math.inf, math.inf
    for limit in params.model_fields[key].metadata:
        lo = getattr(limit, "ge", getattr(limit, "gt", lo))
        hi = getattr(limit, "le", getattr(limit, "lt", hi))
    return float(lo), float(hi)


class RunHoldings(Protocol):
    """What a measured run already holds, as an effect's capture hint asks it (reconcile answers from the run's
    steps), so that a hint never asks for a capture the run has."""

    @property
    def first_position(self) -> str:
        """The sweep's first stage position ("850 mm"), or "first" when the run has none."""
        ...

    def repeated_after(self, seconds: float) -> bool:
        """Whether the run sees a position again at least ``seconds`` after it first saw it."""
        ...

    def early_stacks(self, within_s: float) -> int:
        """How many stacks of the first position the run took within ``within_s`` of the first."""
        ...

    def time_capture(self, after_s: float) -> str:
        """A capture the run lacks that tells the time from the distance, at least ``after_s`` apart."""
        ...


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
class PhasorStage:
    """What a phasor hook may use: the :class:`~sim.tof.ToFSensor` it acts in (``wavenumber``) and the mean over
    the image of every return reaching the pixels (the blurred phasor of all sub-pixel returns: the light the
    whole scene sends back, each surface at its own range)."""

    sensor: Any
    scene_mean: complex


@dataclass(frozen=True)
class Corners:
    """How the checkerboard corner comparison fits the effect (labctl/reconcile/corners.py, docs/reconcile.md).

    The fit searches a vector (entries named ``keys``) within ``lower`` to
    ``upper`` from ``start(profile)`` (the camera's :class:`~sim.profiles.CameraProfile`);
    ``params(x)`` turns it into the effect's parameters, completed by each of
    ``variants`` in turn (the best kept).
    """

    keys: tuple[str, ...]
    lower: tuple[float, ...]
    upper: tuple[float, ...]
    start: Callable[[Any], tuple[float, ...]]
    params: Callable[[Any], dict[str, Any]]
    variants: tuple[Mapping[str, Any], ...] = ({},)


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
    corners: Corners | None = None  # how the checkerboard corners show it (None: they do not)
    procedure: str = ""  # the procedure whose captures show it (named when a run has nothing comparable)
    capture: Callable[[Mapping[str, Any], RunHoldings], str] | None = None  # the capture that would determine its
    # fitted parameters better, from them and what the run already holds (never one the run has)
    families: tuple[str, ...] = ("depth", "intensity")  # the residual families it changes ("resimulated": the
    # noise, validity and correlation families are re-simulated only for an effect that names them)


@dataclass(frozen=True)
class Effect:
    """One effect of the library: its facts and the hooks the sensors call (``None``: it does not act there).

    ``built_in(profile)``: its parameters in a camera's built-in model, from the
    :class:`~sim.profiles.CameraProfile` (``None``: not in it).

    Hooks that decide what the camera images (sim/sensor.py, sim/world.py):

    * ``true_fov_deg(p)``: the [h, v] FOV the scene is imaged with (the datasheet's without);
    * ``lens_distortion(p)``: (k1, whether the point cloud carries the distortion) of the Brown radial model;
    * ``axis_offset_mm(p)``: robot lab: the camera's optical axis passes the robot axis this far to the side;
    * ``plate_offset_mm(p)``: robot lab: the target plate stands this far behind the robot circle's centre;
    * ``blur_px(distance_mm, p, default_coc_px)``: the diameter of a blur disc at ``distance_mm``
      (``default_coc_px``: the disc that costs the profile's lens 10 % of its SFR area);
    * ``binned(p, width, height)``: its parameters for the same camera with pixels merged into bins
      (reconcile's prediction), drawn on the ``width`` x ``height`` sensor; an effect with ``blur_px`` is left
      out of the binned camera.

    An effect with any of these hooks but ``blur_px`` and ``binned``, or with
    ``subsurface_scale``, ``mixes_returns`` or ``mixed_pixels``, changes what
    the render sees (``changes_render``); the two robot-lab hooks only on the
    robot's plates (``changes_stage_render``: the others).

    Hooks, in the order a sensor calls them:

    * ``subsurface_scale(p)``: multiplies every material's sub-surface bias (ToF render);
    * ``mixes_returns``: the ToF render keeps each pixel's correlation phasor;
      ``mixed_pixels``: the depth comes from the blurred phasor of every return
      (else from the dominant surface's own);
    * ``shading(cos_alpha, p)``: factor on the light after the blur (amplitude, IR image);
    * ``phasor(phasor, p, stage)``: the ToF pixel's phasor before its phase gives the range (``PhasorStage``);
    * ``on_range(values, p, stage)``: the noise-free ToF range or stereo depth map, in increasing ``order``;
      ``periodic_range``: that hook is a periodic function of the value it acts on alone (a wiggling, a pixel
      locking; any array shape), so that its mean over pixels spread in range differs from its value at their
      mean range;
    * ``background(p)``: background light the pixels collect besides the camera's own signal (ambient light),
      in units of the reference signal (ToF: A_ref, the amplitude of the 90 % wall at 2 m; stereo: the
      projector's dot light on that wall); it adds shot noise and lowers the contrast the stereo matcher sees;
    * ``frame_offset_mm(t_s, p)``: a range offset of the frame taken at device time ``t_s``;
    * ``warm_up_s(p)``: the time constant of the camera's warm-up the effect follows (the camera's reported
      temperature warms with it);
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
    phasor: Callable[[np.ndarray, Any, PhasorStage], np.ndarray] | None = None
    on_range: Callable[[np.ndarray, Any, RangeStage], np.ndarray] | None = None
    periodic_range: bool = False
    background: Callable[[Any], float] | None = None
    frame_offset_mm: Callable[[float, Any], float] | None = None
    warm_up_s: Callable[[Any], float] | None = None
    step_mm: Callable[[Any], float] | None = None
    built_in: Callable[[Any], Mapping[str, Any] | None] | None = None
    true_fov_deg: Callable[[Any], tuple[float, float]] | None = None
    lens_distortion: Callable[[Any], tuple[float, bool]] | None = None
    axis_offset_mm: Callable[[Any], float] | None = None
    plate_offset_mm: Callable[[Any], float] | None = None
    blur_px: Callable[[float, Any, float], float] | None = None
    binned: Callable[[Any, int, int], Any] | None = None

    @property
    def _shapes_stage_render(self) -> bool:
        """Whether its parameters change where the rays of a stage step go or what they see (the field of view, a
        lens distortion, the light's depth under the surface)."""
        return self.true_fov_deg is not None or self.lens_distortion is not None or self.subsurface_scale is not None

    @property
    def _moves_plates(self) -> bool:
        """Whether its parameters move the robot's plates relative to the camera."""
        return self.axis_offset_mm is not None or self.plate_offset_mm is not None

    @property
    def changes_stage_render(self) -> bool:
        """Whether the render of a stage step (a target on the wall) changes with the effect's parameters."""
        return self._shapes_stage_render or self.mixes_returns or self.mixed_pixels

    @property
    def changes_render(self) -> bool:
        """Whether the render of a step on the robot's plates changes with the effect's parameters."""
        return self.changes_stage_render or self._moves_plates

    @property
    def render_follows_parameters(self) -> bool:
        """Whether a render the effect changes differs from one value of its parameters to another: not where the
        render only keeps each pixel's correlation phasors for it (``mixes_returns``, ``mixed_pixels``), which its
        parameters act on afterwards."""
        return self._shapes_stage_render or self._moves_plates
