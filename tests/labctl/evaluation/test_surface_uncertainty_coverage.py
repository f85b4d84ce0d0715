"""The surface Sq figures' stated uncertainty covers their spread over independent repetitions.

Known answer (GUM 6.2, 6.3: U = 2 u covers about 95 % of the values a figure takes), as in
test_distortion_uncertainty_coverage.py: the same simulated wall step at 2000 mm is run with ``SEEDS`` different
seeds, a seed drawing new camera noise (wall, camera and placement the same in every seed). For each of the three
Sq figures each seed's value must lie within its own U (k = 2, the delete-a-group jackknife of the stack over ten
groups of frames: nine degrees of freedom, so a correct U covers a seed with probability 0.92) of the mean over
the seeds in at least ``MIN_COVERED`` of ``SEEDS`` seeds, and the mean u must be within a factor ``RATIO`` of the
standard deviation over the seeds.

The simulated wall is flat and the model has no fixed texture, so each Sq is the noise left in the stack mean:
the case where the jackknife states more than the spread (metrics.surface.sq_jackknife; here 1.5 to 1.7 times),
which the factor 2 admits. 160 x 120 px (16.5 mm pixels at 2000 mm, the 25 mm cut-off 1.5 px) and 20 frames
(ten groups of two) keep a seed's run and evaluation under a second.
"""

from __future__ import annotations

import numpy as np
import pytest

from tests.coverage_check import assert_u_covers_the_spread, figures_over_seeds

SEEDS = 48
MIN_COVERED = 42
RATIO = 2.0
WALL = """
[[procedure]]
kind = "depth_sweep"
start_mm = 2000
stop_mm = 2000
step_mm = 100
frames = 20
"""
FIGURES = ("surface_primary_sq_mm", "surface_waviness_sq_mm", "surface_roughness_sq_mm")


@pytest.fixture(scope="module")
def figures(tmp_path_factory) -> dict[str, np.ndarray]:
    """Per figure, (value, u) of every seed."""
    return figures_over_seeds(tmp_path_factory.mktemp("seeds"), WALL, FIGURES, SEEDS, (160, 120), extra_devices="offset_mm = 0.0")


@pytest.mark.parametrize("name", FIGURES)
def test_expanded_uncertainty_covers_the_spread_over_seeds(figures, name):
    value, u = figures[name].T
    assert_u_covers_the_spread(name, value, u, MIN_COVERED, RATIO)
