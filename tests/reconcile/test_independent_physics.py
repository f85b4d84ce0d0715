"""Reconcile on runs rewritten by forward models derived from first principles (no effect-library code).

Each test makes a plain simulated run (a 0.4-4 m sweep in 200 mm steps with
an offset calibration, 10 frames per stack, 160 x 120 pixels; shared per
camera) and rewrites its x/y/z stacks the way a camera with one physical
effect would have measured them:

* 4-tap demodulation of a correlation function with odd harmonics (square-wave
  modulation through a finite bandwidth) -> ``wiggling`` with the period
  c / (8 f_mod) the 4-tap sampling aliases the harmonics to;
* a warm-up with two thermal time constants, over a sweep spread in time ->
  ``temperature_drift`` with both;
* a specular floor below the camera: the bounce camera -> floor -> target,
  its reflection point found by Fermat's principle, as a second return whose
  phasor adds to the direct one -> ``floor_multipath`` on the floor;
* column stripes plus row stripes of range offset -> ``fixed_pattern``;
* pixel locking of the stereo matcher, a disparity bias periodic in the
  disparity (1 px period) -> ``disparity_bias``.

Asserted: the effect is named and the gap at least halves.
"""

from __future__ import annotations

import math

import h5py
import numpy as np
import pytest

from labctl.cli import main
from labctl.reconcile.workflow import reconcile
from sim.profiles import get_profile
from tests.reconcile.forward import Pixels, rewrite_run, stretch_time
from tests.reconcile.runs import CAMPAIGN, simulated_run

C_MM_PER_S = 299_792_458_000.0


@pytest.fixture(scope="module")
def plain(tmp_path_factory):
    runs = {}

    def make(camera: str):
        if camera not in runs:
            runs[camera] = simulated_run(tmp_path_factory.mktemp(camera), camera, robot=False)
        return runs[camera]

    return make


def _reconciled(run, tmp_path, error):
    result = reconcile(rewrite_run(run, tmp_path / "measured.h5", error))
    names = [n.name for n in result.named]
    return result, names


def _halved(result):
    assert result.gap_after <= 0.5 * result.gap_before, (result.gap_before, result.gap_after)


def test_four_tap_harmonic_correlation_is_wiggling(plain, tmp_path):
    f_mod = get_profile("blaze101").modulation_mhz * 1e6
    k = 4 * math.pi * f_mod / C_MM_PER_S  # correlation phase per mm of range
    a3, a5 = 0.02, 0.005  # odd harmonics of the correlation (square wave through the sensor's bandwidth)

    def correlation(theta):
        return np.cos(theta) + a3 * np.cos(3 * theta) + a5 * np.cos(5 * theta)

    def error(px: Pixels):
        phi = k * px.range_mm
        taps = [correlation(phi + i * math.pi / 2) for i in range(4)]
        measured = np.arctan2(taps[3] - taps[1], taps[0] - taps[2])
        return np.angle(np.exp(1j * (measured - phi))) / k

    result, names = _reconciled(plain("blaze101"), tmp_path, error)
    assert names[0] == "wiggling", names
    period = C_MM_PER_S / (8 * f_mod)  # the harmonics alias to the 4th harmonic of the phase
    assert abs(result.named[0].parameters["period_mm"] - period) <= 0.02 * period
    _halved(result)


def test_two_time_constant_warm_up_is_temperature_drift(plain, tmp_path):
    def warm_up(t):  # the die (8 min) and, pulling the other way, the housing and lens mount (50 min)
        return 5.0 * np.exp(-t / 500.0) - 3.0 * np.exp(-t / 3000.0)

    slow = stretch_time(plain("blaze101"), tmp_path / "slow.h5", 10.0)  # the sweep spread over 32 min
    result, names = _reconciled(slow, tmp_path, lambda px: warm_up(px.time_s))
    assert names[0] == "temperature_drift", names
    _halved(result)
    fitted = result.named[0].parameters
    assert len(fitted.get("terms", [])) == 1  # both time constants are seen
    # the fitted warm-up follows the true one over the sweep (up to the constant the offsets take)
    times = np.concatenate([o.times_s for o in result.observations if o.scene.procedure == "depth_sweep"])
    model = fitted["delta_mm"] * np.exp(-times / fitted["tau_s"]) + sum(
        term["delta_mm"] * np.exp(-times / term["tau_s"]) for term in fitted["terms"])
    difference = model - warm_up(times)
    assert np.ptp(difference) <= 0.3, np.ptp(difference)


