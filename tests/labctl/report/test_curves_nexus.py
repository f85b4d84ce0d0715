"""curves.h5 beside keyfigures.json, read by silx's NeXus parser (``silx.io.nxdata``, as silx view reads it): the
file's default is the depth errors over distance, each group a curve over the reference distance with units and
long names, and the centre repeatability carries its standard uncertainty as error bars."""

from __future__ import annotations

import json

import h5py
import numpy as np
import pytest
from silx.io import nxdata


@pytest.fixture(scope="module")
def evaluated(evaluated_small_campaign):
    return evaluated_small_campaign


def test_the_default_is_the_depth_error_curve_with_its_auxiliary_signals(evaluated):
    rows = json.loads((evaluated / "keyfigures.json").read_text())["depth_sweep"]
    with h5py.File(evaluated / "curves.h5", "r") as f:
        default = nxdata.get_default(f)
        assert default is not None and default.group.name == "/evaluation/depth_error"
        assert default.is_curve and default.signal_dataset_name == "trueness_q90_mm"
        assert default.axes_dataset_names == ["reference_mm"]
        assert set(default.auxiliary_signals_dataset_names) >= {"precision_q90_mm", "accuracy_q90_mm"}
        order = np.argsort([r["reference_mm"] for r in rows])
        np.testing.assert_allclose(default.axes[0][()], [rows[i]["reference_mm"] for i in order])
        np.testing.assert_allclose(default.signal[()], [rows[i]["trueness_q90_mm"] for i in order])
        for name in ("trueness_q90_mm", "reference_mm", "precision_q90_mm"):
            assert default.group[name].attrs["units"] == "mm" and default.group[name].attrs["long_name"]


def test_the_repeatability_curve_has_its_uncertainty_as_errors(evaluated):
    with h5py.File(evaluated / "curves.h5", "r") as f:
        curve = nxdata.NXdata(f["evaluation/repeatability_center"])
        assert curve.is_curve and curve.errors is not None
        errors, signal = curve.errors[()], curve.signal[()]
        assert np.all(np.isfinite(errors)) and np.all(errors > 0)
        np.testing.assert_allclose(errors, signal / np.sqrt(2 * (8 - 1)), rtol=1e-6)  # GUM E.4.3, n = 8 frames
        accuracy = nxdata.NXdata(f["evaluation/z_accuracy"])
        assert accuracy.is_curve and accuracy.group["z_accuracy_pct"].attrs["units"] == "%"
