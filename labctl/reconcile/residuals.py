"""Measurement minus simulation on the binned grid, with the lab's unknowns profiled out.

Two families of residuals, each over the bins where the comparison is sound
(the measured bin is valid in at least ``MIN_VALID_FRACTION`` of its pixels,
the simulated bin has no depth or reflectance edge):

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

The floors are the simulator's own disagreement with itself on the bin grid
(bin means of a full-resolution simulation against the binned simulation,
``bench/reconcile_null.py``).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np
from scipy import ndimage

from labctl.reconcile.observe import Observation
from labctl.reconcile.predict import Prediction

MIN_VALID_FRACTION = 0.9  # set by hand: a bin compared only when nine tenths of its pixels are valid
Z_FLOOR_MM = 0.02  # the binned simulation against the full-resolution one, set on the test campaign (docs/reconcile.md)
LOG_I_FLOOR = 0.002  # the same for log intensity (0.2 %), set on the test campaign
LOG_I_FLOOR_PROJECTOR = 0.03  # stereo with the dot projector: the binned dot pattern is approximate
GROUPS = ("laser", "stage", "robot")
EDGE_JUMP = 0.05  # set by hand: a relative jump of the measured depth between neighbouring bins that marks an edge


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

    @property
    def n_steps(self) -> int:
        return len(self.z_masks)

    def stack_z(self, maps: list[np.ndarray]) -> np.ndarray:
        return np.concatenate([m[k] for m, k in zip(maps, self.z_masks, strict=True)]) if maps else np.zeros(0)

    def stack_i(self, maps: list[np.ndarray]) -> np.ndarray:
        return np.concatenate([m[k] for m, k in zip(maps, self.i_masks, strict=True)]) if maps else np.zeros(0)

    @cached_property
    def _z_projector(self) -> tuple[np.ndarray, np.ndarray]:
        xw = self.z_nuisance * self.z_weight[:, None]
        return xw, np.linalg.pinv(self.z_nuisance.T @ xw)

    def profile_z(self, v: np.ndarray) -> np.ndarray:
        """``v`` minus its weighted least-squares fit by the depth nuisance (Frisch-Waugh-Lovell)."""
        if not len(v):
            return v
        xw, inverse = self._z_projector
        return v - self.z_nuisance @ (inverse @ (xw.T @ v))

    def profile_i(self, v: np.ndarray) -> np.ndarray:
        """``v`` minus its weighted mean per step (each step's unknown gain)."""
        if not len(v):
            return v
        n = self.n_steps
        wsum = np.bincount(self.i_step, self.i_weight, n)
        mean = np.bincount(self.i_step, self.i_weight * v, n) / np.maximum(wsum, 1e-300)
        return v - mean[self.i_step]

    def profiled(self, dz: list[np.ndarray], di: list[np.ndarray]) -> np.ndarray:
        """Per-step maps of both families stacked, nuisance profiled out and whitened (sqrt weight)."""
        return self.profiled_rows(self.stack_z(dz), self.stack_i(di))

    def profiled_rows(self, z_rows: np.ndarray, i_rows: np.ndarray) -> np.ndarray:
        """Stacked depth and intensity rows with the nuisance profiled out, whitened (sqrt weight)."""
        return np.concatenate([self.profile_z(z_rows) * np.sqrt(self.z_weight),
                               self.profile_i(i_rows) * np.sqrt(self.i_weight)])

    def row_steps(self) -> np.ndarray:
        """Step number of every row of ``profiled``."""
        return np.concatenate([self.z_step, self.i_step])

    def row_cells(self) -> np.ndarray:
        """(step, family) cell of every row of ``profiled``: 2 s for depth, 2 s + 1 for intensity."""
        return np.concatenate([2 * self.z_step, 2 * self.i_step + 1])


def _uniform_light(pred: Prediction) -> np.ndarray:
    """Bins whose simulated intensity is smooth (no texture edge inside the bin or next to it)."""
    return ~pred.edge & np.isfinite(pred.intensity) & (pred.intensity > 0)


def measured_edges(z: np.ndarray) -> np.ndarray:
    """Bins next to a jump of the measured depth (more than ``EDGE_JUMP`` relative, or an invalid bin).

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
            jump |= ~(np.abs(neighbour - centre) <= EDGE_JUMP * np.abs(centre))
    return ndimage.binary_dilation(jump)


def layout(observations: list[Observation], predictions: list[Prediction], technology: str = "tof") -> Layout:
    """Usable bins, weights and nuisance design for a run (the masks fixed by the base model)."""
    z_masks, i_masks, z_step, i_step, rows, zw, iw = [], [], [], [], [], [], []
    for s, (obs, pred) in enumerate(zip(observations, predictions, strict=True)):
        ok = (np.isfinite(obs.z) & np.isfinite(obs.z_var) & (obs.valid_fraction >= MIN_VALID_FRACTION)
              & ~pred.edge & ~measured_edges(obs.z) & np.isfinite(pred.z))
        iok = (ok & _uniform_light(pred) & np.isfinite(obs.intensity) & (obs.intensity > 0)
               & np.isfinite(obs.intensity_var))
        z_masks.append(ok)
        i_masks.append(iok)
        z_step.append(np.full(int(ok.sum()), s))
        i_step.append(np.full(int(iok.sum()), s))
        zw.append(1.0 / (obs.z_var[ok] + Z_FLOOR_MM**2))
        floor = LOG_I_FLOOR_PROJECTOR if technology == "stereo" and obs.scene.projector else LOG_I_FLOOR
        iw.append(1.0 / (obs.intensity_var[iok] / obs.intensity[iok] ** 2 + floor**2))
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
    return Layout(z_masks, i_masks,
                  np.concatenate(z_step).astype(int) if z_step else np.zeros(0, int),
                  np.concatenate(i_step).astype(int) if i_step else np.zeros(0, int),
                  np.concatenate(used) if used else np.zeros((0, len(GROUPS) + 2)),
                  np.concatenate(zw) if zw else np.zeros(0), np.concatenate(iw) if iw else np.zeros(0))


def raw_residuals(observations: list[Observation], predictions: list[Prediction]) -> tuple[list, list]:
    """Per-step maps: z_measured - z_simulated and ln I_measured - ln I_simulated."""
    dz, di = [], []
    for obs, pred in zip(observations, predictions, strict=True):
        dz.append(obs.z - pred.z)
        with np.errstate(invalid="ignore", divide="ignore"):
            di.append(np.log(obs.intensity) - np.log(pred.intensity))
    return dz, di
