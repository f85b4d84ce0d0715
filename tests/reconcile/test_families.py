"""The noise's statistics as residual families: a run whose temporal noise, valid pixels or noise correlation
differs from the model's is never ``none``, and its verdict names the family; spatially correlated noise does not
make the bin means look wrong; ``ambient_light`` is named and fitted from the noise family.

The cameras are written here from first principles (tests/reconcile/forward.py), not with the effect library:
a plain simulated run's stacks are rewritten as a camera with 3x the noise, 40 % of its pixels dark beyond
2.4 m, or its noise correlated over 4 x 4 pixels would have measured them.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from tests.reconcile.forward import correlate_noise, correlated_field, rewrite_noise, rewrite_run, scale_noise
from tests.reconcile.runs import reconcile_cli, simulated_run


@pytest.fixture(scope="module")
def plain(tmp_path_factory):
    """A plain blaze101 run: offset calibration and a 0.4-4 m sweep, 10 frames per step."""
    return simulated_run(tmp_path_factory.mktemp("plain"), "blaze101", robot=False)


def _family(doc, name):
    return next(f for f in doc["unexplained"]["families"] if f["family"] == name)


def test_temporal_noise_three_times_the_models_is_named(plain, tmp_path):
    doc = reconcile_cli(rewrite_noise(plain, tmp_path / "noisy.h5", scale_noise(3.0)), tmp_path / "out")
    noise = doc["families"]["noise"]
    assert doc["verdict"] != "none" and noise["consistent"] is False
    assert noise["gap_before"] == pytest.approx(100 * math.log(3.0), abs=5.0)  # ln 3: the std's log ratio, in %
    assert noise["floor"] < 10.0
    assert doc["families"]["depth"]["consistent"] and doc["families"]["validity"]["consistent"]
    assert "temporal noise" in _family(doc, "noise")["description"]
    assert "noise" in doc["unexplained"]["message"]


def test_invalid_pixels_beyond_2_4_m_are_named_and_the_steps_left_out_listed(plain, tmp_path):
    def dark(px):  # the same 40 % of the pixels of a step fail wherever the range exceeds 2.4 m
        lost = np.random.default_rng(int(px.step["index"])).random(px.z_mm.shape) < 0.4
        return np.where(lost & (px.range_mm > 2400.0), np.nan, 0.0)

    doc = reconcile_cli(rewrite_run(plain, tmp_path / "dark.h5", dark), tmp_path / "out")
    validity = doc["families"]["validity"]
    assert doc["verdict"] != "none" and validity["consistent"] is False
    found = _family(doc, "validity")
    assert found["relative_change"] == pytest.approx(-0.40, abs=0.05), found
    assert found["where"].startswith("beyond")
    assert 2.2 <= float(found["where"].split()[1]) <= 2.7, found["where"]
    depth_out = {e["step"]: e["reason"] for e in doc["excluded_steps"] if e["family"] == "depth"}
    compared = doc["families"]["depth"]["steps"]
    assert len(depth_out) + compared == 20  # every step is compared or listed
    assert depth_out, doc["excluded_steps"]
    assert all("too few valid pixels" in reason for reason in depth_out.values())


def test_noise_correlated_over_4_by_4_pixels_is_named_and_leaves_the_means_alone(plain, tmp_path):
    doc = reconcile_cli(rewrite_noise(plain, tmp_path / "correlated.h5", correlate_noise(4)), tmp_path / "out")
    families = doc["families"]
    assert doc["verdict"] != "none" and families["correlation"]["consistent"] is False
    assert families["noise"]["consistent"] and families["depth"]["consistent"]
    # box-correlated noise (4 x 4 window) in 4 x 4 bins: the ratio is m times the mean correlation of the bin's
    # pixel pairs, 16 (sum_{a,b<4} (4 - |a - b|) / 4 / 16)^2 = 16 (44 / 64)^2 = 7.56
    assert _family(doc, "correlation")["factor"] == pytest.approx(16 * (44 / 64) ** 2, rel=0.1)


def test_zero_mean_correlated_noise_does_not_make_the_means_unexplained(plain, tmp_path):
    rng = np.random.default_rng(5)
    run = rewrite_run(plain, tmp_path / "null.h5", lambda px: correlated_field(px.z_mm.shape, 4, 1.0, rng))
    doc = reconcile_cli(run, tmp_path / "out")
    after = doc["goodness_of_fit"]["after"]
    assert after["depth_consistent"] and after["intensity_consistent"], after
    assert doc["named_effects"] == [] and doc["empirical_corrections"] == []
    assert doc["families"]["correlation"]["consistent"] is False  # what the camera does differ in is named
    assert doc["verdict"] != "none"


def test_ambient_light_is_named_and_fitted_from_the_noise(tmp_path):
    run = simulated_run(tmp_path / "lit", "blaze101", {"ambient_light": {"level": 3.0}}, robot=False)
    doc = reconcile_cli(run, tmp_path / "out")
    assert doc["verdict"] == "effect_found", doc["goodness_of_fit"]["after"]
    (named,) = doc["named_effects"]
    assert named["name"] == "ambient_light"
    lo, hi = named["evidence"]["determination"]["interval_95"]["level"]
    assert lo <= 3.0 <= hi and hi - lo < 1.0, (lo, hi)
    assert doc["families"]["noise"]["gap_before"] > 5 * doc["families"]["noise"]["floor"]
    assert doc["families"]["noise"]["consistent"]


def test_a_vignetting_on_the_d455_leaves_the_valid_pixels_consistent(tmp_path):
    """A cos^4.77 vignetting on the D455 (160 x 120, f = 104 px): at 40 deg off axis its relative slope is
    4.77 tan(40 deg) / 104 = 0.039 per pixel, a contrast of 0.039 sqrt((7^2 - 1) / 12) = 0.078 over the 7 px
    matching window, 1.6 times the texture threshold (0.05). On the far walls and plates, where the dots' own
    contrast is near the threshold, the run then holds more valid pixels than a prediction without that texture
    (73 % more at 4.1 m: ``unexplained`` in the validity family). The vignetting is named, and afterwards the
    valid pixels agree with the model."""
    run = simulated_run(tmp_path / "vignetted", "d455", {"vignetting": {"exponent": 4.77}}, seed=70057)
    doc = reconcile_cli(run, tmp_path / "out")
    assert doc["verdict"] == "effect_found", doc["goodness_of_fit"]["after"]
    assert [e["name"] for e in doc["named_effects"]] == ["vignetting"]
    assert doc["families"]["validity"]["consistent"], doc["families"]["validity"]
