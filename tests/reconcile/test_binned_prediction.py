"""What the binned prediction puts back: the offset calibration's coupling and the shading's bin mean.

Expected values are derived here from the geometry of a pinhole camera and the physics of the effect, not
taken from the prediction:

* A stereo camera whose disparity reads delta px too high reports z' = f b z / (f b + z delta) for a wall at z
  (disparity d = f b / z, f the focal length in px of the camera's own sensor, b the baseline). The offset
  calibration records the wall at 2 m where that camera saw it, z'(D) = R, so the wall stood at
  D = R f b / (f b - R delta), and every step calibrated by it stood R - D nearer than recorded.
* A stereo camera rounds its disparity d = f b / z + sigma_d n (n standard normal) to 1/32 px and stores
  f b / d + drift in whole millimetres: the mean stored depth is drawn here by Monte Carlo, pixel by pixel.
* A bin's share of pixels within the camera's range, on a depth rising linearly across the image, counts the
  pixels whose own depth (at their centres) lies within it.
* A bin's mean of a shaded light is the mean over its pixels of light times shading, each pixel on its own
  ray through a pinhole with c = (W - 1) / 2 and f = (W / 2) / tan(FOV / 2).
"""

from __future__ import annotations

import dataclasses
import math
import warnings
from collections import Counter

import numpy as np
import pytest
import tomli_w
from scipy import optimize, stats

from labctl.reconcile.goodness import statistics_goodness
from labctl.reconcile.noise_model import in_range_share, stored_depth_bias, tof_stored_bias
from labctl.reconcile.observe import bin_mean, observe_run
from labctl.reconcile.predict import (
    RENDERS_PER_STEP,
    SHIFT_REACH_MM,
    SHIFT_TOLERANCE_MM,
    Predictor,
    calibration_shift,
    pixel_nodes,
    pixels_damping,
    pixels_mean,
    range_spread,
    scene_and_pose,
)
from labctl.reconcile.residuals import STATISTICS, layout, raw_residuals, raw_statistics
from labctl.reconcile.workflow import Simulation, base_model, with_effect
from sim.model import parse_model
from sim.profiles import get_profile
from sim.stereo import StereoSensor
from sim.tof import ToFSensor
from tests.reconcile.runs import BACKENDS, CAMPAIGN, ROBOT, SIZES, simulated_run


@pytest.fixture(scope="module")
def d455_run(tmp_path_factory):
    """A plain d455 run: offset calibration at 2 m and a 0.4-4 m sweep in 900 mm steps, robot plates."""
    run = simulated_run(tmp_path_factory.mktemp("d455"), "d455", seed=41, sweep_step_mm=900)
    observations, info, _ = observe_run(run)
    return observations, info


def test_calibrated_walls_move_by_the_models_own_error_at_the_calibration(d455_run):
    observations, info = d455_run
    sim = Simulation(observations, info)
    base = base_model(info)
    delta = 0.1
    drifted = with_effect(base, "stereo_calibration_drift", {"disparity_offset_px": delta})
    plain = sim.predictor(base).wall_shifts(observations, sim.t0_s)
    shifts = sim.predictor(drifted).wall_shifts(observations, sim.t0_s)

    profile = get_profile("d455")
    width = SIZES["d455"][0]
    fb = (width / 2) / math.tan(math.radians(profile.fov_h_deg) / 2) * profile.baseline_mm
    calibration = next(o for o in observations if o.scene.procedure == "offset_calibration")
    recorded = calibration.scene.wall_distance_mm
    stood = recorded * fb / (fb - recorded * delta)
    expected = recorded - stood  # about -50 mm: the drifted camera saw the wall nearer than it stood

    laser = [o.scene.step_id for o in observations if o.scene.reference == "laser"]
    assert len(laser) >= 5 and set(shifts) == set(laser)
    assert {o.scene.step_id for o in observations if o.scene.reference == "robot"}.isdisjoint(shifts)
    # the model without the drift has its own small error there; the drift adds R - D to it (to 0.002 mm here:
    # the plain error is taken at D, not R; two fixed-point steps for the shift, not its root, left 0.04 mm)
    assert shifts[laser[-1]] - plain[laser[-1]] == pytest.approx(expected, abs=0.01)
    assert len({shifts[s] for s in laser}) == 1  # every step carries the one calibration's offset


def test_the_calibration_walls_shift_puts_the_models_central_depth_at_the_recorded_distance(d455_run):
    """The shift s of the calibrated walls is where the model's central depth of the calibration wall, placed s
    nearer than recorded, is the recorded distance R (the offset calibration's own definition: the camera's depth
    there is what the run records). It holds also where the camera's error changes fast with distance: a
    disparity bias of a = 0.058 px at a period of P = 1.68 px changes the depth by up to 2 pi a / P = 0.22 mm per
    mm of the wall's distance, so that stopping after two fixed-point steps from s = 0 leaves about 0.22^2 of the
    shift (tenths of a millimetre) at every calibrated wall."""
    observations, info = d455_run
    sim = Simulation(observations, info)
    model = with_effect(base_model(info), "disparity_bias",
                        {"amplitude_px": 0.058, "period_px": 1.68, "phase_rad": 0.65})
    predictor = sim.predictor(model)
    calibration = next(o for o in observations if o.scene.procedure == "offset_calibration")
    shift = predictor.wall_shifts(observations, sim.t0_s)[calibration.scene.step_id]
    central = predictor.central_depth(calibration.scene, calibration.times_s - sim.t0_s, shift)
    assert abs(shift) > 1.0  # the bias moves the calibration's depth by millimetres
    assert central == pytest.approx(calibration.scene.wall_distance_mm, abs=SHIFT_TOLERANCE_MM)


@pytest.mark.parametrize("amplitude_mm", [0.0, 2.0, 7.0])
def test_the_calibration_shift_is_the_root_also_where_the_error_changes_fast_with_distance(amplitude_mm):
    """A camera that reports a wall at z as C(z) = z + 5 mm + A sin(2 pi z / 50 mm), an error whose slope reaches
    2 pi A / 50 mm (0.88 at A = 7 mm; C still rises, so the wall it calibrates on is one): the calibration recorded
    at R = 2000 mm stood where C(z) = R (found here by bisection), and the shift is R minus that."""
    recorded = 2000.0

    def camera(z: float) -> float:
        return z + 5.0 + amplitude_mm * math.sin(2 * math.pi * z / 50.0)

    shift = calibration_shift(lambda s: camera(recorded - s) - recorded)
    stood = optimize.brentq(lambda z: camera(z) - recorded, recorded - 30.0, recorded + 10.0, xtol=1e-9)
    slope = 1 - 2 * math.pi * amplitude_mm / 50.0  # the least dC/dz: a depth miss of t is a distance miss <= t / it
    assert recorded - shift == pytest.approx(stood, abs=SHIFT_TOLERANCE_MM / slope)
    assert math.isnan(calibration_shift(lambda s: math.nan))  # nothing seen at the calibration: no shift


def test_a_step_without_the_calibrations_offset_is_not_moved(d455_run):
    observations, info = d455_run
    sim = Simulation(observations, info)
    model = with_effect(base_model(info), "stereo_calibration_drift", {"disparity_offset_px": 0.1})
    sweep = next(o for o in observations if o.scene.procedure == "depth_sweep")
    other = dataclasses.replace(sweep, scene=dataclasses.replace(
        sweep.scene, step_id="other", applied_offset_mm=sweep.scene.applied_offset_mm + 1.0))
    shifts = sim.predictor(model).wall_shifts([*observations, other], sim.t0_s)
    assert sweep.scene.step_id in shifts and "other" not in shifts


