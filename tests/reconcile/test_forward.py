"""The forward-model helper moves points along their rays by exactly the error asked for."""

from __future__ import annotations

import math

import h5py
import numpy as np
import pytest

from tests.reconcile.forward import rewrite_run
from tests.reconcile.runs import simulated_run


def test_rewrite_moves_every_valid_point_along_its_ray(tmp_path):
    run = simulated_run(tmp_path / "plain", "blaze101", sweep_step_mm=1800, robot=False)
    measured = rewrite_run(run, tmp_path / "measured.h5", lambda px: 0.01 * px.col + (px.time_s > -1) * 1.5)
    with h5py.File(run, "r") as a, h5py.File(measured, "r") as b:
        assert sorted(a["steps"]) == sorted(b["steps"])
        for name in a["steps"]:
            before = np.stack([a["steps"][name][c][:].astype(float) for c in "xyz"])
            after = np.stack([b["steps"][name][c][:].astype(float) for c in "xyz"])
            r0, r1 = np.linalg.norm(before, axis=0), np.linalg.norm(after, axis=0)
            valid = np.isfinite(r0)
            assert valid.mean() > 0.5 and np.array_equal(valid, np.isfinite(r1))
            col = np.broadcast_to(np.arange(r0.shape[-1]), r0.shape)
            np.testing.assert_allclose((r1 - r0)[valid], (0.01 * col + 1.5)[valid], atol=2e-3)
            cosine = np.sum(before * after, axis=0)[valid] / (r0 * r1)[valid]
            assert np.all(cosine > 1 - 1e-9)
            np.testing.assert_array_equal(a["steps"][name]["intensity"][:], b["steps"][name]["intensity"][:])


@pytest.mark.parametrize("k", [1, 2])
def test_bin_curvature_is_the_bin_mean_of_a_tilted_plate_minus_its_own_samples_mean(k: int) -> None:
    """A plate tilted by 60 deg at 850 mm seen by a pinhole (f = 480 px): the mean of z over each 16 x 16
    pixel bin, each pixel the mean of its own k x k sub-pixel samples, computed sample by sample, against the
    mean of the bin's own k x k samples (k = 1: its centre ray) plus ``bin_curvature``."""
    from labctl.reconcile.predict import bin_curvature

    f, b, d, tilt = 480.0, 16, 850.0, math.radians(60)
    def z_of(u: np.ndarray) -> np.ndarray:  # plane cos(t) z + sin(t) x = d cos(t), x = z u / f
        return d * math.cos(tilt) / (math.cos(tilt) + math.sin(tilt) * u / f)
    def samples_mean(size: float, count: int) -> np.ndarray:  # per cell of ``size`` px: the mean of its k x k
        offsets = (np.arange(k) + 0.5) / k - 0.5           # samples (a plane tilted about the v axis: z(u))
        u = (np.arange(count) + 0.5) * size - 80.0  # cell centres around the principal point
        return z_of(u[:, None] + size * offsets[None, :]).mean(axis=1)
    pixels = samples_mean(1.0, 160)
    bin_mean = np.broadcast_to(pixels.reshape(10, b).mean(axis=1), (10, 10))
    bins = np.broadcast_to(samples_mean(float(b), 10), (10, 10))
    predicted = bins + bin_curvature(np.ascontiguousarray(bins), b, k)
    inner = (slice(1, -1), slice(1, -1))
    assert np.abs(bin_mean - bins)[inner].max() > 0.1  # the term matters at this tilt
    np.testing.assert_allclose(predicted[inner], bin_mean[inner], atol=0.01)
