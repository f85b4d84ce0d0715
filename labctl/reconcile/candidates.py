"""Candidate effects and their signatures: what each would change in the simulated output.

A signature is the change of the binned prediction per unit of the effect's
linear parameter, per step, in depth (mm) and in log intensity. Effects that
act after the render have closed-form signatures from the base prediction
(the formulas of their sim/effects modules, linearized where needed); effects
that move the geometry are differentiated by re-simulating with the effect
switched on (finite difference). Nonlinear parameters (a wiggling period, a
drift time constant, a multipath extra path) are searched on a grid, the
linear ones solved for at each grid point.

Not candidates, because the comparison cannot see them:

* ``range_offset``: a constant range error is what the offset calibration and
  the per-group nuisance offsets absorb;
* ``quantization``: it does not move the mean of a noisy stack;
* ``defocus`` and ``flying_pixels``: they act at edges, and bins at edges are
  left out (the slanted-edge evaluation measures sharpness);
* ``fov_error`` and ``radial_distortion`` corrected in the cloud
  (``cloud = false``): the camera's calibration keeps depth and the point
  cloud right, only feature positions in the intensity image move (the
  checkerboard evaluation measures them).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from labctl.reconcile.observe import Observation
from labctl.reconcile.predict import Prediction, Predictor
from labctl.reconcile.residuals import Layout
from sim.materials import get_material
from sim.model import SimModel
from sim.render import C_MM_PER_S
from sim.scenes.targets import PLATE_MATERIALS
from sim.tof import reference_amplitude

Column = tuple[np.ndarray, np.ndarray]  # change of the stacked depth rows and log-intensity rows (Layout order)


@dataclass
class Context:
    """Everything a signature may use: the run's observations and the current model's predictions."""

    observations: list[Observation]
    predictions: list[Prediction]
    model: SimModel
    make_predictor: Callable[[SimModel], Predictor]
    t0_s: float
    lay: Layout
    _stacks: dict[str, np.ndarray] = field(default_factory=dict)

    @property
    def technology(self) -> str:
        return self.model.profile().technology

    def z_rows(self, attr: str) -> np.ndarray:
        """A prediction map stacked over the depth rows (cached)."""
        if attr not in self._stacks:
            self._stacks[attr] = self.lay.stack_z([np.broadcast_to(getattr(p, attr), p.z.shape)
                                                  for p in self.predictions])
        return self._stacks[attr]

    def per_step(self, values: np.ndarray) -> np.ndarray:
        """One value per step spread over that step's depth rows."""
        return np.asarray(values)[self.lay.z_step]

    def no_intensity(self) -> np.ndarray:
        return np.zeros(len(self.lay.i_step))

    def finite_difference(self, name: str, params: dict[str, Any], step_filter: Callable[[Observation], bool],
                          scale: float) -> Column:
        """(prediction with the effect switched on - current prediction) / ``scale``, on the steps it touches."""
        effects = {**self.model.effects, name: params}
        predictor = self.make_predictor(self.model.model_copy(update={"effects": effects}))
        dz, di = [np.zeros_like(p.z) for p in self.predictions], [np.zeros_like(p.z) for p in self.predictions]
        for s, (obs, base) in enumerate(zip(self.observations, self.predictions, strict=True)):
            if not step_filter(obs):
                continue
            p = predictor.predict(obs.scene, obs.times_s - self.t0_s)
            dz[s] = np.nan_to_num((p.z - base.z) / scale)
            with np.errstate(invalid="ignore", divide="ignore"):
                di[s] = np.nan_to_num((np.log(p.intensity) - np.log(base.intensity)) / scale)
        return self.lay.stack_z(dz), self.lay.stack_i(di)


@dataclass(frozen=True)
class Candidate:
    """One effect of the library as the reconcile workflow tests it."""

    name: str
    technologies: tuple[str, ...]
    n_params: int  # free parameters (linear and nonlinear), for the BIC penalty
    grid: Callable[[Context], list[float | None]]
    columns: Callable[[Context, float | None], list[Column]]
    to_params: Callable[[Context, np.ndarray, float | None], dict[str, Any] | None]
    vector: Callable[[dict[str, Any]], tuple[np.ndarray, tuple[np.ndarray, np.ndarray]]]
    from_vector: Callable[[np.ndarray], dict[str, Any]]
    applies: Callable[[Context], bool] = field(default=lambda ctx: True)


def _none(_: Context) -> list[float | None]:
    return [None]


def _depth(ctx: Context, rows: np.ndarray) -> Column:
    return np.nan_to_num(rows), ctx.no_intensity()


# range_scale: r' = r (1 + scale)  ->  dz = z per unit scale
def _scale_columns(ctx: Context, _: float | None) -> list[Column]:
    return [_depth(ctx, ctx.z_rows("z"))]


RANGE_SCALE = Candidate(
    "range_scale", ("tof", "stereo"), 1, _none, _scale_columns,
    lambda ctx, c, _: {"scale": float(c[0])} if abs(c[0]) <= 0.1 else None,
    lambda p: (np.array([p["scale"]]), (np.array([-0.1]), np.array([0.1]))),
    lambda x: {"scale": float(x[0])},
)


