"""The forward-model helper moves points along their rays by exactly the error asked for."""

from __future__ import annotations

import h5py
import numpy as np

from tests.reconcile.forward import rewrite_run, simulated_run


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
