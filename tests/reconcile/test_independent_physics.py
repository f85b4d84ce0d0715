"""Reconcile on runs rewritten by forward models derived from first principles (no effect-library code).

Each test makes a plain simulated run (a 0.4-4 m sweep in 200 mm steps with
an offset calibration, 10 frames per stack, 160 x 120 pixels; shared per
camera) and rewrites its x/y/z stacks the way a camera with one physical
effect would have measured them:

* 4-tap demodulation of a correlation function with odd harmonics (square-wave
  modulation through a finite bandwidth) -> ``wiggling`` with the period
  c / (8 f_mod) the 4-tap sampling aliases the harmonics to;
* a warm-up of a two-node thermal network (die and housing, two coupled
  first-order equations integrated numerically), over a sweep spread in time ->
  ``temperature_drift`` with two time constants;
* a specular floor below the camera: the bounce camera -> floor -> target,
  its reflection point found by Fermat's principle, as a second return whose
  phasor adds to the direct one -> ``floor_multipath`` on the floor;
* column stripes plus row stripes of range offset -> ``fixed_pattern``;
* pixel locking of the stereo matcher: the matching cost of a texture sampled
  at whole disparities and a parabola fitted through its minimum ->
  ``disparity_bias`` with a 1 px period.

Asserted: the effect is named and the gap at least halves.
"""

from __future__ import annotations

import math

import h5py
import numpy as np
import pytest
from scipy import integrate

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


def two_node_warm_up(times_s: np.ndarray) -> np.ndarray:
    """Range error (mm) of a camera warming up, from a two-node thermal network: the die (heat capacity 2 J/K)
    dissipates 0.05 W into the housing through 200 K/W, the housing (60 J/K) into the room through 40 K/W, both
    at room temperature at power-on. C_1 T_1' = P - (T_1 - T_2) / R_12, C_2 T_2' = (T_1 - T_2) / R_12 - T_2 / R_2a,
    integrated numerically (temperatures above the room's). The range error is -0.5 mm/K of die temperature
    (the driver's delay) and +2 mm/K of housing temperature (the lens mount), taken from the steady state."""
    c1, c2, r12, r2a, power = 2.0, 60.0, 200.0, 40.0, 0.05

    def rates(_: float, t: np.ndarray) -> list[float]:
        flow = (t[0] - t[1]) / r12
        return [(power - flow) / c1, (flow - t[1] / r2a) / c2]

    end = float(np.max(times_s))
    solution = integrate.solve_ivp(rates, (0.0, end), [0.0, 0.0], dense_output=True, rtol=1e-9, atol=1e-12)
    steady = np.array([power * (r12 + r2a), power * r2a])
    die, housing = solution.sol(np.clip(times_s, 0.0, end))
    return -0.5 * (die - steady[0]) + 2.0 * (housing - steady[1])


def test_two_node_thermal_warm_up_is_temperature_drift(plain, tmp_path):
    slow = stretch_time(plain("blaze101"), tmp_path / "slow.h5", 10.0)  # the sweep spread over 32 min
    result, names = _reconciled(slow, tmp_path, lambda px: two_node_warm_up(np.array([px.time_s]))[0])
    assert names[0] == "temperature_drift", names
    _halved(result)
    fitted = result.named[0].parameters
    assert len(fitted.get("terms", [])) == 1  # both time constants are seen
    # the fitted warm-up follows the true one over the sweep (up to the constant the offsets take)
    times = np.concatenate([o.times_s for o in result.observations if o.scene.procedure == "depth_sweep"])
    model = fitted["delta_mm"] * np.exp(-times / fitted["tau_s"]) + sum(
        term["delta_mm"] * np.exp(-times / term["tau_s"]) for term in fitted["terms"])
    difference = model - two_node_warm_up(times)
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


TEXTURE_CORRELATION_PX = 0.8  # the projected pattern's autocorrelation width, px


def matched_disparity(d: np.ndarray) -> np.ndarray:
    """The disparity a block matcher reports for true disparities ``d`` (px): the SSD cost of a texture with
    Gaussian autocorrelation exp(-s^2 / (4 w^2)) is 1 - exp(-(k - d)^2 / (4 w^2)) at the integer candidates k;
    the sub-pixel position is the vertex of the parabola through the best k and its two neighbours."""
    best = np.round(d)
    cost = [1.0 - np.exp(-((best + i) - d) ** 2 / (4 * TEXTURE_CORRELATION_PX**2)) for i in (-1, 0, 1)]
    with np.errstate(invalid="ignore", divide="ignore"):
        return best + (cost[0] - cost[2]) / (2 * (cost[0] - 2 * cost[1] + cost[2]))


def test_pixel_locking_of_a_parabola_fit_is_disparity_bias(plain, tmp_path):
    baseline = get_profile("d455").baseline_mm

    def error(px: Pixels):
        d = px.disparity_px(baseline)
        z_biased = px.focal_px * baseline / matched_disparity(d)
        return (z_biased - px.z_mm) * px.range_mm / px.z_mm

    result, names = _reconciled(plain("d455"), tmp_path, error)
    assert names[0] == "disparity_bias", names
    # the bias's fundamental: 2 <(matched - d) sin(2 pi d)> over a period (its phase is pi: the fit pulls towards
    # whole pixels); the parabola's bias has a weaker second harmonic besides
    d = np.linspace(5.0, 6.0, 2000, endpoint=False)
    fundamental = abs(2 * np.mean((matched_disparity(d) - d) * np.sin(2 * math.pi * d)))
    fitted = result.named[0].parameters
    assert abs(fitted["amplitude_px"] - fundamental) <= 0.2 * fundamental, (fitted, fundamental)
    assert abs(fitted["period_px"] - 1.0) <= 0.05, fitted
    _halved(result)