# wiggling: dr = a sin(2 pi r / P) + b cos(2 pi r / P); the period searched between 3 sweep steps and the range span
def _range_span(ctx: Context) -> tuple[float, float]:
    ranges = np.concatenate([p.range_mm[np.isfinite(p.range_mm)] for p in ctx.predictions])
    return float(ranges.min()), float(ranges.max())


def _wiggling_grid(ctx: Context) -> list[float | None]:
    lo, hi = _range_span(ctx)
    return list(np.geomspace(150.0, max(hi - lo, 300.0), 90))


def _wiggling_columns(ctx: Context, period: float | None) -> list[Column]:
    phase = 2 * math.pi / float(period) * ctx.z_rows("range_mm")
    ratio = ctx.z_rows("z_per_range")
    return [_depth(ctx, np.sin(phase) * ratio), _depth(ctx, np.cos(phase) * ratio)]


def _wiggling_params(ctx: Context, c: np.ndarray, period: float | None) -> dict[str, Any] | None:
    amplitude = float(np.hypot(c[0], c[1]))
    return {"amplitude_mm": amplitude, "period_mm": float(period), "phase_rad": float(math.atan2(c[1], c[0]))} \
        if amplitude <= 100.0 else None


WIGGLING = Candidate(
    "wiggling", ("tof",), 3, _wiggling_grid, _wiggling_columns, _wiggling_params,
    lambda p: (np.array([p["amplitude_mm"], p["period_mm"], p["phase_rad"]]),
               (np.array([0.0, 10.0, -4 * math.pi]), np.array([100.0, 20000.0, 4 * math.pi]))),
    lambda x: {"amplitude_mm": float(x[0]), "period_mm": float(x[1]),
               "phase_rad": float((x[2] + math.pi) % (2 * math.pi) - math.pi)},
)


# temperature_drift: dr = delta exp(-t / tau), t since the run's first frame
def _drift_grid(_: Context) -> list[float | None]:
    return list(np.geomspace(10.0, 86400.0, 48))


def _drift_columns(ctx: Context, tau: float | None) -> list[Column]:
    factor = [float(np.mean(np.exp(-(o.times_s - ctx.t0_s) / float(tau)))) if len(o.times_s) else 0.0
              for o in ctx.observations]
    return [_depth(ctx, ctx.per_step(factor) * ctx.z_rows("z_per_range"))]


TEMPERATURE_DRIFT = Candidate(
    "temperature_drift", ("tof", "stereo"), 2, _drift_grid, _drift_columns,
    lambda ctx, c, tau: {"delta_mm": float(c[0]), "tau_s": float(tau)} if abs(c[0]) <= 100.0 else None,
    lambda p: (np.array([p["delta_mm"], math.log(p["tau_s"])]),
               (np.array([-100.0, math.log(1.0)]), np.array([100.0, math.log(86400.0)]))),
    lambda x: {"delta_mm": float(x[0]), "tau_s": float(math.exp(x[1]))},
)


# intensity_related_error: dr = e A_ref / A (light before vignetting)
def _ire_columns(ctx: Context, _: float | None) -> list[Column]:
    a_ref = reference_amplitude(ctx.model.profile())
    light = ctx.z_rows("light")
    with np.errstate(divide="ignore", invalid="ignore"):
        return [_depth(ctx, np.where(light > 0, a_ref / light, 0.0) * ctx.z_rows("z_per_range"))]


INTENSITY_RELATED_ERROR = Candidate(
    "intensity_related_error", ("tof",), 1, _none, _ire_columns,
    lambda ctx, c, _: {"error_at_reference_mm": float(c[0])} if abs(c[0]) <= 50.0 else None,
    lambda p: (np.array([p["error_at_reference_mm"]]), (np.array([-50.0]), np.array([50.0]))),
    lambda x: {"error_at_reference_mm": float(x[0])},
)


# vignetting: ln A' = ln A + exponent ln cos(alpha)
def _vignetting_columns(ctx: Context, _: float | None) -> list[Column]:
    log_cos = ctx.lay.stack_i([np.broadcast_to(np.log(p.cos_alpha), p.z.shape) for p in ctx.predictions])
    return [(np.zeros(len(ctx.lay.z_step)), log_cos)]


VIGNETTING = Candidate(
    "vignetting", ("tof", "stereo"), 1, _none, _vignetting_columns,
    lambda ctx, c, _: {"exponent": float(c[0])} if 0.0 <= c[0] <= 20.0 else None,
    lambda p: (np.array([p["exponent"]]), (np.array([0.0]), np.array([20.0]))),
    lambda x: {"exponent": float(x[0])},
)


# multipath: dr ~ s Im(M e^{jkL} / (A e^{jkr})) / k for a small strength s (M: mean phasor of the image)
def _wavenumber(ctx: Context) -> float:
    return 4 * math.pi * ctx.model.profile().modulation_mhz * 1e6 / C_MM_PER_S


