"""Effects a sweep confounds are not named on the sweep's resemblance alone.

The measured errors are written here from first principles (tests/reconcile/forward.py), not with the
effect library's code:

* a range error that follows the signal, -1.5 mm per decade of the pixel's intensity, on a blaze-101 run that
  calibrates its offset at 2000 mm, sweeps 400 ... 4000 mm and returns to 2000 mm at its end
  (``return_mm``). Along the sweep the intensity falls with the distance and the run's time grows, so a
  warm-up drift draws nearly the same curve; but the error at 2000 mm is the same at the start, in the middle
  and at the end of the run, which a drift cannot do;
* a constant stereo disparity offset on a D455 (z' = f b / (f b / z + delta), f from the file's field of
  view, b = 95 mm, the D455's baseline in Intel's datasheet): an error growing with z^2, which no library
  effect of today has; a range scale (linear in z) is not the answer.
"""

from __future__ import annotations

import numpy as np

from labctl.reconcile.workflow import reconcile
from tests.reconcile.forward import rewrite_run
from tests.reconcile.runs import BACKENDS, CAMPAIGN, simulated_run

RETURN = "return_mm = 2000\n"  # a key of the template's depth sweep: back to 2000 mm after 4000 mm
D455_BASELINE_MM = 95.0
DISPARITY_OFFSET_PX = 0.01  # at the file's focal length: about 5 mm at 2 m and 20 mm at 4 m


def _signal_error(px):
    with np.errstate(invalid="ignore", divide="ignore"):
        return -1.5 * np.log10(np.where(px.intensity > 0, px.intensity, np.nan))


def _disparity_offset(px):
    fb = px.focal_px * D455_BASELINE_MM
    with np.errstate(invalid="ignore", divide="ignore"):
        dz = fb / (fb / px.z_mm + DISPARITY_OFFSET_PX) - px.z_mm
        return dz * px.range_mm / px.z_mm  # the depth error as a range error along the ray


def test_a_signal_following_error_on_a_returning_sweep_is_not_named_a_drift(tmp_path):
    campaign = CAMPAIGN.format(backend=BACKENDS["blaze101"], seed=3, sweep_step_mm=200, robot=RETURN)
    plain = simulated_run(tmp_path / "plain", "blaze101", campaign=campaign)
    result = reconcile(rewrite_run(plain, tmp_path / "measured.h5", _signal_error))
    named = [e.name for e in result.named]
    assert "temperature_drift" not in named, (result.verdict, named, result.notes)
    assert result.verdict in ("unexplained", "ambiguous"), (result.verdict, named)
    assert result.ambiguity is None or "temperature_drift" not in result.ambiguity.between or \
        "return_mm" not in result.ambiguity.separating_capture  # the run already returns to 2000 mm
    if result.verdict == "unexplained":
        assert result.unexplained.carrying_axis == "intensity", result.unexplained.description


def test_a_constant_disparity_offset_is_not_named_a_range_scale(tmp_path):
    campaign = CAMPAIGN.format(backend=BACKENDS["d455"], seed=3, sweep_step_mm=200, robot="")
    plain = simulated_run(tmp_path / "plain", "d455", campaign=campaign)
    result = reconcile(rewrite_run(plain, tmp_path / "measured.h5", _disparity_offset))
    named = [e.name for e in result.named]
    assert "range_scale" not in named, (result.verdict, named, result.notes)
    assert result.verdict != "none"
    if result.ambiguity is not None:  # the separating capture is one the run does not hold
        steps = [o.scene.step_id for o in result.observations]
        assert not any(s in result.ambiguity.separating_capture for s in steps), result.ambiguity