@pytest.fixture(scope="module")
def blaze101_run(tmp_path_factory):
    """A plain blaze-101 run: offset calibration at 2 m and a 0.4-4 m sweep in 900 mm steps, robot plates."""
    run = simulated_run(tmp_path_factory.mktemp("blaze101"), "blaze101", seed=43, sweep_step_mm=900)
    observations, info, _ = observe_run(run)
    return observations, info


@pytest.mark.parametrize("camera", ["blaze101", "d455"])
def test_a_wall_moved_within_the_reach_of_its_render_is_predicted_as_if_drawn_there(request, camera):
    """A laser-referenced wall moved by a shift within ``SHIFT_REACH_MM`` of one it was drawn at is taken between
    that render and one drawn further (``RenderMove``): a plane's ranges change linearly with the move, its light
    and phase to second order in the move over the range (1e-6 mm over 0.4 m). Its prediction is the one of the
    wall drawn at the shift itself; beyond the reach the wall is drawn anew. Without the move the depth would be
    off by up to the reach (1e-3 mm)."""
    observations, info = request.getfixturevalue(f"{camera}_run")
    sim = Simulation(observations, info)
    model = with_effect(base_model(info), *(("wiggling", {"amplitude_mm": 3.0, "period_mm": 900.0})
                                            if camera == "blaze101" else
                                            ("stereo_calibration_drift", {"disparity_offset_px": 0.1})))
    walls = [o for o in observations if o.scene.reference == "laser"]
    assert len(walls) >= 5
    start = 1.47
    for o in walls:
        times = o.times_s - sim.t0_s
        along = sim.predictor(model)
        at_start = along.predict(o.scene, times, start)
        for share in (1e-5, 0.3, -1.0, 1.5):
            shift = start + share * SHIFT_REACH_MM
            moved = along.predict(o.scene, times, shift)
            drawn = Predictor(model, info["width"], info["height"], info["bin_px"]).predict(o.scene, times, shift)
            assert np.array_equal(np.isfinite(moved.z), np.isfinite(drawn.z))
            assert np.nanmax(np.abs(moved.z - drawn.z)) < 1e-6, (o.scene.step_id, share)
            assert np.nanmax(np.abs(moved.intensity / drawn.intensity - 1.0)) < 1e-6, (o.scene.step_id, share)
            if share == 1.5:  # beyond the reach: drawn at the shift itself
                assert np.array_equal(moved.z, drawn.z, equal_nan=True)
            if abs(share) >= 0.3:  # the move itself is seen
                assert np.nanmax(np.abs(moved.z - at_start.z)) > 0.25 * abs(share) * SHIFT_REACH_MM


def _pinhole_cosines(width: int, height: int, fov_h_deg: float, fov_v_deg: float) -> np.ndarray:
    """cos of each pixel's ray to the optical axis."""
    u = (np.arange(width) - (width - 1) / 2) / ((width / 2) / math.tan(math.radians(fov_h_deg) / 2))
    v = (np.arange(height) - (height - 1) / 2) / ((height / 2) / math.tan(math.radians(fov_v_deg) / 2))
    return 1.0 / np.sqrt(1.0 + u[None, :] ** 2 + v[:, None] ** 2)