def test_specular_floor_bounce_is_floor_multipath(plain, tmp_path):
    f_mod = get_profile("blaze101").modulation_mhz * 1e6
    floor_mm, reflectance = 400.0, 0.4  # floor 400 mm below the optical axis (camera y points down)

    def error(px: Pixels):
        x, y, z = px.x_mm, px.y_mm, px.z_mm
        r = px.range_mm
        # Fermat: the reflection point on the floor splits the horizontal offset in the ratio of the heights
        share = floor_mm / (2 * floor_mm - y)
        fx, fz = x * share, z * share
        path = np.sqrt(fx**2 + floor_mm**2 + fz**2) + np.sqrt((x - fx) ** 2 + (y - floor_mm) ** 2 + (z - fz) ** 2)
        # target facing the camera: irradiance cos(incidence) / distance^2, z / r^3 direct, z / path^3 bounced
        q = reflectance * (r / path) ** 3
        extra_phase = 2 * math.pi * f_mod * (path - r) / C_MM_PER_S  # round trip r + path against 2 r
        shift = np.angle(1 + q * np.exp(1j * extra_phase)) * C_MM_PER_S / (4 * math.pi * f_mod)
        return np.where(y < floor_mm, shift, 0.0)

    result, names = _reconciled(plain("blaze101"), tmp_path, error)
    assert names[0] == "floor_multipath", names
    assert result.named[0].parameters["plane"] == "floor"
    _halved(result)


def test_column_and_row_stripes_are_fixed_pattern(plain, tmp_path):
    rng = np.random.default_rng(5)
    column_bands = rng.normal(0.0, 1.5, 20)  # 8-column bands (column-parallel readout groups), mm
    row_bands = rng.normal(0.0, 1.0, 10)

    def stripes(col, row, width, height):
        return column_bands[col * 20 // width] + 0.01 * (col - width / 2) + row_bands[row * 10 // height]

    def error(px: Pixels):
        return stripes(px.col, px.row, px.width, px.height)

    result, names = _reconciled(plain("blaze101"), tmp_path, error)
    assert names[0] == "fixed_pattern", names
    _halved(result)
    # the fitted column profile follows the bands (bin means of 4 columns; the mean goes to the offsets)
    fitted = np.array(result.named[0].parameters["column_offsets_mm"])
    truth = np.array([np.mean(stripes(np.arange(4 * i, 4 * i + 4), 0, 160, 120)) for i in range(40)])
    seen = fitted != 0
    assert np.corrcoef(fitted[seen], truth[seen])[0, 1] > 0.95
    # the written model re-simulates the pattern: same seed, so the first steps carry the same noise
    (tmp_path / "model.toml").write_text(result.model_toml())
    (tmp_path / "short.toml").write_text(CAMPAIGN.format(backend="blaze", seed=3, sweep_step_mm=3600, robot=""))
    with pytest.raises(SystemExit) as info:
        main(["run", str(tmp_path / "short.toml"), "--sim", "--model", str(tmp_path / "model.toml"),
              "-o", str(tmp_path / "resimulated.h5"), "--quiet"])
    assert info.value.code == 0
    with h5py.File(tmp_path / "measured.h5", "r") as measured, h5py.File(tmp_path / "resimulated.h5", "r") as resim:
        for step in ("00000_offset_calibration", "00001_depth_sweep"):
            left = np.nanmean(measured["steps"][step]["z"][:].astype(float), axis=(0, 1))[8:-8]
            right = np.nanmean(resim["steps"][step]["z"][:].astype(float), axis=(0, 1))[8:-8]
            true_columns = stripes(np.arange(160), 0, 160, 120)[8:-8]
            assert np.std(left - right) <= 0.25 * np.std(true_columns), (np.std(left - right), np.std(true_columns))


def test_pixel_locking_is_disparity_bias(plain, tmp_path):
    baseline = get_profile("d455").baseline_mm
    amplitude_px = 0.03

    def error(px: Pixels):
        d = px.disparity_px(baseline)
        z_biased = px.focal_px * baseline / (d + amplitude_px * np.sin(2 * math.pi * d))
        return (z_biased - px.z_mm) * px.range_mm / px.z_mm

    result, names = _reconciled(plain("d455"), tmp_path, error)
    assert names[0] == "disparity_bias", names
    assert abs(result.named[0].parameters["amplitude_px"] - amplitude_px) <= 0.2 * amplitude_px
    _halved(result)
