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

from labctl.reconcile.workflow import _step_covariance


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