def test_shaded_light_is_the_bin_mean_of_the_pixels_light_times_their_vignetting():
    width, height, b, exponent = 160, 120, 4, 5.0
    model = parse_model(tomli_w.dumps({"camera": "amt100", "camera_overrides": {"width": width, "height": height},
                                       "effects": {"vignetting": {"exponent": exponent}}}), "test model")
    predictor = Predictor(model, width, height, b)
    profile = get_profile("amt100")
    cos_alpha = _pinhole_cosines(width, height, profile.fov_h_deg, profile.fov_v_deg)
    # light falling across the image like a lit wall's, cos^4, with a tilt of 20 % across the width
    tilt = np.linspace(0.9, 1.1, width)[None, :]
    light = cos_alpha**4 * tilt

    def bins(a: np.ndarray) -> np.ndarray:
        return a.reshape(height // b, b, width // b, b).mean(axis=(1, 3))

    truth = bins(light * cos_alpha**exponent)
    shaded = predictor.shade(bins(light))
    centre = bins(light) * _pinhole_cosines(width // b, height // b, profile.fov_h_deg, profile.fov_v_deg) ** exponent
    inner = (slice(1, -1), slice(1, -1))  # one-sided slopes at the border
    error = np.abs(np.log(shaded[inner] / truth[inner]))
    error_centre = np.abs(np.log(centre[inner] / truth[inner]))
    assert error_centre.max() > 3e-4  # the centre's factor alone: 0.05 %, a bias many standard errors wide
    assert error.max() < error_centre.max() / 100  # what is left is third order in the bin size


def test_statistics_rows_a_later_model_does_not_predict_are_left_out(d455_run):
    observations, info = d455_run
    sim = Simulation(observations, info)
    preds = sim.predict(base_model(info))
    lay = layout(observations, preds, "stereo")
    # a model fitted later predicts no valid fraction in the first compared bins of every step
    later = []
    for pred, mask in zip(preds, lay.family_masks("validity"), strict=True):
        valid = pred.valid_rate.copy()
        rows, cols = np.nonzero(mask)
        valid[rows[:3], cols[:3]] = np.nan
        later.append(dataclasses.replace(pred, valid_rate=valid))
    steps, families = statistics_goodness(lay, observations, later, raw_statistics(observations, later))
    assert {f.family for f in families} == set(STATISTICS)
    assert all(math.isfinite(f.floor) for f in families)
    assert all(math.isfinite(s.floor) for s in steps)


def test_a_model_that_leaves_a_compared_bin_dark_is_a_finite_misfit_only_there(d455_run):
    """A model a fit tries can leave a compared bin without light or noise (a target moved off the bin's rays): its
    ln ratio is infinite. The whitened rows stay finite,
    without a warning, and that model is far off in that bin and nowhere else; uncapped, the infinite row turned
    its step's intensity rows into NaN and the fit's sum of squares into an overflow."""
    observations, info = d455_run
    sim = Simulation(observations, info)
    preds = sim.predict(base_model(info))
    lay = layout(observations, preds, "stereo")
    step = next(i for i, m in enumerate(lay.i_masks) if m.sum() > 3)
    row, col = (int(a[0]) for a in np.nonzero(lay.i_masks[step]))
    dark = list(preds)
    dark[step] = dataclasses.replace(preds[step], intensity=preds[step].intensity.copy(),
                                     noise_mm=preds[step].noise_mm.copy())
    dark[step].intensity[row, col] = 0.0
    dark[step].noise_mm[row, col] = 0.0
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        before, after = (lay.profiled(*raw_residuals(observations, p), raw_statistics(observations, p))
                         for p in (preds, dark))
    assert np.isfinite(after).all()
    changed = np.abs(after - before) > 1e-9 * (1 + np.abs(before))
    # the dark bin's own row and, through its step's unknown gain, the rest of that step's intensity rows
    start = sum(int(m.sum()) for m in lay.z_masks) + sum(int(m.sum()) for m in lay.i_masks[:step])
    step_rows = slice(start, start + int(lay.i_masks[step].sum()))
    assert changed[step_rows].all()
    noise_changed = changed.copy()
    noise_changed[step_rows] = False
    assert noise_changed.sum() <= 1  # the noise row of the dark bin, where it is compared
    ln_ratio = np.log(observations[step].intensity[row, col])  # ln(measured / 0) is infinite: counted at the cap
    own = np.flatnonzero(lay.i_masks[step].ravel()).tolist().index(row * lay.i_masks[step].shape[1] + col)
    assert abs(after[start + own]) > abs(before[start + own]) + 10.0 * abs(ln_ratio)


def test_a_depth_signatures_profiled_rows_are_its_depth_rows_and_zeros(d455_run):
    """The empirical forms are fitted on the depth rows alone (``Layout.profiled_depth``; a pixel map's 117
    columns over every row took 2.7 GB): a signature that leaves the intensity and the statistics alone is zero on
    their rows once profiled, so nothing is lost."""
    observations, info = d455_run
    sim = Simulation(observations, info)
    lay = layout(observations, sim.predict(base_model(info)), "stereo")
    depth = np.random.default_rng(5).normal(size=len(lay.z_step))
    full = lay.profiled_rows(depth, np.zeros(len(lay.i_step)))
    np.testing.assert_array_equal(full[:len(depth)], lay.profiled_depth(depth))
    assert not full[len(depth):].any() and len(full) > 2 * len(depth)


def test_a_depth_row_without_a_prediction_leaves_the_others_profiled_without_it(d455_run):
    """A trial model that predicts no depth at a compared bin gives that row NaN. The other rows are the weighted
    least-squares residual of the depth nuisance fitted to them alone (solved here by ``np.linalg.lstsq`` on the
    weighted design), and the row stays NaN; before, the one NaN made every depth row NaN, which the fit's residual
    reads as zero: the whole depth family fitted perfectly."""
    observations, info = d455_run
    sim = Simulation(observations, info)
    lay = layout(observations, sim.predict(base_model(info)), "stereo")
    rng = np.random.default_rng(8)
    depth = rng.normal(size=len(lay.z_step)) + lay.z_nuisance @ rng.normal(size=lay.z_nuisance.shape[1])
    missing = np.zeros(len(depth), dtype=bool)
    missing[rng.choice(len(depth), 7, replace=False)] = True
    got = lay.profile_z(np.where(missing, np.nan, depth))
    root = np.sqrt(lay.z_weight[~missing])
    design = lay.z_nuisance[~missing]
    beta = np.linalg.lstsq(design * root[:, None], depth[~missing] * root, rcond=None)[0]
    np.testing.assert_allclose(got[~missing], depth[~missing] - design @ beta, atol=1e-9)
    assert np.isnan(got[missing]).all()
    np.testing.assert_allclose(lay.profile_z(depth), depth - lay.z_nuisance @ np.linalg.lstsq(
        lay.z_nuisance * np.sqrt(lay.z_weight)[:, None], depth * np.sqrt(lay.z_weight), rcond=None)[0], atol=1e-9)


def _stored_mean_by_monte_carlo(z: np.ndarray, sigma_d: float, step_d: float, fb: float, step_mm: float,
                                drift: float, draws: int, rng: np.random.Generator) -> float:
    """Mean over the pixels ``z`` of (stored depth - (z + drift)), each pixel's disparity drawn ``draws`` times."""
    d = fb / z[:, None] + sigma_d * rng.standard_normal((z.size, draws))
    stored = np.rint((fb / (np.rint(d / step_d) * step_d) + drift) / step_mm) * step_mm
    return float(np.mean(stored - (z[:, None] + drift)))


@pytest.mark.parametrize(("z_mm", "slope_mm_px", "drift"), [
    (806.0, 0.0, 0.0), (906.0, 0.0, 0.0), (1006.0, 0.0, 0.35), (2006.0, 0.0, 0.0), (806.0, 0.3, 0.0),
    (1206.0, 1.1, -0.2)])
def test_stored_stereo_depth_mean_is_that_of_both_roundings(z_mm, slope_mm_px, drift):
    """The d455's disparity grid (1/32 px) and millimetre output at the test size (f b 9904.5 px mm, sigma_d
    0.0248 px): the bins of a wall (and of a surface sloping along the rows) against a Monte Carlo of the
    pixels' roundings; the noise-free depth alone is off by up to 0.3 mm."""
    fb, sigma_d, step_d, b = 9904.5, 0.0248, 1 / 32, 4
    z = np.full((5, 5), z_mm) + slope_mm_px * b * np.arange(5)[None, :]  # bins of b pixels
    bias = stored_depth_bias(z, np.full_like(z, sigma_d), step_d, fb, 1.0, drift, b)
    pixels = z[2, 2] + slope_mm_px * (np.arange(b) - (b - 1) / 2)  # the centre bin's pixels along a row
    expected = _stored_mean_by_monte_carlo(pixels, sigma_d, step_d, fb, 1.0, drift, 400_000,
                                           np.random.default_rng(5))
    assert bias[2, 2] == pytest.approx(expected, abs=0.01)


def test_the_wall_means_of_a_plain_stereo_run_follow_the_prediction_step_by_step(tmp_path):
    """A plain d455 run of the reconcile tests' campaign, its sweep 0.6-1.5 m in 100 mm steps of 20 frames, no
    robot, whose laser reads without noise: after the offset calibration's common offset, each
    wall's mean residual is within 0.1 mm of the others (the noise-free depth alone left -0.28 mm at 806 mm,
    +0.17 mm at 906 mm: the roundings' bias)."""
    campaign = CAMPAIGN.format(backend=BACKENDS["d455"], seed=7, sweep_step_mm=100, robot="").replace(
        "start_mm = 400", "start_mm = 600").replace("stop_mm = 4000", "stop_mm = 1500").replace("frames = 10", "frames = 20")
    run = simulated_run(tmp_path, "d455", campaign=campaign, lab={"laser_noise_mm": 0.0, "laser_resolution_mm": 0.001})
    observations, info, _ = observe_run(run)
    sim = Simulation(observations, info)
    preds = sim.predict(base_model(info))
    means = [float(np.nanmean(o.z - p.z)) for o, p in zip(observations, preds, strict=True)
             if o.scene.procedure == "depth_sweep" and np.isfinite(o.z - p.z).any()]
    assert len(means) == 10
    assert max(means) - min(means) < 0.1  # 0.045 mm measured; 0.45 mm before the roundings were predicted


def _rounded_bias_by_fourier(mu: float, sigma: float, step: float, terms: int = 4000) -> float:
    """E[round_step(mu + sigma n)] - mu for standard normal n from the sawtooth's Fourier series,
    round(x) - x = sum_m (-1)^m sin(2 pi m x) / (pi m) (x in steps), each term damped by the normal
    characteristic function exp(-2 pi^2 m^2 sigma^2 / step^2)."""
    m = np.arange(1, terms + 1)
    x, s = mu / step, sigma / step
    return float(step * np.sum((-1.0) ** m * np.sin(2 * np.pi * m * x) / (np.pi * m) * np.exp(-2 * np.pi**2 * m**2 * s**2)))


@pytest.mark.parametrize(("z_mm", "sigma_mm", "slope_mm_px"), [
    (400.3, 0.05, 0.0), (400.8, 0.05, 0.0), (597.45, 0.2, 0.0), (1203.1, 0.5, 0.0), (806.37, 0.1, 0.06)])
def test_stored_tof_depth_mean_is_that_of_the_output_step(z_mm, sigma_mm, slope_mm_px):
    """An amt100-like camera storing whole millimetres, its depth noise small against the step at near range: a
    bin's expected stored depth minus the noise-free depth (``tof_stored_bias``) against the sawtooth's Fourier
    series (a wall: every pixel at z) and, for a surface sloping along the rows, the mean of that series over the
    bin's pixels; up to 0.3 mm where the noise-free depth alone is taken."""
    b = 4
    z = np.full((5, 5), z_mm) + slope_mm_px * b * np.arange(5)[None, :]
    bias = tof_stored_bias(z, np.full_like(z, sigma_mm), 1.0, b)
    pixels = z[2, 2] + slope_mm_px * (np.arange(b) - (b - 1) / 2)
    expected = np.mean([_rounded_bias_by_fourier(p, sigma_mm, 1.0) for p in pixels])
    assert bias[2, 2] == pytest.approx(expected, abs=0.005)
    assert abs(_rounded_bias_by_fourier(400.3, 0.05, 1.0)) > 0.25  # what the noise-free depth would miss


def _noise_free_pixels(predictor: Predictor, observation) -> tuple[np.ndarray, np.ndarray]:
    """The bin means of the measured camera's pixels without their temporal noise (the simulator's expected depth
    per pixel at the full size, which its frames average to: a ToF camera's range times the reported ray's
    z / range, a stereo camera's depth where valid), and the count of the pixels reported in each bin."""
    scene, pose = scene_and_pose(observation.scene, predictor.model, predictor.full_effects,
                                 predictor.full.wavelength_nm)
    if predictor.technology == "stereo":
        stereo = StereoSensor(predictor.full, predictor.full_effects)
        z, valid, _, _ = stereo.expected(stereo.render_scene(scene, pose), predictor.full.exposure_us)
        return bin_mean(np.where(valid, z, np.nan), predictor.bin_px)
    camera = ToFSensor(predictor.full, predictor.full_effects)
    tx, ty = np.broadcast_arrays(camera.geometry.tx.astype(float), camera.geometry.ty.astype(float))
    range_mm, _, _ = camera.expected(camera.render_scene(scene, pose), predictor.full.exposure_us)
    return bin_mean(range_mm / np.sqrt(1.0 + tx**2 + ty**2), predictor.bin_px)


def _noise_free_amplitude(predictor: Predictor, observation) -> tuple[np.ndarray, float]:
    """The measured ToF camera's pixels' light without its temporal noise (the simulator's expected amplitude at
    the full size, lens blur and defocus included, which its frames average to; 0 where it lights none), and its
    ambient light."""
    scene, pose = scene_and_pose(observation.scene, predictor.model, predictor.full_effects,
                                 predictor.full.wavelength_nm)
    camera = ToFSensor(predictor.full, predictor.full_effects)
    _, amplitude, ambient = camera.expected(camera.render_scene(scene, pose), predictor.full.exposure_us)
    return amplitude, ambient


def _noise_free_light(predictor: Predictor, observation) -> np.ndarray:
    """The bin means of ``_noise_free_amplitude`` over the pixels it lights (NaN where it lights none)."""
    amplitude, _ = _noise_free_amplitude(predictor, observation)
    return bin_mean(np.where(amplitude > 0, amplitude, np.nan), predictor.bin_px)[0]


@pytest.mark.parametrize("distortion", [None, {"k1": -0.1, "cloud": True}])
def test_a_frontal_walls_binned_tof_depth_is_its_pixels_mean_at_every_distance(tmp_path, distortion):
    """A plain blaze-101 run (sweep 0.4-4 m in 900 mm steps, no robot) whose laser reads without noise, and the
    same with a barrel distortion. A wall square to the optical axis is the plane z = D; its pixels read D up to
    their own range sampling (1.2e-6 of D from bin to bin) and, distorted, to their reported rays' z / range over
    their true rays'; every bin's predicted depth is the mean of its pixels, whatever its field angle (the range
    averaged over a bin's rays times the centre ray's z / range exceeds D by D w^2 (1 + 2 tan^2 theta) / 24:
    0.08 mm of spread over the bins at 4 m at this size; the centre ray's factor varies over the bin's pixels about
    its centre value, the render's mean over its own rays); the measured walls' means follow the prediction at
    every distance after the one offset they share."""
    campaign = CAMPAIGN.format(backend=BACKENDS["blaze101"], seed=5, sweep_step_mm=900, robot="")
    hidden = {"radial_distortion": distortion} if distortion else None
    run = simulated_run(tmp_path, "blaze101", hidden=hidden, campaign=campaign,
                        lab={"laser_noise_mm": 0.0, "laser_resolution_mm": 0.001})
    observations, info, _ = observe_run(run)
    sim = Simulation(observations, info)
    model = with_effect(base_model(info), "radial_distortion", distortion) if distortion else base_model(info)
    predictor = sim.predictor(model)
    preds = sim.predict(model)
    walls = [(o, p) for o, p in zip(observations, preds, strict=True) if o.scene.procedure == "depth_sweep"]
    assert len(walls) == 5
    means = []
    for o, p in walls:
        inner = p.z[2:-2, 2:-2]  # away from the image border, where the blur's reach changes the bins
        alone = predictor.predict(o.scene, o.times_s - o.times_s[0]).z[2:-2, 2:-2]  # the wall where recorded
        error = (alone - _noise_free_pixels(predictor, o)[0][2:-2, 2:-2]) / o.scene.wall_distance_mm
        # at most 2e-8 here; 7e-7 and 1.4e-6 with the light-weighted render and the centre value's curvature term,
        # 1.2e-5 distorted with the curvature of the bin's own rays on the centre rays' factor as well
        assert np.nanstd(error) < 1e-7 and abs(np.nanmean(error)) < 1e-7, (o.scene.step_id, error)
        means.append(float(np.nanmean(o.z[2:-2, 2:-2] - inner)))
    # 0.003 mm measured; 0.1 mm with the centre ray's factor
    assert max(means) - min(means) < 0.02, means


def test_a_far_walls_bins_average_a_short_wiggling_over_their_pixels(tmp_path):
    """A blaze-101 run (sweep 0.4-4 m in 900 mm steps, no robot) with a 0.5 mm wiggling of a 150 mm period. A
    wall's pixels each report their own range's error; a bin at the image's edge spans up to 100 mm of range at
    4 m, so its mean error is far below the error at its mean range (the pixels' sines average out). The
    measured camera's pixels are taken without their temporal noise (``_noise_free_pixels``), each bin's mean
    against the prediction."""
    wiggling = {"amplitude_mm": 0.5, "period_mm": 150.0, "phase_rad": 0.3}
    campaign = CAMPAIGN.format(backend=BACKENDS["blaze101"], seed=5, sweep_step_mm=900, robot="")
    run = simulated_run(tmp_path, "blaze101", hidden={"wiggling": wiggling}, campaign=campaign,
                        lab={"laser_noise_mm": 0.0, "laser_resolution_mm": 0.001})
    observations, info, _ = observe_run(run)
    sim = Simulation(observations, info)
    predictor = sim.predictor(with_effect(base_model(info), "wiggling", wiggling))
    plain = sim.predictor(base_model(info))
    k = 2 * math.pi / wiggling["period_mm"]
    for o in observations:
        times = o.times_s - o.times_s[0]
        predicted, without = predictor.predict(o.scene, times), plain.predict(o.scene, times)
        pixels = _noise_free_pixels(predictor, o)[0]
        error = predicted.z - pixels
        # at most 0.0048 mm (at 4 m, a bin at the border)
        assert np.nanmax(np.abs(error)) < 0.01, (o.scene.step_id, np.nanmax(np.abs(error)))
        if o.scene.wall_distance_mm == 4000.0:  # what the error at each bin's mean range misses there: 0.14 mm
            at_centre = without.z + 0.5 * np.sin(k * without.range_mm + 0.3) * without.z_per_range
            assert np.nanmax(np.abs(at_centre - pixels)) > 0.1


@pytest.mark.parametrize(("bin_px", "span_rad"), [(1, 0.0), (4, 20.0), (5, 20.0), (8, 20.0), (16, 3.8)])
def test_the_pixels_mean_of_a_sine_over_a_ramp_is_damped_by_the_dirichlet_kernel(bin_px, span_rad):
    """A value rising across each bin by s_v per pixel down and s_u across, the sine's phase changing by up to
    ``span_rad`` over the bin's side: the mean over the bin's pixels of sin(k v + phi), summed here pixel by pixel,
    is sin(k v + phi) D(k s_v) D(k s_u) with the Dirichlet kernel D(x) = sin(b x / 2) / (b sin(x / 2)) (the mean
    of cos(x o) over the b symmetric pixel offsets o; a bin of one pixel, 1). A bin of 16 pixels is taken by
    quadrature, here over the span of a 150 mm wiggling across a far wall's bin at the image's edge."""
    rng = np.random.default_rng(7)
    k, phi = 2 * math.pi / 150.0, 0.7
    top = span_rad / (k * bin_px)
    v, s_v, s_u = rng.uniform(0, 5000, (3, 6)), rng.uniform(-top, top, (3, 6)), rng.uniform(-top, top, (3, 6))
    offsets = np.arange(bin_px) - (bin_px - 1) / 2
    by_pixel = np.mean([np.sin(k * (v + s_v * a + s_u * b) + phi) for a in offsets for b in offsets], axis=0)
    expected = np.sin(k * v + phi)
    for s in (s_v, s_u):
        x = k * s
        expected = expected * (np.sin(bin_px * x / 2) / (bin_px * np.sin(x / 2)) if bin_px > 1 else 1.0)
    np.testing.assert_allclose(by_pixel, expected, atol=1e-12)
    np.testing.assert_allclose(pixels_mean(lambda r: np.sin(k * r + phi), v, bin_px, (s_v, s_u)), by_pixel, atol=1e-12)
    np.testing.assert_allclose(pixels_mean(lambda r: np.sin(k * r + phi), v, bin_px, (s_v, s_u), stacked=True),
                               by_pixel, atol=1e-12)  # every position at once, as a function of the value alone
    np.testing.assert_allclose(np.sin(k * v + phi) * pixels_damping(k, (s_v, s_u), bin_px), by_pixel, atol=1e-12)


@pytest.mark.parametrize(("bin_px", "most"), [(3, 8), (8, 8), (9, 8), (16, 8), (40, 8), (4, 4), (16, 4)])
def test_a_large_bins_pixel_quadrature_holds_the_moments_of_its_pixel_centres(bin_px, most):
    """The positions and weights ``pixels_mean`` takes a bin's side at: its b pixel centres, each 1 / b, up to
    ``most`` pixels; beyond, ``most`` nodes whose weighted powers o^d equal the mean of o^d over the b pixel
    centres for every degree d below 2 ``most`` (a Gauss quadrature), within the bin. The ToF camera's 4 nodes on
    a 16-pixel side take the mean of a sine whose phase changes by 3.8 rad across it (a 150 mm wiggling on a far
    wall's edge bin) to within 3e-5 of its amplitude."""
    nodes, weights = pixel_nodes(bin_px, most)
    centres = np.arange(bin_px) - (bin_px - 1) / 2
    assert len(nodes) == min(bin_px, most) and np.all(np.abs(nodes) <= centres[-1])
    for degree in range(2 * most):
        scale = np.mean(np.abs(centres) ** degree)
        assert np.sum(weights * nodes**degree) == pytest.approx(np.mean(centres**degree), abs=1e-12 * scale)
    x = 3.8 / bin_px
    assert abs(np.sum(weights * np.cos(x * nodes)) - np.mean(np.cos(x * centres))) < 3e-5


def test_a_ranges_spread_is_taken_one_sided_at_the_border_and_beside_an_edge():
    """A range z = a + b i + c j + d i^2 over bins (i down, j across) of 4 pixels: its slope per pixel down is
    (b + d (2 i)) / 4 from the central difference, and at the first and last row and beside a bin marked as an
    edge, the one-sided difference with the smooth neighbour, (b + d (2 i +- 1)) / 4; its curvature per pixel^2
    down 2 d / 16 where both neighbours are smooth, else 0."""
    i, j = np.mgrid[0:6, 0:5].astype(float)
    a, b, c, d = 3000.0, 40.0, -12.0, 1.5
    z = a + b * i + c * j + d * i**2
    smooth = np.ones(z.shape, dtype=bool)
    smooth[3, 2] = False  # an edge runs through one bin
    (down, across), (c_down, c_across) = range_spread(z, 4, smooth)
    central = (b + 2 * d * i) / 4
    np.testing.assert_allclose(down[1:-1, [0, 1, 3, 4]][[0, 3], :], central[1:-1, [0, 1, 3, 4]][[0, 3], :])
    np.testing.assert_allclose(down[0], (b + d * (2 * 0 + 1)) / 4 + 0 * j[0])  # the first row: ahead only
    np.testing.assert_allclose(down[-1], (b + d * (2 * 5 - 1)) / 4 + 0 * j[0])  # the last row: behind only
    assert down[2, 2] == pytest.approx((b + d * (2 * 2 - 1)) / 4)  # above the edge: behind only
    assert down[4, 2] == pytest.approx((b + d * (2 * 4 + 1)) / 4)  # below it: ahead only
    assert down[3, 2] == 0.0 and c_down[3, 2] == 0.0  # the edge's own bin
    np.testing.assert_allclose(c_down[1, :], 2 * d / 16)
    assert c_down[0, 0] == 0.0 and c_down[2, 2] == 0.0
    np.testing.assert_allclose(across[:, 0], c / 4)  # linear across: the one-sided difference at the border is exact
    np.testing.assert_allclose(across[0, 1:-1], c / 4)
    np.testing.assert_allclose(c_across, 0.0, atol=1e-12)


def test_a_tilted_plates_binned_tof_depth_is_the_plain_mean_of_its_pixels(tmp_path):
    """The blaze-101's robot plates at -60...60 deg, 3 m away, 20 mm behind the circle's centre. A bin's
    measured depth is the plain mean over its pixels, each a range over its own footprint times its reported
    ray's z / range; here that measured camera's pixels are taken without their temporal noise (the
    simulator's expected range per pixel at the full 160 x 120, which its frames average to).

    The bin-grid render weights its rays by their light (1 / r^2), which pulls the mean towards a tilted
    plate's near side by about 2 var(z) / z (var(z) = z^2 tan^2(theta) w^2 / 16 for rays spread over the
    4-pixel bin's w = 0.029 rad): 0.06 mm at 20 deg, 1.3 mm at 40 deg. And its 2 x 2 samples per bin already
    hold part of the bin's curvature, (k^2 - 1) / (12 k^2) of its spread (``bin_curvature``)."""
    campaign = CAMPAIGN.format(backend=BACKENDS["blaze101"], seed=5, sweep_step_mm=1800, robot=ROBOT)
    model = {"target_misalignment": {"offset_mm": 20.0}}
    run = simulated_run(tmp_path, "blaze101", hidden=model, campaign=campaign)
    observations, info, _ = observe_run(run)
    predictor = Predictor(with_effect(base_model(info), "target_misalignment", model["target_misalignment"]),
                          info["width"], info["height"], info["bin_px"])
    plates = [o for o in observations if o.scene.robot_angle_deg is not None]
    assert len(plates) == 14
    for o in plates:
        pixels, count = _noise_free_pixels(predictor, o)
        predicted = predictor.predict(o.scene, o.times_s - o.times_s[0])
        inner = (count == info["bin_px"] ** 2) & ~predicted.edge
        error = (predicted.z - pixels)[inner]
        # at most 0.032 mm here (at 60 deg); 2.0 mm with the light-weighted render and the centre-value curvature
        assert inner.sum() > 300 and abs(error.mean()) < 0.05, (o.scene.step_id, error.mean())
        if abs(o.scene.robot_angle_deg) == 40:  # what the light weighting alone would miss by
            weighted = predictor._render(o.scene)
            assert np.nanmean((weighted.z_dom - weighted.z_plain)[inner]) < -1.0


def test_a_tilted_plates_binned_stereo_depth_averages_a_pixel_locking_over_its_pixels(tmp_path):
    """The d455's robot plates at -60...60 deg with a 0.045 px pixel locking of period 1.57 px (``disparity_bias``,
    a periodic error in each pixel's own disparity). A tilted plate's bin spreads its pixels over a range of
    disparity, and the bin's measured depth is the mean of the error over them, not the error at the bin's mean
    disparity. The measured camera's pixels are taken without their temporal noise (the simulator's expected
    depth per pixel at the full 160 x 120, which its frames average to)."""
    hidden = {"disparity_bias": {"amplitude_px": 0.0448, "period_px": 1.5692, "phase_rad": 2.4367}}
    run = simulated_run(tmp_path, "d455", hidden=hidden, seed=71634)
    observations, info, _ = observe_run(run)
    predictor = Predictor(with_effect(base_model(info), "disparity_bias", hidden["disparity_bias"]),
                          info["width"], info["height"], info["bin_px"])
    plates = [o for o in observations if o.scene.robot_angle_deg is not None]
    assert len(plates) == 14
    for o in plates:
        pixels, count = _noise_free_pixels(predictor, o)
        rendered = predictor._render(o.scene)
        binned = predictor._pixels_reported(predictor._pixel_weighted(rendered.z_dom, rendered.z_plain))
        inner = (count == info["bin_px"] ** 2) & np.isfinite(binned) & ~predictor.predict(o.scene, o.times_s).edge
        error = (binned - pixels)[inner]
        # at most 0.003 mm from bin to bin here; 0.29 mm with the error taken at the bin's mean disparity
        assert inner.sum() > 300 and np.abs(error).max() < 0.05, (o.scene.step_id, np.abs(error).max())


@pytest.mark.parametrize("cut_mm,at_px,slope_mm_px", [(6000.0, 10.3, 174.0), (6000.0, 13.6, -55.0),
                                                     (600.0, 9.7, 30.0)])
def test_a_bins_share_within_the_range_counts_its_pixels_on_a_steep_surface(cut_mm, at_px, slope_mm_px):
    """A depth rising by ``slope_mm_px`` per pixel along the rows of a 6 x 5-bin map of 4-pixel bins, reaching an
    end of the range [600, 6000] mm ``at_px`` pixels from the image's left edge, inside a bin: pixel column u
    (its centre u + 1/2 from the edge) has depth cut + slope (u + 1/2 - at), each bin's mean is its pixels', and
    its share is the count of its pixels within the range over 4; its mean alone would put it wholly in or out."""
    bin_px, width_bins = 4, 6
    u = np.arange(width_bins * bin_px)
    pixel_z = cut_mm + slope_mm_px * (u + 0.5 - at_px)
    inside = ((pixel_z >= 600.0) & (pixel_z <= 6000.0)).reshape(width_bins, bin_px).mean(axis=1)
    assert ((inside > 0) & (inside < 1)).any()  # a bin straddles the cut
    z = np.tile(pixel_z.reshape(width_bins, bin_px).mean(axis=1), (5, 1))
    np.testing.assert_allclose(in_range_share(z, 600.0, 6000.0, bin_px), np.tile(inside, (5, 1)))


@pytest.mark.parametrize("low_mm", [100.0, 1350.0, 1390.0])
def test_a_bins_share_is_whole_where_its_pixels_lie_within_the_range_and_none_without_a_depth(low_mm):
    """A plane rising 20 mm a pixel across 6 x 5 bins of 4 pixels (bin means 1410-1810 mm), two bins without a
    depth (NaN), the range [``low_mm``, 7000] mm: the lowest pixels, column 0, lie at 1380 mm, 30 mm below the
    lowest bin mean. From 100 mm every pixel is within the range and every bin with a depth has the share 1;
    from 1350 mm too, though the range ends nearer the map than its span of 400 mm; from 1390 mm the first
    column's bins hold one pixel column below the range (share 3/4). The bins without a depth have none."""
    bin_px = 4
    u = np.arange(6 * bin_px)
    pixel_z = 1400.0 + 20.0 * (u + 0.5 - 1.5)
    z = np.tile(pixel_z.reshape(6, bin_px).mean(axis=1), (5, 1))
    z[1, 2] = z[3, 4] = np.nan
    expected = np.tile(((pixel_z >= low_mm) & (pixel_z <= 7000.0)).reshape(6, bin_px).mean(axis=1), (5, 1))
    expected[np.isnan(z)] = 0.0
    assert (expected[:, 0] == (0.75 if low_mm == 1390.0 else 1.0)).all()
    np.testing.assert_array_equal(in_range_share(z, low_mm, 7000.0, bin_px), expected)


@pytest.fixture(scope="module")
def wall_beyond_range(tmp_path_factory):
    """The blaze-101's plain test campaign without the robot (sweep in 1800 mm steps), a predictor of a camera
    whose range ends at 2500 mm (``max_range_mm``), and the sweep's wall at 2200 mm."""
    campaign = CAMPAIGN.format(backend=BACKENDS["blaze101"], seed=5, sweep_step_mm=1800, robot="")
    run = simulated_run(tmp_path_factory.mktemp("beyond_range"), "blaze101", campaign=campaign)
    observations, info, _ = observe_run(run)
    plain = base_model(info)
    model = plain.model_copy(update={"camera_overrides": plain.camera_overrides.model_copy(
        update={"max_range_mm": 2500.0})})
    predictor = Predictor(model, info["width"], info["height"], info["bin_px"])
    wall = next(o for o in observations if o.scene.procedure == "depth_sweep" and o.scene.wall_distance_mm
                and abs(o.scene.wall_distance_mm - 2200) < 50)
    return observations, info, predictor, wall


def test_a_tof_bins_valid_share_is_that_of_its_pixels_within_the_range(wall_beyond_range):
    """The blaze-101's wall at 2200 mm, seen by a camera whose range ends at 2500 mm (``max_range_mm``): a pixel's
    range is the wall's distance over the cosine of its field angle, 2200 mm on the axis and 2850 mm in the
    corners, so the range's end runs through the image on a ring. The camera cuts pixel by pixel; each bin's
    predicted valid fraction is the share of its pixels the measured camera (the simulator's expected range per
    pixel at the full 160 x 120) reports, to within one of its 16 pixels where the ring curves within the bin
    (its mean alone would put a bin wholly in or out)."""
    observations, info, predictor, wall = wall_beyond_range
    _, count = _noise_free_pixels(predictor, wall)
    predicted = predictor.predict(wall.scene, wall.times_s - wall.times_s[0])
    share = count / info["bin_px"] ** 2
    inner = ~predicted.edge
    straddling = (share > 0) & (share < 1) & inner
    assert straddling.sum() > 40
    error = predicted.valid_rate[inner] - share[inner]
    assert np.abs(error).max() <= 1 / 16 + 1e-9 and abs(error[straddling[inner]].mean()) < 0.01


def test_a_tof_bins_depth_and_light_continue_beyond_the_range_only_its_validity_drops(wall_beyond_range):
    """The wall and camera of the test above. A frontal wall's depth is its distance at every pixel, and its light
    falls smoothly with the field angle, whether the camera reports the pixel or not: the range's end cuts what
    the camera reports, not the light or the depth the bin's pixels would read. The bins wholly beyond it keep
    the wall's depth and a light continuing their reported neighbours' (the field angle's fall over one bin,
    about 8 % at the corners); only their valid fraction (0) and noise (none) know the cut, and they are not
    compared. A model that moves a bin across the range's end then changes its comparison by the pixels it cuts
    (the validity family), not by a jump of its depth and intensity rows: such a jump made a cliff in the
    residual that stopped a fit of a strong multipath short of the truth."""
    observations, info, predictor, wall = wall_beyond_range
    predicted = predictor.predict(wall.scene, wall.times_s - wall.times_s[0])
    inner = ~predicted.edge
    beyond = inner & ~predicted.reported
    inside = inner & predicted.reported
    assert beyond.sum() > 10 and inside.sum() > 100
    assert np.all(predicted.valid_rate[beyond] == 0) and np.all(np.isnan(predicted.noise_mm[beyond]))
    assert np.abs(predicted.z[inner] - wall.scene.wall_distance_mm).max() < 5.0
    pairs = 0
    for axis in (0, 1):
        for a, b in ((beyond, inside), (inside, beyond)):
            across = np.roll(a, 1, axis=axis) & b  # a bin of one side whose neighbour before it is of the other
            across[(0,) if axis == 0 else (slice(None), 0)] = False
            ratio = predicted.intensity[across] / np.roll(predicted.intensity, 1, axis=axis)[across]
            pairs += across.sum()
            assert np.all(np.abs(np.log(ratio)) < 0.15)
    assert pairs > 10
    lay = layout(observations, [predictor.predict(o.scene, o.times_s - o.times_s[0]) for o in observations])
    assert not (lay.z_masks[observations.index(wall)] & beyond).any()


@pytest.mark.parametrize("camera", ["blaze101", "flexx2"])
def test_a_face_masks_compared_bins_hold_their_pixels_mean_light(tmp_path, camera):
    """The silicone face mask 300 mm before the wall at 700 mm. A bin's measured intensity is the mean of its
    pixels' light (the simulator's expected amplitude at the full size, which the frames average to, lens blur
    included). The bin-grid render samples each bin with 2 x 2 rays: where the mask folds (the nose hiding part
    of the cheek: the light of neighbouring rays bends by up to 140 %) they cannot hold its mean, and such bins
    are left out (``light_folds``; 9 % off their pixels' mean on the blaze-101). Every compared bin's light is
    its pixels' mean within 2 %, after the one gain they share: on the flexx2's larger mask the light's smooth
    curvature within a bin leaves up to 1.3 %, which the 2 x 2 rays and the second differences of neighbouring
    bins (``Predictor.pixels_light``) miss."""
    campaign = CAMPAIGN.format(backend=BACKENDS[camera], seed=5, sweep_step_mm=3600, robot="").replace(
        "[sim]", '[[procedure]]\nkind = "face_mask"\ndistance_mm = 700\nframes = 10\n[sim]')
    observations, info, _ = observe_run(simulated_run(tmp_path, camera, campaign=campaign))
    mask = next(o for o in observations if o.scene.procedure == "face_mask")
    predictor = Predictor(base_model(info), info["width"], info["height"], info["bin_px"])
    predicted = predictor.predict(mask.scene, mask.times_s - mask.times_s[0])
    pixels = _noise_free_light(predictor, mask)
    compared = ~predicted.edge & np.isfinite(pixels) & (predicted.intensity > 0)
    ratio = np.log(pixels[compared] / predicted.intensity[compared])
    assert compared.sum() > 500
    assert np.max(np.abs(ratio - np.median(ratio))) < 0.02


def test_a_lit_walls_binned_light_is_its_pixels_mean_as_the_lens_blurs_it(tmp_path):
    """A plain amt100 run (sweep 0.4-4 m in 1200 mm steps, no robot), predicted without and with a vignetting. A
    bin's measured intensity is the mean of its pixels' light (the simulator's expected amplitude at the full
    size, lens blur and defocus included). The bin-grid render samples each bin with 2 x 2 rays; the light of a
    wall curves over the field, so the bin's mean over its pixels differs from theirs to second order, and the
    lens spreads each pixel's light over its PSF, which adds the same order again: without either term the
    bins' light was off by up to 6e-5 of itself, centre against corners (which a vignetting's exponent fitted
    7e-5 low took up), with the bin's curvature alone by 3e-5. Every bin away from the border is its pixels'
    mean within 2e-6 after the one gain they share (at most 8e-7 measured)."""
    campaign = CAMPAIGN.format(backend=BACKENDS["amt100"], seed=5, sweep_step_mm=1200, robot="")
    observations, info, _ = observe_run(simulated_run(tmp_path, "amt100", campaign=campaign))
    walls = [o for o in observations if o.scene.procedure == "depth_sweep"]
    assert len(walls) == 4
    for model in (base_model(info), with_effect(base_model(info), "vignetting", {"exponent": 5.4})):
        predictor = Predictor(model, info["width"], info["height"], info["bin_px"])
        for o in walls:
            predicted = predictor.predict(o.scene, o.times_s - o.times_s[0]).intensity[2:-2, 2:-2]
            pixels = _noise_free_light(predictor, o)[2:-2, 2:-2]
            assert np.isfinite(pixels).all()  # every inner bin lit: none left out of the comparison below
            ratio = np.log(pixels / predicted)
            assert np.max(np.abs(ratio - np.median(ratio))) < 2e-6, (o.scene.step_id, model.effects)


def test_a_fit_keeps_a_few_renders_per_step_not_one_per_try(d455_run):
    """A fit of a lens distortion renders every step anew at each value it tries: the shared cache keeps the
    ``RENDERS_PER_STEP`` last used per step (a complete campaign's fit of 50 tries kept all 50 sets: 10 GB),
    and the values it comes back to render again, identical. A multipath's parameters act after the render,
    which only keeps the phasors for it: one render serves every value."""
    observations, info = d455_run
    sim = Simulation(observations, info)
    base = base_model(info)
    first = sim.predict(with_effect(base, "radial_distortion", {"k1": 0.0}))
    for k1 in (0.01, 0.02, 0.03, 0.04, 0.05, 0.0):
        again = sim.predict(with_effect(base, "radial_distortion", {"k1": k1}))
    held = Counter(key[0] for key in sim.cache if len(key) == 2 and key[0].startswith("0"))
    assert set(held.values()) == {RENDERS_PER_STEP}
    np.testing.assert_array_equal(again[0].z, first[0].z)

    tof = parse_model('camera = "blaze101"')
    step = observations[0].scene
    keys = {Predictor(with_effect(tof, "multipath", {"strength": s, "extra_path_mm": 900.0 + s}), 160, 120, 4)
            .geometry_key(step) for s in (0.05, 0.1)}
    assert len(keys) == 1 and "multipath" in keys.pop()


def test_where_the_right_camera_sees_follows_the_true_depth_not_the_reported_one(d455_run):
    """The d455's right camera sees a point of the left image's column u at u - f b / z, z the point's true
    depth: a range error of the reported depth (``range_scale``) moves no point out of the right image. On the
    robot's frontal plates at 850 mm (placed by the robot, not by the offset calibration, so the same in both
    models), whose left columns up to f b / z of the full sensor are out of it, the predicted valid fraction of
    every bin is the same with a 5 % range error as without (the leftmost bins lower when it followed the
    reported depth)."""
    observations, info = d455_run
    sim = Simulation(observations, info)
    base = base_model(info)
    plain, scaled = sim.predict(base), sim.predict(with_effect(base, "range_scale", {"scale": -0.05}))
    plates = [k for k, o in enumerate(observations) if o.scene.robot_angle_deg == 0]
    assert plates
    for k in plates:
        left = plain[k].valid_rate[:, :3]
        assert np.nanmin(left[:, 0]) < 0.9  # the leftmost bins hold columns the right camera does not see
        np.testing.assert_allclose(scaled[k].valid_rate[:, :3], left, atol=1e-12)


def test_a_tof_bins_valid_fraction_is_its_pixels_mean_where_the_light_slopes_across_the_cut(tmp_path):
    """The amt100's robot plates (the plain test campaign). The simulator takes a pixel-frame as valid when its
    amplitude A + sigma_A n (n standard normal, sigma_A^2 = (2 A + ambient) / 2) lies between the confidence cut
    and the saturation (sim/kernels.py, ``tof_frame``): a pixel whose noise-free amplitude is A is valid with the
    probability P(A) that a normal variable falls in that interval, and a bin's valid fraction is the mean of P
    over its 16 pixels. Where a plate's light crosses the cut, P is far from linear over the bin's pixels; taken
    at the bin's mean amplitude, the fractions of the bins between 2 % and 98 % valid were too sharp (too high
    above one half, too low below) by 0.036 on average and up to 0.075."""
    campaign = CAMPAIGN.format(backend=BACKENDS["amt100"], seed=5, sweep_step_mm=1800, robot=ROBOT)
    run = simulated_run(tmp_path, "amt100", campaign=campaign)
    observations, info, _ = observe_run(run)
    predictor = Predictor(base_model(info), info["width"], info["height"], info["bin_px"])
    p, a_ref = predictor.full, ToFSensor(predictor.full, predictor.full_effects).a_ref
    cut, saturation = p.confidence_threshold_ratio * a_ref, p.saturation_ratio * a_ref
    errors = []
    for o in (o for o in observations if o.scene.robot_angle_deg is not None):
        amplitude, ambient = _noise_free_amplitude(predictor, o)
        sigma = np.sqrt((2.0 * amplitude + ambient) / 2.0)
        probability = np.where(amplitude > 0, stats.norm.cdf(saturation, amplitude, sigma)
                               - stats.norm.cdf(cut, amplitude, sigma), 0.0)
        truth = bin_mean(probability, predictor.bin_px)[0]
        lit = bin_mean(np.where(amplitude > 0, 1.0, np.nan), predictor.bin_px)[1]
        predicted = predictor.predict(o.scene, o.times_s - o.times_s[0])
        inner = (lit == info["bin_px"] ** 2) & ~predicted.edge & (truth > 0.02) & (truth < 0.98)
        errors.append((predicted.valid_rate - truth)[inner])
    error = np.concatenate(errors)
    assert len(error) > 100
    # 0.0015 on average and at most 0.018 here (408 bins); at the bins' mean amplitude 0.036 and 0.075
    assert np.abs(error).mean() < 0.005 and np.abs(error).max() < 0.03, (np.abs(error).mean(), np.abs(error).max())
    # each step keeps its last valid fraction with its light: a model that darkens the corners gets its own
    shared: dict = {}
    vignetted = with_effect(base_model(info), "vignetting", {"exponent": 6.0})
    for model in (base_model(info), vignetted):
        kept = Predictor(model, info["width"], info["height"], info["bin_px"], shared)
        fresh = Predictor(model, info["width"], info["height"], info["bin_px"])
        for o in observations:
            times = o.times_s - o.times_s[0]
            assert np.array_equal(kept.predict(o.scene, times).valid_rate, fresh.predict(o.scene, times).valid_rate)


def test_the_band_the_right_camera_misses_is_taken_at_each_pixel_columns_depth(tmp_path):
    """The d455's robot plates with a 36.5 mm camera axis offset (the robot turns the plates about an axis that
    far from the camera's), which brings the plates at -60 deg to the image's left edge at 2.2 m. There the plate's
    depth falls by 16 mm a pixel of 160 towards the edge, the right camera sees a pixel column u while
    u - f b / z >= 0 at that column's own depth, and f b / z is 4.5-4.7 px, at the rounding's edge: the leftmost
    bins' valid fraction, as the simulated camera's frames give it, is predicted within 2 points (one of a bin's
    four pixel columns, 25 points, off with the band taken at the bin's mean depth)."""
    hidden = {"camera_axis_offset": {"offset_mm": 36.5}}
    run = simulated_run(tmp_path, "d455", hidden=hidden, seed=20988)
    observations, info, _ = observe_run(run)
    sim = Simulation(observations, info)
    predictions = sim.predict(with_effect(base_model(info), "camera_axis_offset", hidden["camera_axis_offset"]))
    steep = [(o, p) for o, p in zip(observations, predictions, strict=True) if o.scene.robot_angle_deg == -60]
    assert len(steep) == 2
    for o, p in steep:
        left = ~p.edge[:, :3] & (p.valid_rate[:, :3] > 0)  # the plate's bins beside the band, not at its edges
        measured, predicted = o.valid_rate[:, :3][left], p.valid_rate[:, :3][left]
        assert left.sum() >= 20 and measured.min() < 0.9, (o.scene.step_id, left.sum(), measured.min())
        np.testing.assert_allclose(predicted, measured, atol=0.02, err_msg=o.scene.step_id)
