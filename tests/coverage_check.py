"""The known-answer check of the uncertainty coverage tests: over independent repetitions (seeds), the stated
U = 2 u covers each figure's deviation from the mean over the seeds in about 95 % of them (GUM 6.2, 6.3), and the
stated u matches the spread actually seen (a grossly overstated uncertainty fails too); and the figures of one simulated
campaign over many seeds, which those tests check."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pytest

from labctl.cli import main
from labctl.evaluation.evaluate import evaluate_runs
from metrics.uncertainty import combined_standard_uncertainty
from tests.conftest import SMALL_MODEL, campaign_text

#: the coverage tests' campaign: the offset calibration and walls at 1000 and 2000 mm, 8 frames each
SWEEP = """
[[procedure]]
kind = "offset_calibration"
frames = 8

[[procedure]]
kind = "depth_sweep"
start_mm = 1000
stop_mm = 2000
step_mm = 1000
frames = 8
"""


def assert_u_covers_the_spread(name: str, value: np.ndarray, u: np.ndarray, min_covered: int, ratio: float) -> None:
    """``value`` and standard uncertainty ``u`` of figure ``name`` per seed: every one finite and u > 0, U = 2 u
    covering at least ``min_covered`` seeds, and the mean u within a factor ``ratio`` of the spread over seeds."""
    assert np.isfinite(value).all() and np.isfinite(u).all() and (u > 0).all()
    covered = int(np.sum(np.abs(value - value.mean()) <= 2.0 * u))
    spread = float(np.std(value, ddof=1))
    assert covered >= min_covered, f"{name}: U covers {covered} of {value.size} seeds (spread {spread:.4g}, u {u.mean():.4g})"
    assert 1 / ratio <= u.mean() / spread <= ratio, f"{name}: mean u {u.mean():.4g}, spread over seeds {spread:.4g}"


def figures_over_seeds(tmp: Path, procedures: str, figures: Sequence[str], seeds: int, size: tuple[int, int],
                       fixed: tuple[str, ...] = (), model_text: str | None = None,
                       **campaign: str) -> dict[str, np.ndarray]:
    """Per figure, (value, u of the budget's components that vary between seeds) of a simulated run of
    ``procedures`` at ``size`` (width, height) with each of the seeds 0 ... ``seeds`` - 1: a blaze-101, or the
    model ``model_text`` (its camera's size overridden by ``size`` already; ``campaign`` then names the camera's
    ``backend``). ``fixed``: the names (prefixes) of the components that stand for an error the same in every
    seed; ``campaign``: further arguments of ``campaign_text``."""
    model = tmp / "model.toml"
    model.write_text(model_text or SMALL_MODEL.format(camera="blaze101", width=size[0], height=size[1]))
    rows: dict[str, list[tuple[float, float]]] = {name: [] for name in figures}
    for seed in range(seeds):
        text = tmp / f"c{seed}.toml"
        text.write_text(campaign_text(procedures=procedures, seed=seed, **campaign))
        out = tmp / f"r{seed}.h5"
        with pytest.raises(SystemExit) as info:
            main(["run", str(text), "--sim", "--model", str(model), "-o", str(out), "--quiet"])
        assert info.value.code == 0
        found = evaluate_runs([out]).figures
        for name in figures:
            varying = [c for c in found[name].budget if not (fixed and c.name.startswith(fixed))]
            rows[name].append((found[name].value, combined_standard_uncertainty(varying)))
        out.unlink()
    return {name: np.array(values) for name, values in rows.items()}
