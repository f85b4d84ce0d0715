"""A candidate's fit on full re-simulations: where it starts (``score.polished``), and its solver, scipy's least
squares with its default forward differences less the Jacobian it takes at the point where it stops
(labctl/reconcile/workflow.py ``_ForwardJacobian``)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import optimize

from labctl.reconcile.candidates import candidates_for
from labctl.reconcile.observe import observe_run
from labctl.reconcile.residuals import layout
from labctl.reconcile.score import polished, score
from labctl.reconcile.workflow import FIT_FTOL, Simulation, _ForwardJacobian, _State, base_model
from tests.reconcile.runs import simulated_run


@pytest.mark.parametrize("room", [None, 1e-12])
def test_a_fit_takes_the_default_solvers_steps_and_one_jacobian_fewer(room):
    """A sine's amplitude, period and phase fitted to noisy samples (whitened by their sigma), once by
    ``least_squares`` differencing itself, once through ``_ForwardJacobian``: the same points in the same order
    and the same result, three evaluations fewer (the Jacobian where the step lowered the cost by less than
    ``FIT_FTOL`` of it, which the default takes and nothing uses). ``room``: the amplitude starts that close
    under its upper bound, so that its difference is taken backwards."""
    rng = np.random.default_rng(3)
    t = np.linspace(0.0, 10.0, 2000)
    y = 3.0 * np.sin(2 * np.pi * t / 1.5 + 0.5) + rng.normal(size=t.size) * 0.3
    x0 = np.array([3.1, 1.53, 0.6])
    lo, hi = np.array([0.0, 0.1, -10.0]), np.array([100.0 if room is None else 3.1 + room, 20.0, 10.0])

    def residual(x: np.ndarray, seen: list[np.ndarray]) -> np.ndarray:
        seen.append(x.copy())
        return (x[0] * np.sin(2 * np.pi * t / x[1] + x[2]) - y) / 0.3

    default: list[np.ndarray] = []
    own: list[np.ndarray] = []
    a = optimize.least_squares(lambda x: residual(x, default), x0, bounds=(lo, hi), x_scale="jac", ftol=FIT_FTOL)
    jacobian = _ForwardJacobian(lambda x: residual(x, own), (lo, hi))
    b = optimize.least_squares(jacobian.residual, x0, jac=jacobian, bounds=(lo, hi), x_scale="jac", ftol=FIT_FTOL)
    # stopped by ftol; the held Jacobian's gradient at that point may read as gtol's instead (scipy checks it after)
    assert a.status == 2 and b.status in (1, 2)
    assert len(own) == len(default) - 3
    assert all(np.array_equal(u, v) for u, v in zip(default, own, strict=False))
    assert np.array_equal(a.x, b.x) and np.array_equal(a.fun, b.fun)
    if room is not None:  # the amplitude's step went down, away from the bound
        assert own[1][0] < x0[0] < hi[0] and default[1][0] == own[1][0]


def test_a_fit_starts_from_its_grid_point_polished_towards_the_hidden_value(tmp_path):
    """A blaze-101 test campaign with a hidden 2 mm wiggling of a 1560 mm period, half-way between two points of the
    candidate's period grid (the test campaign's compared ranges span 4490 mm: its points at 4 x 4490 mm / (4 + k),
    1633 and 1497 mm): the fit on full re-simulations starts from the best grid point's period searched between its
    neighbours on the linear fit (``score.polished``), nearer the hidden period than the grid's point."""
    period = 1560.0
    hidden = {"amplitude_mm": 2.0, "period_mm": period, "phase_rad": 0.4}
    run = simulated_run(tmp_path, "blaze101", hidden={"wiggling": hidden}, seed=11)
    observations, info, _ = observe_run(run)
    model = base_model(info)
    sim = Simulation(observations, info)
    state = _State(sim, layout(observations, sim.predict(model), "tof"), model)
    ctx, r = state.context(), state.scored_residual(None)
    candidate = next(c for c in candidates_for(ctx) if c.name == "wiggling")
    fit = score(candidate, ctx, state.lay, r)
    assert fit is not None and fit.nonlinear == fit.params["period_mm"]
    grid = np.asarray(candidate.grid(ctx))
    step = float(np.diff(grid)[np.argmin(np.abs(grid[:-1] - period))])
    start = polished(candidate, fit, ctx, state.lay, r)
    # the grid's point 73 mm off (a 136 mm step here), the polished one 7 mm, about the run's noise on the period
    assert abs(fit.params["period_mm"] - period) > 0.2 * step, (fit.params, step)
    assert abs(start["period_mm"] - period) < 0.15 * step, (start, fit.params, step)
