"""Standard errors of reconcile's fitted parameters against the scatter of the fits they describe.

A stereo sweep's walls are fitted bin by bin, each bin weighted by its noise, which grows as z^2: the near walls
carry the fit. Each wall also carries an error of its own that its bins share (the laser's reading of that step),
so the steps, not the bins, are the replications. Here the truth is known because the data are drawn in the
test: a straight line in the wall distance whose slope is 0, walls 0.6-4 m apart with a shared error of 0.07
units each and per-bin noise 0.1 D^2. Over 2000 draws the stated 95 % interval must hold the true slope in at
least 90 % of them; the cluster-robust sandwich that counts each step's score as it is (Liang & Zeger 1986)
held it in 62 %, since two or three precise steps carry the fit.
"""

from __future__ import annotations

import numpy as np
from scipy import optimize

from labctl.reconcile.residuals import GROUPS, Layout
from labctl.reconcile.workflow import _combined_covariance, _Fitted, _reference_covariance, _step_covariance


def test_stated_intervals_cover_the_true_slope_when_a_few_precise_steps_carry_the_fit():
    rng = np.random.default_rng(20261126)
    n_steps, bins, draws = 12, 40, 2000
    distance = np.linspace(0.6, 4.0, n_steps)
    noise = 0.1 * distance**2
    steps = np.repeat(np.arange(n_steps), bins)
    design = np.stack([np.ones(steps.size), distance[steps]], axis=1) / noise[steps, None]  # whitened
    covered = 0
    for _ in range(draws):
        shared = rng.normal(0.0, 0.07, n_steps)[steps]
        whitened = (shared + rng.normal(0.0, 1.0, steps.size) * noise[steps]) / noise[steps]
        fitted, *_ = np.linalg.lstsq(design, whitened, rcond=None)
        cov = _step_covariance(design, whitened - design @ fitted, steps, n_steps)
        covered += abs(fitted[1]) <= 1.96 * np.sqrt(cov[1, 1])
    assert covered / draws >= 0.90


def _laser_walls(n_steps: int, noise_per_m2: float, bins: int = 40,
                 reference_var: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray, Layout]:
    """``n_steps`` laser-referenced walls 0.6-4 m of ``bins`` depth bins each, noise ``noise_per_m2`` z^2 (mm, z in
    m), the laser group's offset their shared nuisance: the walls' distances, each bin's noise and step, and
    their layout (``reference_var``: each step's own reference variance)."""
    distance = np.linspace(0.6, 4.0, n_steps)
    noise = noise_per_m2 * distance**2
    steps = np.repeat(np.arange(n_steps), bins)
    nuisance = np.zeros((steps.size, len(GROUPS) + 2))
    nuisance[:, GROUPS.index("laser")] = 1.0
    extra = {} if reference_var is None else {"reference_var": reference_var}
    lay = Layout([np.ones(bins, bool)] * n_steps, [np.zeros(bins, bool)] * n_steps, steps, np.zeros(0, int),
                 nuisance, 1.0 / noise[steps] ** 2, np.zeros(0), **extra)
    return distance, noise, steps, lay


