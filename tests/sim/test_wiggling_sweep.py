"""Wiggling recovered from a simulated wall sweep (issue: each effect's formula, end to end)."""

import math

import numpy as np
import pytest
from scipy.optimize import curve_fit

from labctl.cli import main
from labctl.run.store import RunReader
from metrics.stack import stack_stats

PROCEDURES = """
[[procedure]]
kind = "offset_calibration"
frames = 4

[[procedure]]
kind = "depth_sweep"
start_mm = 400
stop_mm = 4000
step_mm = 50
frames = 4
"""


def sine(d, c, a, period, phase):
    return c + a * np.sin(2 * math.pi * d / period + phase)


def fit_wiggling(distance: np.ndarray, error: np.ndarray) -> tuple[float, float]:
    """Amplitude and period by a grid search over periods (linear least squares), then curve_fit."""
    best = None
    for period in np.arange(200.0, 3000.0, 5.0):
        design = np.column_stack([np.ones_like(distance), np.sin(2 * math.pi * distance / period),
                                  np.cos(2 * math.pi * distance / period)])
        coef, res, *_ = np.linalg.lstsq(design, error, rcond=None)
        rss = float(np.sum((design @ coef - error) ** 2))
        if best is None or rss < best[0]:
            best = (rss, period, coef)
    _, period, (c, s, co) = best
    p0 = [c, math.hypot(s, co), period, math.atan2(co, s)]
    (c, a, period, phase), _ = curve_fit(sine, distance, error, p0=p0)
    return abs(a), period


def test_wiggling_amplitude_and_period_from_a_wall_sweep(tmp_path, write_campaign):
    model = tmp_path / "m.toml"
    model.write_text('camera = "blaze101"\n[camera_overrides]\nwidth = 48\nheight = 36\n'
                     "[effects.wiggling]\namplitude_mm = 3.0\nperiod_mm = 1250.0\nphase_rad = 1.0\n")
    out = tmp_path / "r.h5"
    with pytest.raises(SystemExit) as info:
        main(["run", str(write_campaign(procedures=PROCEDURES)), "--sim", "--model", str(model),
              "-o", str(out), "--quiet"])
    assert info.value.code == 0
    distance, error = [], []
    with RunReader(out) as run:
        for step in run.steps("depth_sweep"):
            z = stack_stats(step.read("z")).mean[14:22, 20:28]  # centre: range ~ z, one wiggling phase
            reference = step.attrs["reference_distance_mm"]
            distance.append(reference)
            error.append(float(np.mean(z)) - reference)
    amplitude, period = fit_wiggling(np.array(distance), np.array(error))
    assert amplitude == pytest.approx(3.0, abs=0.15)
    assert period == pytest.approx(1250.0, rel=0.01)
