"""The checkerboard figures' stated uncertainty covers their spread over independent repetitions.

Known answer (GUM 6.2, 6.3: U = 2 u covers about 95 % of the values a figure takes), as in
test_uncertainty_coverage.py: the same simulated checkerboard step is run with ``SEEDS`` different seeds, a seed
drawing new camera noise (the board, its placement and the camera are the same in every seed, so the figures
scatter only as repeated stacks would). For each of the four radial distortion figures and the x/y trueness and
accuracy Q90 each seed's value must lie within its own U (k = 2: the delete-a-group jackknife of the stack; for
accuracy the spread of the single frame) of the mean over the seeds in at least ``MIN_COVERED`` of ``SEEDS``
seeds (87.5 %), and the mean u must be within a factor ``RATIO`` of the standard deviation over the seeds. The
tile size's component stands for an error the same in every seed (the board is the same), so it cannot show in
the spread and is left out of U here.

Why 48 seeds and not 16: the jackknife over G = 10 groups estimates u with G - 1 = 9 degrees of freedom, so a
correct U covers a seed with probability P(|t_9| < 2) = 0.92, not 0.95; 14 of 16 would then fail one of the four
figures in four seed sets of ten. With 48 seeds and 42 needed a correct U passes each figure with probability
0.93; a u understated by a third covers 78 % of the seeds and passes with probability 0.08.

The smallest set-up where the corners are found in every seed: 80 x 60 px, 60 mm tiles at 600 mm (about 6 px a
tile, 117 corners), 20 frames (ten groups of two).
"""

from __future__ import annotations

import numpy as np
import pytest

from tests.coverage_check import assert_u_covers_the_spread, figures_over_seeds

SEEDS = 48
MIN_COVERED = 42
RATIO = 2.0
BOARD = """
[[procedure]]
kind = "checkerboard"
distance_mm = 600
tile_mm = 60
frames = 20
"""
FIGURES = (*(f"radial_distortion_{image}_{axis}_pct" for image in ("intensity", "cloud") for axis in "wh"),
           *(f"{axis}_{kind}_q90_mm" for kind in ("trueness", "accuracy") for axis in "xy"))
#: the component that stands for an error the same in every seed
FIXED = ("tile size",)


@pytest.fixture(scope="module")
def figures(tmp_path_factory) -> dict[str, np.ndarray]:
    """Per figure, (value, u of the components that vary between seeds) of every seed."""
    return figures_over_seeds(tmp_path_factory.mktemp("seeds"), BOARD, FIGURES, SEEDS, (80, 60), FIXED)


@pytest.mark.parametrize("name", FIGURES)
def test_expanded_uncertainty_covers_the_spread_over_seeds(figures, name):
    value, u = figures[name].T
    assert_u_covers_the_spread(name, value, u, MIN_COVERED, RATIO)