def test_stated_intervals_cover_the_true_slope_with_the_shared_offset_profiled_out():
    """The same walls as reconcile fits them: the offset the steps share (the laser group's depth offset) profiled
    out before the fit (``Layout.profiled_rows``), the slope fitted on what is left. Leaving a step out must
    re-estimate the offset as well: the jackknife over the profiled slope alone held the truth in about 60 % of
    the draws (the nearest walls carry the offset, and their leverage on it went uncounted); over the slope and
    ``Layout.shared_nuisance`` together in about 94 %."""
    rng = np.random.default_rng(20261127)
    n_steps, draws = 12, 2000
    distance, noise, steps, lay = _laser_walls(n_steps, 0.1)
    nothing = np.zeros(0)
    slope = lay.profiled_rows(distance[steps], nothing)[:, None]
    shared = lay.shared_nuisance()
    assert shared.shape == (steps.size, 1)
    covered, profiled_only = 0, 0
    for _ in range(draws):
        measured = rng.normal(0.0, 0.07, n_steps)[steps] + rng.normal(0.0, 1.0, steps.size) * noise[steps]
        whitened = lay.profiled_rows(measured, nothing)
        fitted = float(slope[:, 0] @ whitened / (slope[:, 0] @ slope[:, 0]))
        residual = whitened - slope[:, 0] * fitted
        covered += abs(fitted) <= 1.96 * np.sqrt(_step_covariance(slope, residual, steps, n_steps, shared)[0, 0])
        profiled_only += abs(fitted) <= 1.96 * np.sqrt(_step_covariance(slope, residual, steps, n_steps)[0, 0])
    assert 0.90 <= covered / draws <= 0.99
    assert profiled_only / draws < 0.75  # what the intervals held before the shared nuisance was counted


def test_the_slope_an_error_propagates_by_is_taken_over_the_rounding_steps_not_across_one():
    """A prediction that averages a rounding over finitely many grid positions (as the stereo depth's is,
    labctl/reconcile/noise_model.py) is piecewise constant: at the solver's finite difference its derivative is 0
    or a jump divided by 1e-8. Over a step of the parameter's uncertainty the slope is the true one."""
    z = np.linspace(500.0, 3000.0, 400)
    positions = (np.arange(8) + 0.5) / 8

    def residual(x: np.ndarray) -> np.ndarray:
        return -np.mean(np.rint(z[:, None] * (1 + x[0]) + positions[None, :]), axis=1)

    x = np.array([0.01])
    fitted = _Fitted(optimize.OptimizeResult(x=x, fun=residual(x)), lambda v: v, residual,
                     (np.array([-0.1]), np.array([0.1])), [slice(0, 1)])
    tiny = fitted.secant_jacobian(np.array([1.5e-10]))[:, 0]
    secant = fitted.secant_jacobian(np.array([0.01]))[:, 0]
    assert np.max(np.abs(tiny)) > 1e6 or not np.any(tiny)  # a jump or nothing, not the slope
    assert np.all(np.abs(secant + z) <= 1 / len(positions) / 0.02 + 1e-9)  # within one position's jump over 2 h


def test_a_known_reference_error_per_step_bounds_the_interval_from_below_where_few_steps_carry_the_fit():
    """Three walls, each referenced by a laser reading with an error of its own (0.07 mm, known from the meter's
    repeatability: ``Layout.reference_var``), the offset they share profiled out. With so few steps the
    jackknife's variance rests on one or two effective replications and often falls short (it held the true slope
    in about 87 % of the draws); the larger of it and the declared errors' (``_combined_covariance``, Birge 1932)
    in at least 93 %."""
    rng = np.random.default_rng(20261129)
    n_steps, draws = 3, 2000
    distance, noise, steps, lay = _laser_walls(n_steps, 0.02, reference_var=np.full(n_steps, 0.07**2))
    nothing = np.zeros(0)
    slope = lay.profiled_rows(distance[steps], nothing)[:, None]
    internal = np.linalg.pinv(slope.T @ slope) + _reference_covariance(slope, lay.reference_directions())
    covered, jackknife_only = 0, 0
    for _ in range(draws):
        measured = rng.normal(0.0, 0.07, n_steps)[steps] + rng.normal(0.0, 1.0, steps.size) * noise[steps]
        whitened = lay.profiled_rows(measured, nothing)
        fitted = float(slope[:, 0] @ whitened / (slope[:, 0] @ slope[:, 0]))
        external = _step_covariance(slope, whitened - slope[:, 0] * fitted, steps, n_steps, lay.shared_nuisance())
        covered += abs(fitted) <= 1.96 * np.sqrt(_combined_covariance(external, internal)[0, 0])
        jackknife_only += abs(fitted) <= 1.96 * np.sqrt(external[0, 0])
    assert covered / draws >= 0.93
    assert jackknife_only / draws < 0.90
