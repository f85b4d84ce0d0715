"""Measurement minus simulation on the binned grid, with the lab's unknowns profiled out.

Two families of residuals of the bin means, each over the bins where the
comparison is sound (the measured bin is valid in at least
``MIN_VALID_FRACTION`` of its pixels, the simulated bin has no depth or
reflectance edge):

* depth: z_measured - z_simulated, weighted by 1 / (var + ``Z_FLOOR_MM``^2)
  with var the bin mean's variance estimated from the stack itself;
* intensity: ln I_measured - ln I_simulated, weighted by
  1 / (var / I^2 + ``LOG_I_FLOOR``^2) (``LOG_I_FLOOR_PROJECTOR`` for stereo
  steps with the dot projector on: the binned simulation spreads the dots
  by the in-focus lens only, so bins differ by a few % at close range).

What a lab does not know exactly and every reconcile must allow for is
profiled out by weighted least squares (nuisance parameters): one depth
offset per reference group (laser-referenced, stage-nominal and robot steps:
the camera's mounting offset, the laser offset, a constant range offset), the
wall's tilt against the stage axis (z proportional to the ray slopes on
stage-lab steps), and one intensity gain per step (exposure, remission and
illumination power are not known in absolute terms). Candidate effect
signatures are profiled the same way, so that an effect is credited only
with what the nuisance cannot explain.

Three families of the noise's statistics (``STATISTICS``), over the bins away
from depth and reflectance edges where both the run and the model give them
(labctl/reconcile/observe.py, labctl/reconcile/noise_model.py), with no
nuisance, each weighted by 1 / (its sampling variance + its floor^2):

* noise: ln(s_measured) - ln(sigma_model) - E, s the bin's pooled temporal std
  on nu = m (n - 1) / max(1, c) degrees of freedom (c the local correlation
  ratio), E = (psi(nu / 2) + ln(2 / nu)) / 2 the mean of ln s / sigma for a
  chi-square variance; sampling variance psi'(nu / 2) / 4 (psi: digamma),
  plus the model's own spread of ln sigma (``Prediction.noise_log_spread``);
* validity: the fraction of valid pixel-frames measured minus predicted;
  sampling variance p (1 - p) / N (binomial over the bin's N = b^2 n
  pixel-frames, p the model's) plus the model's own uncertainty of p
  (``Prediction.valid_spread``: stereo pixels at the texture threshold);
* correlation: ln(c_measured) - ln(c_model) - E_c, E_c = psi((n - 1) / 2) +
  ln(2 / (n - 1)) - psi(nu / 2) - ln(2 / nu) (the ratio of two chi-square
  variances, n - 1 and nu degrees of freedom); sampling variance
  psi'((n - 1) / 2) + psi'(nu / 2).

The floors of the bin-mean families are the simulator's own disagreement with
itself on the bin grid (bin means of a full-resolution simulation against the
binned simulation, ``bench/reconcile_null.py``); those of the statistics'
families (``STAT_FLOORS``) what the binned noise law leaves out (the amplitude
at the bin centre for the mean over its pixels, the lens blur, the output
step's rounding), checked on simulated runs with nothing hidden.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np
from scipy import ndimage, special

from labctl.reconcile.observe import Observation
from labctl.reconcile.predict import Prediction

MIN_VALID_FRACTION = 0.9  # set by hand: a bin compared only when nine tenths of its pixels are valid
Z_FLOOR_MM = 0.02  # the binned simulation against the full-resolution one, set on the test campaign (docs/reconcile.md)
LOG_I_FLOOR = 0.002  # the same for log intensity (0.2 %), set on the test campaign
LOG_I_FLOOR_PROJECTOR = 0.03  # stereo with the dot projector: the binned dot pattern is approximate
GROUPS = ("laser", "stage", "robot")
EDGE_JUMP = 0.05  # set by hand: a relative jump of the measured depth between neighbouring bins that marks an edge
STATISTICS = ("noise", "validity", "correlation")
FAMILIES = ("depth", "intensity", *STATISTICS)
STAT_FLOORS = {"noise": 0.03, "validity": 0.02, "correlation": 0.05}  # ln std, valid fraction, ln ratio
#: the largest ln ratio of a measured to a predicted quantity (intensity, noise, correlation) a row counts with. A
#: model a fit tries can leave a compared bin dark or noiseless (a target moved off the bin's rays; before a ToF
#: bin's means continued beyond the camera's range, also a strong multipath moving bins out of it): the ratio is
#: then infinite, and an infinite row turns its step's profiled rows and the fit's sum of squares into NaN and
#: overflow. Capped, such a model is still e^50
#: off there, beyond any camera's range (a 16-bit amplitude spans e^11), and the solver rejects it as the poor fit
#: it is.
MAX_LOG_RATIO = 50.0


@dataclass
class Layout:
    """Where each step's usable bins sit in the stacked residual vectors."""

    z_masks: list[np.ndarray]
    i_masks: list[np.ndarray]
    z_step: np.ndarray  # step number of every depth row
    i_step: np.ndarray  # step number of every intensity row
    z_nuisance: np.ndarray  # (rows, parameters) design of the depth nuisance
    z_weight: np.ndarray
    i_weight: np.ndarray
    s_masks: dict[str, list[np.ndarray]] = field(default_factory=dict)  # per statistics family (``STATISTICS``)
    s_step: dict[str, np.ndarray] = field(default_factory=dict)
    s_weight: dict[str, np.ndarray] = field(default_factory=dict)
    #: each step's reference variance of its own (mm^2, ``StepScene.reference_uncertainty_mm``), shared by its bins
    reference_var: np.ndarray = field(default_factory=lambda: np.zeros(0))

    @property
    def n_steps(self) -> int:
        return len(self.z_masks)

    @property
    def n_cells(self) -> int:
        """(step, family) cells of ``row_cells``."""
        return len(FAMILIES) * self.n_steps

    def stack_family(self, family: str, maps: list[np.ndarray]) -> np.ndarray:
        """One statistics family's per-step maps stacked over its rows."""
        masks = self.s_masks.get(family, [])
        return np.concatenate([m[k] for m, k in zip(maps, masks, strict=True)]) if masks else np.zeros(0)

    def stack_statistics(self, maps: dict[str, list[np.ndarray]] | None) -> np.ndarray:
        """The statistics families' maps stacked in ``STATISTICS`` order (zeros for a family not given)."""
        maps = maps or {}
        return np.concatenate([self.stack_family(f, maps[f]) if f in maps else np.zeros(len(self.s_step.get(f, [])))
                               for f in STATISTICS])

    @cached_property
    def _whitening(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """sqrt of the weights of the depth, intensity and statistics rows (``profiled_rows``)."""
        s_weight = np.concatenate([self.s_weight.get(f, np.zeros(0)) for f in STATISTICS])
        return np.sqrt(self.z_weight), np.sqrt(self.i_weight), np.sqrt(s_weight)

    @cached_property
    def _i_weight_sums(self) -> np.ndarray:
        """Each step's sum of its intensity rows' weights (``profile_i``)."""
        return np.maximum(np.bincount(self.i_step, self.i_weight, self.n_steps), 1e-300)

    def stack_z(self, maps: list[np.ndarray]) -> np.ndarray:
        return np.concatenate([m[k] for m, k in zip(maps, self.z_masks, strict=True)]) if maps else np.zeros(0)

    def stack_i(self, maps: list[np.ndarray]) -> np.ndarray:
        return np.concatenate([m[k] for m, k in zip(maps, self.i_masks, strict=True)]) if maps else np.zeros(0)

    @cached_property
    def _z_projector(self) -> tuple[np.ndarray, np.ndarray]:
        xw = self.z_nuisance * self.z_weight[:, None]
        return xw, np.linalg.pinv(self.z_nuisance.T @ xw)

    def family_masks(self, family: str) -> list[np.ndarray]:
        """The per-step masks of the bins ``family`` (``FAMILIES``) compares."""
        if family == "depth":
            return self.z_masks
        if family == "intensity":
            return self.i_masks
        return self.s_masks.get(family, [])

    @staticmethod
    def unstack(rows: np.ndarray, masks: list[np.ndarray]) -> list[np.ndarray]:
        """Stacked rows back into per-step maps over ``masks`` (NaN outside them)."""
        maps, start = [], 0
        for mask in masks:
            m = np.full(mask.shape, np.nan)
            n = int(mask.sum())
            m[mask] = rows[start:start + n]
            maps.append(m)
            start += n
        return maps

    def profile_z(self, v: np.ndarray) -> np.ndarray:
        """``v`` minus its weighted least-squares fit by the depth nuisance (Frisch-Waugh-Lovell). A NaN row (a
        trial model that predicts no depth at a compared bin) is left out of the fit and stays NaN: in the sums it
        would make every row NaN, and the caller's NaN-to-zero would then read the whole depth family as fitted."""
        if not len(v):
            return v
        xw, inverse = self._z_projector
        missing = np.isnan(v)
        if not missing.any():
            return v - self.z_nuisance @ (inverse @ (xw.T @ v))
        xw = np.where(missing[:, None], 0.0, xw)
        kept = np.where(missing, 0.0, v)
        out = kept - self.z_nuisance @ (np.linalg.pinv(self.z_nuisance.T @ xw) @ (xw.T @ kept))
        out[missing] = np.nan
        return out

    def profiled_depth(self, z_rows: np.ndarray) -> np.ndarray:
        """The depth rows of ``profiled_rows`` for stacked depth rows alone: what a signature that leaves the
        intensity and the statistics alone has on the depth rows, the other rows of ``profiled_rows`` being zero."""
        return self.profile_z(z_rows) * self._whitening[0]

    def profile_i(self, v: np.ndarray) -> np.ndarray:
        """``v`` minus its weighted mean per step (each step's unknown gain); rows that are all zero (a signature
        that leaves the intensity alone) are returned as they are, without the per-step sums (zero minus zero)."""
        if not v.any():
            return v
        mean = np.bincount(self.i_step, self.i_weight * v, self.n_steps) / self._i_weight_sums
        return v - mean[self.i_step]

    def profiled(self, dz: list[np.ndarray], di: list[np.ndarray],
                 stats: dict[str, list[np.ndarray]] | None = None) -> np.ndarray:
        """Per-step maps of every family stacked, nuisance profiled out and whitened (sqrt weight); the
        statistics families' rows (``stats``, ``raw_statistics``) are zero when not given."""
        return self.profiled_rows(self.stack_z(dz), self.stack_i(di), self.stack_statistics(stats))

    def profiled_rows(self, z_rows: np.ndarray, i_rows: np.ndarray, s_rows: np.ndarray | None = None) -> np.ndarray:
        """Stacked depth, intensity and statistics rows (``stack_statistics``; zero when not given) with the
        nuisance profiled out, whitened (sqrt weight)."""
        s_rows = np.zeros(len(self._whitening[2])) if s_rows is None else s_rows
        return self.whitened(self.profile_z(z_rows), self.profile_i(i_rows), s_rows)

    def whitened(self, z_rows: np.ndarray, i_rows: np.ndarray, s_rows: np.ndarray) -> np.ndarray:
        """Stacked depth, intensity and statistics rows with the nuisance already profiled out, whitened as
        ``profiled_rows`` whitens them (sqrt weight)."""
        z_root, i_root, s_root = self._whitening
        return np.concatenate([z_rows * z_root, i_rows * i_root, s_rows * s_root])

    def shared_nuisance(self) -> np.ndarray:
        """The whitened design of the nuisance that steps share (the depth offset of each reference group, the wall's
        tilt) over every row of ``profiled``, zero on the rows it does not touch, its unused columns left out. The
        per-step intensity gains are not in it: each belongs to one step, so leaving a step out takes its gain with
        it and the profiled rows already are what the other steps see."""
        design = np.zeros((len(self.row_steps()), self.z_nuisance.shape[1]))
        design[:len(self.z_step)] = self.z_nuisance * self._whitening[0][:, None]
        return design[:, np.any(design != 0, axis=0)]

    def reference_directions(self) -> list[tuple[float, np.ndarray]]:
        """Per step with a reference uncertainty of its own (``reference_var``): that variance and the whitened
        rows (over every row of ``profiled``) an error of 1 mm in the step's reference moves, its depth rows by
        sqrt(weight) (the wall moves with its reference; the nuisance profiled out of the Jacobian the rows are
        taken against, Frisch-Waugh-Lovell)."""
        out = []
        n_rows = len(self.row_steps())
        for s in np.flatnonzero(self.reference_var > 0) if len(self.reference_var) == self.n_steps else ():
            rows = np.zeros(n_rows)
            on = self.z_step == s
            rows[:len(self.z_step)][on] = self._whitening[0][on]
            out.append((float(self.reference_var[s]), rows))
        return out

    def row_steps(self) -> np.ndarray:
        """Step number of every row of ``profiled``."""
        return np.concatenate([self.z_step, self.i_step, *(self.s_step.get(f, np.zeros(0, int)) for f in STATISTICS)])

    def family_rows(self) -> list[slice]:
        """The rows of ``profiled`` of each family, in ``FAMILIES`` order (each family's rows are contiguous)."""
        sizes = [len(self.z_step), len(self.i_step), *(len(self.s_step.get(f, ())) for f in STATISTICS)]
        edges = np.cumsum([0, *sizes])
        return [slice(int(a), int(b)) for a, b in zip(edges[:-1], edges[1:], strict=True)]

    def row_cells(self) -> np.ndarray:
        """(step, family) cell of every row of ``profiled``: F s + f, f the family's place in ``FAMILIES``."""
        f = len(FAMILIES)
        return np.concatenate([f * self.z_step, f * self.i_step + 1,
                               *(f * self.s_step.get(name, np.zeros(0, int)) + 2 + k
                                 for k, name in enumerate(STATISTICS))]).astype(int)


def _uniform_light(pred: Prediction) -> np.ndarray:
    """Bins whose simulated intensity is smooth (no texture edge inside the bin or next to it)."""
    return ~pred.edge & np.isfinite(pred.intensity) & (pred.intensity > 0)


def measured_edges(z: np.ndarray, invalid_is_edge: bool = True) -> np.ndarray:
    """Bins next to a jump of the measured depth (more than ``EDGE_JUMP`` relative, or, with
    ``invalid_is_edge``, an invalid bin).

    Where a depth edge sits in the measurement is itself uncertain (a target
    misplaced by the effect being sought moves its outline), so bins at the
    measured edges are left out as well as those at the simulated ones.
    """
    padded = np.pad(z, 1, constant_values=np.nan)
    centre = padded[1:-1, 1:-1]
    jump = np.zeros(z.shape, dtype=bool)
    for dy, dx in ((0, 1), (2, 1), (1, 0), (1, 2)):
        neighbour = padded[dy:dy + z.shape[0], dx:dx + z.shape[1]]
        with np.errstate(invalid="ignore"):
            step = np.abs(neighbour - centre) > EDGE_JUMP * np.abs(centre)
            jump |= ~(np.abs(neighbour - centre) <= EDGE_JUMP * np.abs(centre)) if invalid_is_edge else step
    return ndimage.binary_dilation(jump)


def step_rows(steps: np.ndarray, n_steps: int) -> list[np.ndarray]:
    """The indices of each step's rows (steps 0 .. ``n_steps`` - 1 of ``steps``), ascending within a step: one
    stable sort instead of one pass over all rows per step."""
    order = np.argsort(steps, kind="stable")
    return np.split(order, np.searchsorted(steps[order], np.arange(1, n_steps)))


def layout(observations: list[Observation], predictions: list[Prediction], technology: str = "tof") -> Layout:
    """Usable bins, weights and nuisance design for a run (the masks fixed by the base model)."""
    z_masks, i_masks, z_step, i_step, rows, zw, iw, reference_var = [], [], [], [], [], [], [], []
    for s, (obs, pred) in enumerate(zip(observations, predictions, strict=True)):
        ok = (np.isfinite(obs.z) & np.isfinite(obs.z_var) & (obs.valid_fraction >= MIN_VALID_FRACTION)
              & ~pred.edge & ~measured_edges(obs.z) & np.isfinite(pred.z) & pred.reported)
        iok = (ok & _uniform_light(pred) & np.isfinite(obs.intensity) & (obs.intensity > 0)
               & np.isfinite(obs.intensity_var))
        z_masks.append(ok)
        i_masks.append(iok)
        z_step.append(np.full(int(ok.sum()), s))
        i_step.append(np.full(int(iok.sum()), s))
        zw.append(1.0 / (obs.z_var[ok] + Z_FLOOR_MM**2))
        floor = LOG_I_FLOOR_PROJECTOR if technology == "stereo" and obs.scene.projector else LOG_I_FLOOR
        iw.append(1.0 / (obs.intensity_var[iok] / obs.intensity[iok] ** 2 + floor**2))
        reference_var.append(obs.scene.reference_uncertainty_mm**2)
        design = np.zeros((int(ok.sum()), len(GROUPS) + 2))
        design[:, GROUPS.index(obs.scene.reference)] = 1.0
        if obs.scene.reference != "robot":  # the wall's tilt: z grows along the ray slopes
            h, w = ok.shape
            tx = np.broadcast_to((np.arange(w) - (w - 1) / 2) / w, (h, w))
            ty = np.broadcast_to(((np.arange(h) - (h - 1) / 2) / w)[:, None], (h, w))
            design[:, 3] = (pred.z * tx)[ok]
            design[:, 4] = (pred.z * ty)[ok]
        rows.append(design)
    used = [x for x in rows if len(x)]
    s_masks, s_step, s_weight = _statistics_layout(observations, predictions)
    return Layout(z_masks, i_masks,
                  np.concatenate(z_step).astype(int) if z_step else np.zeros(0, int),
                  np.concatenate(i_step).astype(int) if i_step else np.zeros(0, int),
                  np.concatenate(used) if used else np.zeros((0, len(GROUPS) + 2)),
                  np.concatenate(zw) if zw else np.zeros(0), np.concatenate(iw) if iw else np.zeros(0),
                  s_masks, s_step, s_weight, np.array(reference_var, dtype=float))


def statistics_masks(obs: Observation, pred: Prediction) -> dict[str, np.ndarray]:
    """The bins each statistics family compares on one step (away from simulated and measured depth edges)."""
    away = ~pred.edge & ~measured_edges(obs.z, invalid_is_edge=False)
    noise = away & np.isfinite(obs.noise_mm) & np.isfinite(pred.noise_mm) & (pred.noise_mm > 0)
    seen = (pred.valid_rate > 0) | (obs.valid_rate > 0)
    return {"noise": noise, "validity": away & seen & np.isfinite(pred.valid_rate),
            "correlation": noise & np.isfinite(obs.correlation) & (obs.correlation > 0)
            & np.isfinite(pred.correlation)}


def sampling_variance(obs: Observation, pred: Prediction) -> dict[str, np.ndarray]:
    """Per bin, the sampling variance of each statistics family's residual (module docstring)."""
    nu = np.maximum(obs.noise_dof, 1.0)
    frames = max(obs.n_frames - 1, 1)
    p = np.clip(pred.valid_rate, 0.0, 1.0)
    return {"noise": special.polygamma(1, nu / 2) / 4 + np.nan_to_num(pred.noise_log_spread) ** 2,
            "validity": p * (1 - p) / obs.pixel_frames + pred.valid_spread**2,
            "correlation": special.polygamma(1, frames / 2) + special.polygamma(1, nu / 2)}


def _statistics_layout(observations: list[Observation], predictions: list[Prediction]):
    masks: dict[str, list[np.ndarray]] = {f: [] for f in STATISTICS}
    steps: dict[str, list[np.ndarray]] = {f: [] for f in STATISTICS}
    weights: dict[str, list[np.ndarray]] = {f: [] for f in STATISTICS}
    for s, (obs, pred) in enumerate(zip(observations, predictions, strict=True)):
        ok, var = statistics_masks(obs, pred), sampling_variance(obs, pred)
        for f in STATISTICS:
            masks[f].append(ok[f])
            steps[f].append(np.full(int(ok[f].sum()), s))
            weights[f].append(1.0 / (var[f][ok[f]] + STAT_FLOORS[f] ** 2))
    return (masks, {f: np.concatenate(steps[f]).astype(int) if steps[f] else np.zeros(0, int) for f in STATISTICS},
            {f: np.concatenate(weights[f]) if weights[f] else np.zeros(0) for f in STATISTICS})


def raw_statistics(observations: list[Observation], predictions: list[Prediction]) -> dict[str, list[np.ndarray]]:
    """Per-step maps of the statistics families (module docstring): noise and correlation as bias-corrected
    log ratios of measured to model, validity as the difference of the valid fractions."""
    out: dict[str, list[np.ndarray]] = {f: [] for f in STATISTICS}
    for obs, pred in zip(observations, predictions, strict=True):
        nu = np.maximum(obs.noise_dof, 1.0)
        frames = max(obs.n_frames - 1, 1)
        mean_log_var = special.digamma(nu / 2) + np.log(2 / nu)  # E ln(chi2_nu / nu)
        with np.errstate(invalid="ignore", divide="ignore"):
            out["noise"].append(_capped(np.log(obs.noise_mm / pred.noise_mm)) - mean_log_var / 2)
            out["correlation"].append(_capped(np.log(obs.correlation / pred.correlation))
                                      - (special.digamma(frames / 2) + math.log(2 / frames) - mean_log_var))
        out["validity"].append(obs.valid_rate - pred.valid_rate)
    return out


def raw_residuals(observations: list[Observation], predictions: list[Prediction]) -> tuple[list, list]:
    """Per-step maps: z_measured - z_simulated and ln I_measured - ln I_simulated (within +-``MAX_LOG_RATIO``)."""
    dz, di = [], []
    for obs, pred in zip(observations, predictions, strict=True):
        dz.append(obs.z - pred.z)
        with np.errstate(invalid="ignore", divide="ignore"):
            di.append(_capped(np.log(obs.intensity) - np.log(pred.intensity)))
    return dz, di


def _capped(log_ratio: np.ndarray) -> np.ndarray:
    """``log_ratio`` within +-``MAX_LOG_RATIO`` (NaN stays NaN: a bin with nothing to compare)."""
    return np.clip(log_ratio, -MAX_LOG_RATIO, MAX_LOG_RATIO)
