"""Errors that older libraries confused with others: what reconcile names now that the library has their forms.

Forward models written here from first principles (tests/reconcile/forward.py rewrites a plain run):

* a range error of -1.5 mm per decade of the pixel's signal, on a depth sweep that returns to 2 m at its end
  (an offset calibration at 2 m before and after the 0.4-4 m sweep): the signal falls as the sweep moves
  out and is back at the 2 m value at the end, so over the run's time it looks like a drift; over the
  signal it is a straight line in log10 of the intensity -> ``log_amplitude_error``. The run also holds the
  robot's PTFE and silicone plates (two signals at one position), which separate an error following the
  signal from one following the distance (without them: ``ambiguous``, tests/reconcile/test_confounds.py);
* a constant offset of 0.1 px on every stereo disparity d = f b / z: the depth f b / (d + 0.1) is short by
  about z^2 0.1 / (f b), growing as the square of the distance -> ``stereo_calibration_drift``.
"""

from __future__ import annotations

import h5py
import numpy as np

from labctl.reconcile.workflow import reconcile
from sim.profiles import get_profile
from tests.reconcile.forward import Pixels, rewrite_run
from tests.reconcile.runs import BACKENDS, CAMPAIGN, ROBOT, simulated_run

RETURN_TO_2M = """
[[procedure]]
kind = "offset_calibration"
distance_mm = 2000
frames = 10
"""


def test_a_signal_dependent_error_on_a_sweep_back_to_2m_is_log_amplitude_error(tmp_path):
    campaign = CAMPAIGN.format(backend=BACKENDS["blaze101"], seed=3, sweep_step_mm=200, robot=ROBOT) + RETURN_TO_2M
    plain = simulated_run(tmp_path / "plain", "blaze101", campaign=campaign)
    with h5py.File(plain, "r") as f:
        steps = sorted(f["steps"])
        assert f["steps"][steps[-1]].attrs["procedure"] == "offset_calibration"
        at_2m = float(np.median(f["steps"][steps[0]]["intensity"][:]))

    def error(px: Pixels):
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.where(px.intensity > 0, -1.5 * np.log10(px.intensity / at_2m), 0.0)

    result = reconcile(rewrite_run(plain, tmp_path / "measured.h5", error))
    names = [n.name for n in result.named]
    assert names[:1] == ["log_amplitude_error"], (names, result.verdict)
    assert abs(result.named[0].parameters["per_decade_mm"] + 1.5) <= 0.3, result.named[0].parameters


def test_a_constant_disparity_offset_is_stereo_calibration_drift(tmp_path):
    baseline = get_profile("d455").baseline_mm
    plain = simulated_run(tmp_path / "plain", "d455", robot=False)

    def error(px: Pixels):
        d = px.disparity_px(baseline)
        z_drifted = px.focal_px * baseline / (d + 0.1)
        return (z_drifted - px.z_mm) * px.range_mm / px.z_mm

    result = reconcile(rewrite_run(plain, tmp_path / "measured.h5", error))
    names = [n.name for n in result.named]
    assert names[:1] == ["stereo_calibration_drift"], (names, result.verdict)
    assert abs(result.named[0].parameters["disparity_offset_px"] - 0.1) <= 0.02, result.named[0].parameters