def _multipath_grid(ctx: Context) -> list[float | None]:
    period = 2 * math.pi / _wavenumber(ctx)
    return list(np.linspace(period / 36, period, 36))


def _multipath_columns(ctx: Context, extra_path: float | None) -> list[Column]:
    k = _wavenumber(ctx)
    mean = ctx.per_step(np.array([p.phasor_mean for p in ctx.predictions]))
    amplitude = ctx.z_rows("intensity")
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = mean * np.exp(1j * k * (float(extra_path) - np.nan_to_num(ctx.z_rows("range_dom")))) / amplitude
    return [_depth(ctx, np.where(amplitude > 0, ratio.imag / k, 0.0) * ctx.z_rows("z_per_range"))]


def _multipath_params(ctx: Context, c: np.ndarray, extra_path: float | None) -> dict[str, Any] | None:
    strength, path = float(c[0]), float(extra_path)
    if strength < 0:  # -s e^{jkL} = s e^{jk(L + period / 2)}
        period = 2 * math.pi / _wavenumber(ctx)
        strength, path = -strength, (path + period / 2) % period or period
    return {"strength": strength, "extra_path_mm": path} if strength <= 1.0 else None


MULTIPATH = Candidate(
    "multipath", ("tof",), 2, _multipath_grid, _multipath_columns, _multipath_params,
    lambda p: (np.array([p["strength"], p["extra_path_mm"]]), (np.array([0.0, 1.0]), np.array([1.0, 10000.0]))),
    lambda x: {"strength": float(x[0]), "extra_path_mm": float(x[1])},
)


# material_bias: translucent materials read scale x their sub-surface bias long (re-simulated)
def _translucent(o: Observation) -> bool:
    material = o.scene.target if o.scene.target in PLATE_MATERIALS else None
    names = [material] if material else {"boehler_star": ["ptfe"], "face_mask": ["silicone"]}.get(o.scene.target, [])
    return any(get_material(n).subsurface_bias_mm != 0 for n in names)


MATERIAL_BIAS = Candidate(
    "material_bias", ("tof",), 1, _none,
    lambda ctx, _: [ctx.finite_difference("material_bias", {"scale": 1.0}, _translucent, 1.0)],
    lambda ctx, c, _: {"scale": float(c[0])} if 0.0 <= c[0] <= 10.0 else None,
    lambda p: (np.array([p["scale"]]), (np.array([0.0]), np.array([10.0]))),
    lambda x: {"scale": float(x[0])},
    applies=lambda ctx: any(_translucent(o) for o in ctx.observations),
)


def _on_robot(o: Observation) -> bool:
    return o.scene.target in PLATE_MATERIALS


def _offset_candidate(name: str) -> Candidate:
    step = 10.0
    return Candidate(
        name, ("tof", "stereo"), 1, _none,
        lambda ctx, _: [ctx.finite_difference(name, {"offset_mm": step}, _on_robot, step)],
        lambda ctx, c, _: {"offset_mm": float(c[0])} if abs(c[0]) <= 200.0 else None,
        lambda p: (np.array([p["offset_mm"]]), (np.array([-200.0]), np.array([200.0]))),
        lambda x: {"offset_mm": float(x[0])},
        applies=lambda ctx: sum(_on_robot(o) for o in ctx.observations) >= 3,
    )


TARGET_MISALIGNMENT = _offset_candidate("target_misalignment")
CAMERA_AXIS_OFFSET = _offset_candidate("camera_axis_offset")

# radial_distortion left in the point cloud: the rays the camera reports are not the ones it sees
RADIAL_DISTORTION = Candidate(
    "radial_distortion", ("tof", "stereo"), 1, _none,
    lambda ctx, _: [ctx.finite_difference("radial_distortion", {"k1": 0.02, "cloud": True}, lambda o: True, 0.02)],
    lambda ctx, c, _: {"k1": float(c[0]), "cloud": True} if abs(c[0]) <= 0.5 else None,
    lambda p: (np.array([p["k1"]]), (np.array([-0.5]), np.array([0.5]))),
    lambda x: {"k1": float(x[0]), "cloud": True},
)

CANDIDATES = (RANGE_SCALE, WIGGLING, TEMPERATURE_DRIFT, INTENSITY_RELATED_ERROR, VIGNETTING, MULTIPATH,
              MATERIAL_BIAS, TARGET_MISALIGNMENT, CAMERA_AXIS_OFFSET, RADIAL_DISTORTION)
NOT_IDENTIFIABLE = {
    "range_offset": "absorbed by the offset calibration and the per-group offsets",
    "quantization": "does not move the mean of a noisy stack",
    "defocus": "acts at edges, which the comparison leaves out (see the slanted-edge evaluation)",
    "flying_pixels": "acts at depth edges, which the comparison leaves out",
    "fov_error": "the camera's calibration keeps depth and the cloud right (see the checkerboard evaluation)",
}


def candidates_for(ctx: Context) -> Iterator[Candidate]:
    """The candidates that apply to this run and are not yet in the model."""
    for c in CANDIDATES:
        if ctx.technology in c.technologies and c.name not in ctx.model.effects and c.applies(ctx):
            yield c
