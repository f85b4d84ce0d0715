"""Each effect, switched on, changes exactly what its formula says (and nothing when off).

Sensors with and without an effect share seed and step, so their frames carry
the same noise and differences isolate the effect.
"""

import math

import cv2
import numpy as np
import pytest

from labctl.reconcile.candidates import SIGNATURE_NODES
from metrics.sfr import edge_sfr
from sim.effects import EFFECTS
from sim.effects.base import valid_range
from sim.effects.diffuse_floor_multipath import bounce_phasor
from sim.effects.fixed_pattern import Params, cell_average, offset_map_mm
from sim.errors import ModelError
from sim.geometry import Pose
from sim.materials import get_material
from sim.model import default_model_text, parse_model
from sim.scenes.targets import build_scene, plate_scene
from sim.sensor import default_coc_px
from sim.sensor import edge_sfr as analytic_sfr
from sim.stereo import StereoSensor
from sim.tof import ToFSensor

SMALL = "[camera_overrides]\nwidth = 160\nheight = 120\n"


def make(camera="blaze101", effects="", overrides=SMALL, base=True):
    text = (default_model_text(camera) if base else f'camera = "{camera}"\n') + effects + overrides
    model = parse_model(text)
    profile = model.profile()
    cls = ToFSensor if profile.technology == "tof" else StereoSensor
    return cls(profile, model.effect_params())


def prep(sensor, target="wall", distance=1500.0, params=None, pose=None, **kw):
    scene = build_scene(target, params or {}, sensor.profile.wavelength_nm, distance)
    return sensor.prepare(scene, pose or Pose.at_origin(), sensor.profile.exposure_us, 3, 7, **kw)


def test_vocabulary_is_the_contract():
    assert set(EFFECTS) == {
        "range_offset", "range_scale", "wiggling", "temperature_drift", "intensity_related_error", "vignetting",
        "radial_distortion", "fov_error", "defocus", "quantization", "flying_pixels", "multipath",
        "material_bias", "target_misalignment", "camera_axis_offset", "fixed_pattern", "floor_multipath",
        "disparity_bias", "empirical_range", "empirical_pixel_map", "ambient_light", "log_amplitude_error",
        "stereo_calibration_drift", "diffuse_floor_multipath",
    }


def test_effect_parameters_are_validated_with_ranges():
    with pytest.raises(Exception, match="wiggling.*amplitude_mm"):
        parse_model('camera = "blaze101"\n[effects.wiggling]\namplitude_mm = -3\n')
    with pytest.raises(Exception, match="applies to tof cameras, not stereo"):
        parse_model('camera = "d455"\n[effects.multipath]\nstrength = 0.1\n')
    with pytest.raises(Exception, match="unknown parameter 'wavelength'"):
        parse_model('camera = "blaze101"\n[effects.wiggling]\nwavelength = 3\n')


def test_range_offset_and_scale():
    base = prep(make())
    off = prep(make(effects="[effects.range_offset]\noffset_mm = 7.5\n"))
    scl = prep(make(effects="[effects.range_scale]\nscale = 0.01\n"))
    np.testing.assert_allclose(off.range_mm - base.range_mm, 7.5, atol=1e-3)
    np.testing.assert_allclose(scl.range_mm, base.range_mm * 1.01, rtol=1e-6)
    np.testing.assert_array_equal(off.amplitude, base.amplitude)


def test_empirical_corrections_interpolate_their_tables():
    table = "[effects.empirical_range]\nrange_mm = [1000.0, 2000.0]\ncorrection_mm = [2.0, -2.0]\n"
    grid = "[effects.empirical_pixel_map]\ncorrection_mm = [[0.0, 4.0], [0.0, 4.0]]\n"
    base = prep(make())
    r = base.range_mm.astype(float)
    rng = prep(make(effects=table))
    np.testing.assert_allclose(rng.range_mm - base.range_mm, np.interp(r, [1000, 2000], [2, -2]), atol=2e-3)
    pix = prep(make(effects=grid))
    w = r.shape[1]
    u = (np.arange(w) - (w - 1) / 2) / (w / 2)  # -1 ... 1 across the sensor: the map goes 0 ... 4 mm
    np.testing.assert_allclose(pix.range_mm - base.range_mm, np.broadcast_to(2 * (u + 1), r.shape), atol=2e-3)
    stereo = make("d455", effects=table)
    plain = make("d455")
    z = plain.depth(plain.render_scene(build_scene("wall", {}, plain.profile.wavelength_nm, 1500.0), Pose.at_origin())[0])
    z_fx = stereo.depth(stereo.render_scene(build_scene("wall", {}, plain.profile.wavelength_nm, 1500.0),
                                            Pose.at_origin())[0])
    np.testing.assert_allclose(z_fx - z, np.interp(z, [1000, 2000], [2, -2]), atol=1e-6)
    with pytest.raises(Exception, match="range_mm must increase"):
        parse_model('camera = "blaze101"\n[effects.empirical_range]\nrange_mm = [2.0, 1.0]\ncorrection_mm = [0.0, 0.0]\n')
    with pytest.raises(Exception, match="rectangular"):
        parse_model('camera = "blaze101"\n[effects.empirical_pixel_map]\ncorrection_mm = [[1.0], [1.0, 2.0]]\n')


def test_wiggling_formula_on_the_range():
    wig = prep(make(effects="[effects.wiggling]\namplitude_mm = 4\nperiod_mm = 375\nphase_rad = 0.3\n"))
    base = prep(make())
    r = base.range_mm.astype(float)
    expected = 4 * np.sin(2 * math.pi * r / 375 + 0.3)
    np.testing.assert_allclose(wig.range_mm - base.range_mm, expected, atol=2e-3)


def test_temperature_drift_decays_with_time():
    cam_on = make(effects="[effects.temperature_drift]\ndelta_mm = 6\ntau_s = 300\n")
    cam_off = make()
    p_on, p_off = prep(cam_on), prep(cam_off)
    for t in (0.0, 300.0, 900.0):
        z_on = cam_on.frame(p_on, 4, t)[2]
        z_off = cam_off.frame(p_off, 4, t)[2]
        dz = cam_on.geometry.cos_alpha  # range shift projected on z
        np.testing.assert_allclose(z_on - z_off, 6 * math.exp(-t / 300) * dz, atol=2e-3)


def test_temperature_drift_with_two_time_constants():
    cam_on = make(effects="[effects.temperature_drift]\ndelta_mm = 6\ntau_s = 60\n"
                          "terms = [{ delta_mm = -2.5, tau_s = 900 }]\n")
    cam_off = make()
    p_on, p_off = prep(cam_on), prep(cam_off)
    for t in (0.0, 60.0, 900.0):  # at t = tau of each term
        z_on, z_off = cam_on.frame(p_on, 4, t)[2], cam_off.frame(p_off, 4, t)[2]
        expected = 6 * math.exp(-t / 60) - 2.5 * math.exp(-t / 900)
        np.testing.assert_allclose(z_on - z_off, expected * cam_on.geometry.cos_alpha, atol=2e-3)


def test_fixed_pattern_column_row_and_pixel_terms():
    cells = "[effects.fixed_pattern]\ncolumn_offsets_mm = [1.0, -1.0]\nrow_offsets_mm = [0.6, 0.0, -0.3]\n"
    on, base = prep(make(effects=cells)), prep(make())
    diff = on.range_mm.astype(float) - base.range_mm
    np.testing.assert_allclose(diff[:40, :80], 1.6, atol=1e-3)  # 160 columns in 2 cells, 120 rows in 3
    np.testing.assert_allclose(diff[40:80, 80:], -1.0, atol=1e-3)
    np.testing.assert_allclose(diff[80:, 80:], -1.3, atol=1e-3)
    np.testing.assert_array_equal(on.amplitude, base.amplitude)
    # 3 cells sampled by 4 pixels: pixel 1 covers [1/4, 1/2) = 1/12 of cell a, 1/6 of cell b (by hand)
    np.testing.assert_allclose(cell_average(3, 4) @ np.array([3.0, 6.0, 9.0]), [3.0, 5.0, 7.0, 9.0])
    random = Params(column_sigma_mm=2.0, row_sigma_mm=1.0, pixel_sigma_mm=0.5, seed=4)
    full = offset_map_mm(160, 120, random)
    columns = full.mean(axis=0) - full.mean()
    assert 1.6 < columns.std() < 2.4  # one column stripe per column, sigma 2 (+ the averaged rows, pixels)
    assert 0.4 < np.std(full - full.mean(axis=0) - full.mean(axis=1)[:, None] + full.mean()) < 0.6
    # a binned camera on the same grid sees exactly the bin means
    binned = offset_map_mm(40, 30, random.model_copy(update={"grid_px": [160, 120]}))
    np.testing.assert_allclose(binned, full.reshape(30, 4, 40, 4).mean(axis=(1, 3)), atol=1e-9)


def test_floor_multipath_adds_the_mirrored_bounce():
    on = make(effects='[effects.floor_multipath]\nplane = "floor"\ndistance_mm = 300\nreflectance = 0.5\n')
    p_on, p_off = prep(on), prep(make())
    k = on.wavenumber
    rays = on.geometry.optics.directions(*on.geometry.optics.pixel_grid())
    r = p_off.range_mm.astype(float)
    x, y, z = rays * r
    # explicit bounce camera -> F -> P with F on the floor y = 300 (Fermat: equal heights ratio)
    t = 300.0 / (600.0 - y)
    path = np.sqrt((x * t) ** 2 + 300.0**2 + (z * t) ** 2) + np.sqrt((x - x * t) ** 2 + (y - 300) ** 2 + (z - z * t) ** 2)
    expected = np.angle(1 + 0.5 * (r / path) ** 3 * np.exp(1j * k * (path - r) / 2)) / k
    expected = np.where(y < 300.0, expected, 0.0)
    np.testing.assert_allclose(p_on.range_mm - p_off.range_mm, expected, atol=2e-3)
    assert np.abs(expected).max() > 1.0 and np.any(y >= 300.0)


def test_intensity_related_error_grows_as_light_falls():
    on = make(effects="[effects.intensity_related_error]\nerror_at_reference_mm = 2.0\n")
    p_on, p_off = prep(on, distance=3000.0), prep(make(), distance=3000.0)
    expected = 2.0 * on.a_ref / p_off.amplitude
    np.testing.assert_allclose(p_on.range_mm - p_off.range_mm, expected, rtol=1e-3, atol=1e-3)
    assert expected.min() > 2.0 * (3000 / 2000) ** 2 * 0.99  # less light than the 2 m reference


def test_log_amplitude_error_is_a_curve_over_the_decades_of_light():
    on = make(effects="[effects.log_amplitude_error]\nper_decade_mm = -1.5\nper_decade_squared_mm = 0.8\n"
                      "table_log10_ratio = [-1.0, 0.0]\ntable_error_mm = [2.0, 0.0]\n")
    p_on, p_off = prep(on, distance=3000.0), prep(make(), distance=3000.0)
    centre = (slice(59, 61), slice(79, 81))
    # the 90 % wall at 3 m on the axis returns (2 / 3)^2 of the reference light: x = 2 log10(2 / 3) = -0.3522
    x = 2 * math.log10(2 / 3)
    expected = -1.5 * x + 0.8 * x * x + 2.0 * -x  # the table: 2 mm at x = -1, 0 at x = 0, linear between: 1.332 mm
    np.testing.assert_allclose(p_on.range_mm[centre] - p_off.range_mm[centre], expected, atol=0.01)
    with pytest.raises(ValueError, match="same length"):
        parse_model('camera = "blaze101"\n[effects.log_amplitude_error]\ntable_log10_ratio = [0.0]\n')


def test_stereo_calibration_drift_offsets_the_disparity_and_scales_the_depth():
    drift = make("d455", effects="[effects.stereo_calibration_drift]\ndisparity_offset_px = 0.2\n"
                                 "baseline_error = 0.01\n")
    plain = make("d455")
    fb = drift.focal_baseline
    centre = (slice(58, 62), slice(78, 82))
    for z in (1000.0, 2000.0, 4000.0):
        on, off = prep(drift, distance=z), prep(plain, distance=z)
        # z' = f b 1.01 / (f b / z + 0.2): the stored disparity f b / z' is (f b / z + 0.2) / 1.01
        np.testing.assert_allclose(on.disparity[centre], (fb / z + 0.2) / 1.01, rtol=1e-4)
        np.testing.assert_allclose(off.disparity[centre], fb / z, rtol=1e-4)


def test_diffuse_floor_multipath_is_the_bounce_summed_over_floor_patches():
    on = make(effects='[effects.diffuse_floor_multipath]\nplane = "floor"\ndistance_mm = 300\nalbedo = 0.5\n')
    p_on, p_off = prep(on, distance=2000.0), prep(make(), distance=2000.0)
    k, fov_h, fov_v = on.wavenumber, math.radians(on.profile.fov_h_deg), math.radians(on.profile.fov_v_deg)
    rays = on.geometry.optics.directions(*on.geometry.optics.pixel_grid())
    for row, col in ((60, 80), (75, 40), (30, 150)):  # points above the floor (y < 300 mm)
        x, y, z = rays[:, row, col] * float(p_off.range_mm[row, col])
        r, h = math.sqrt(x * x + y * y + z * z), 300.0 - y
        # midpoint sum over 1200 x 1200 patches of the floor lit by the emitter (depth w from 300 / tan(fov_v / 2)
        # to the target, width +-w tan(fov_h / 2)): irradiance 300 / |CF|^3, radiance 0.5 E / pi, cosines
        # h / |FP| at the patch and (z - w) / |FP| at the target, against the direct z / r^3
        edges = np.linspace(300.0 / math.tan(fov_v / 2), z, 1201)
        w = (edges[1:] + edges[:-1]) / 2
        u = (np.arange(1200) + 0.5) / 1200 * 2 - 1
        b = np.outer(w * math.tan(fov_h / 2), u)
        area = (edges[1] - edges[0]) * (2 * w * math.tan(fov_h / 2) / 1200)
        cf = np.sqrt(300.0**2 + b**2 + w[:, None] ** 2)
        fp = np.sqrt(h**2 + (b - x) ** 2 + (z - w[:, None]) ** 2)
        light = 0.5 / math.pi * 300.0 / cf**3 * h * (z - w[:, None]) / fp**4 * area[:, None]
        m = np.sum(light * np.exp(1j * k * (cf + fp - r) / 2)) / (z / r**3)
        assert p_on.range_mm[row, col] - p_off.range_mm[row, col] == pytest.approx(np.angle(1 + m) / k, abs=0.02)
        # the reconcile grid's smaller rule: its first-order signature Im m / k within 0.02 mm at albedo 0.5
        coarse = 0.5 * bounce_phasor(*(np.array([v]) for v in (x, y, z)), "floor", 300.0, on, nodes=SIGNATURE_NODES)
        assert coarse[0].imag / k == pytest.approx(m.imag / k, abs=0.02)
    assert np.nanmax(np.abs(p_on.range_mm - p_off.range_mm)) > 1.0
    beyond = (rays[1] * p_off.range_mm) >= 300.0  # the wall below the floor's height gets no bounce
    assert beyond.any() and np.all(p_on.range_mm[beyond] == p_off.range_mm[beyond])


def test_vignetting_multiplies_amplitude_by_cos_power():
    on = make(effects="[effects.vignetting]\nexponent = 4\n")
    ratio = prep(on).amplitude / prep(make()).amplitude
    np.testing.assert_allclose(ratio, on.geometry.cos_alpha**4, rtol=1e-5)


def test_quantization_rounds_coordinates():
    cam = make(effects="[effects.quantization]\nstep_mm = 2.0\n")
    x, y, z = cam.frame(prep(cam), 0, 0.0)[:3]
    for c in (x, y, z):
        v = c[np.isfinite(c)]
        np.testing.assert_array_equal(v / 2.0, np.round(v / 2.0))


def corner_positions(image):
    """Sub-pixel inner corners of a checkerboard image (OpenCV)."""
    img = cv2.normalize(image, None, 0, 255, cv2.NORM_MINMAX).astype(np.uint8)
    found, corners = cv2.findChessboardCornersSB(img, (9, 7), flags=cv2.CALIB_CB_EXHAUSTIVE)
    assert found
    return corners.reshape(-1, 2)


@pytest.mark.parametrize("k1", [-0.08, 0.06])
def test_radial_distortion_moves_image_points_by_the_formula(k1):
    """Corners of a checkerboard appear at r_d = r_u (1 + k1 (r_u / R)^2) of where a pinhole puts them."""
    over = "[camera_overrides]\nwidth = 320\nheight = 240\n"
    cam = make(effects=f"[effects.radial_distortion]\nk1 = {k1}\n", overrides=over)
    plain = make(overrides=over)
    params = {"tile_mm": 60.0, "board_mm": (600.0, 480.0)}  # 10 x 8 tiles: 9 x 7 inner corners
    found = corner_positions(prep(cam, "checkerboard", 650.0, params).amplitude)
    undistorted = corner_positions(prep(plain, "checkerboard", 650.0, params).amplitude)
    u, v = cam.geometry.optics.distort(undistorted[:, 0], undistorted[:, 1])
    predicted = np.column_stack([u, v])
    # match each predicted corner to the nearest found one
    d = np.linalg.norm(found[:, None, :] - predicted[None, :, :], axis=2).min(axis=0)
    shift = np.linalg.norm(predicted - undistorted, axis=1)
    assert shift.max() > 2.0
    assert np.median(d) < 0.1 and d.max() < 0.3  # agreement an order of magnitude below the effect


def test_radial_distortion_every_pixel_sees_a_ray_down_to_the_bound():
    """At the lowest k1 the effect admits, each pixel has an undistorted position r_u with
    r_u (1 + k1 (r_u / R)^2) = r_d on the rising branch (r_u < R / sqrt(-3 k1)); a k1 below -4/27, where the
    image corner lies beyond the fold of r_d(r_u), is refused by name."""
    k1 = valid_range(EFFECTS["radial_distortion"].params, "k1")[0]
    assert -4 / 27 < k1 < 0
    optics = make(effects=f"[effects.radial_distortion]\nk1 = {k1}\n").geometry.optics
    u, v = optics.pixel_grid()
    uu, vv = optics.undistort(u, v)
    big_r = optics.half_diagonal_px
    r_u = np.hypot(uu - optics.pinhole.cx, vv - optics.pinhole.cy) / big_r
    r_d = np.hypot(u - optics.pinhole.cx, v - optics.pinhole.cy) / big_r
    assert np.all(r_u < 1 / math.sqrt(-3 * k1))
    np.testing.assert_allclose(r_u * (1 + k1 * r_u**2), r_d, atol=1e-9)
    with pytest.raises(ModelError, match="k1"):
        make(effects="[effects.radial_distortion]\nk1 = -0.15\n")


def test_radial_distortion_cloud_flag():
    """cloud = false: the point cloud of a flat wall stays flat; cloud = true: it bends with k1."""
    corrected = make(effects="[effects.radial_distortion]\nk1 = 0.1\ncloud = false\n")
    bent = make(effects="[effects.radial_distortion]\nk1 = 0.1\ncloud = true\n")
    z_c = corrected.frame(prep(corrected), 0, 0.0)[2]
    z_b = bent.frame(prep(bent), 0, 0.0)[2]
    assert abs(np.nanmedian(z_c[:10, :10]) - 1500.0) < 3.0  # the wall stands at 1500 mm
    assert np.nanmedian(z_b[:10, :10]) < 1480.0  # corner rays reported too steep: z too small


def test_fov_error_changes_the_visible_tile_count():
    cam = make(effects="[effects.fov_error]\nfov_deg = [65.0, 51.0]\n", overrides="")
    image = prep(cam, "checkerboard", 500.0).amplitude
    row = image[240] > np.median(image[240])
    crossings = np.count_nonzero(np.diff(row))
    assert 2 * 500 * math.tan(math.radians(32.5)) / 19 == pytest.approx(33.5, abs=0.05)
    assert crossings in (33, 34)
    assert cam.geometry.optics.pinhole.fov_h_deg == 65.0


def test_defocus_blur_follows_the_thin_lens_law():
    """Edge SFR of the simulated chart at s = 0.8 H and 2 H matches sinc x Gauss x disc(coc H / s)."""
    over = "[camera_overrides]\nwidth = 320\nheight = 240\n"
    cam = make(overrides=over)
    p = cam.profile
    coc = default_coc_px(p.lens_sigma_px)
    for s in (0.8 * p.hyperfocal_mm, 2 * p.hyperfocal_mm):
        chart = prep(cam, "slanted_edge", s).amplitude
        white = prep(cam, "white_sheet", s).amplitude
        img = chart / white
        roi = img[130:230, 110:210]  # the near-vertical edge leaves the centre downwards, leaning left
        result = edge_sfr(roi)
        f = np.linspace(0, 1, 4001)
        truth = analytic_sfr(f, p.lens_sigma_px, coc * p.hyperfocal_mm / s)
        sfr50 = f[np.argmax(truth < 0.5)]
        assert result.sfr50 == pytest.approx(sfr50, rel=0.04), s


@pytest.mark.parametrize("camera", ["blaze101", "amt100", "flexx2"])
def test_edge_sfr_above_nyquist_is_the_lens_not_an_alias(camera):
    """In focus (no defocus effect), the chart's edge SFR follows |sinc f| x Gauss(lens_sigma_px) from 0.1 to
    0.75 cy/px, above Nyquist too (within 0.03; measured at most 0.023), so SFR10 -- the imagery resolution
    of Thesis 2024, Table 6-3 the lens is calibrated to -- comes out within 5 %. Blurring pixel values instead of
    sub-pixels folds the lens's response about 0.5 cy/px: SFR10 read 0.84 instead of 0.61 cy/px for the
    AM-T100's 0.46 px."""
    cam = make(camera, overrides="[camera_overrides]\nwidth = 320\nheight = 240\n", base=False)
    p = cam.profile
    img = prep(cam, "slanted_edge", 1000.0).amplitude / prep(cam, "white_sheet", 1000.0).amplitude
    result = edge_sfr(img[130:230, 110:210])
    f = np.linspace(0.1, 0.75, 66)
    truth = analytic_sfr(f, p.lens_sigma_px)
    assert np.abs(np.interp(f, result.frequency, result.sfr) - truth).max() < 0.03
    f10 = np.linspace(0, 1, 4001)[np.argmax(analytic_sfr(np.linspace(0, 1, 4001), p.lens_sigma_px) < 0.1)]
    assert result.sfr10 == pytest.approx(f10, rel=0.05)


def test_flying_pixels_mix_depths_at_edges():
    params = {"segments": 24, "gap_mm": 400.0}
    on = make(effects="[effects.flying_pixels]\n")
    p_on, p_off = prep(on, "boehler_star", 1800.0, params), prep(make(), "boehler_star", 1800.0, params)
    star, wall = 1400.0, 1800.0

    def between(p):
        z = p.range_mm[p.amplitude > 0]
        return np.mean((z > star + 50) & (z < wall - 50))

    assert between(p_off) == 0.0
    assert between(p_on) > 0.002


def test_multipath_shifts_range_by_the_phasor_sum():
    on = make(effects="[effects.multipath]\nstrength = 0.1\nextra_path_mm = 600\n")
    p_on, p_off = prep(on), prep(make())
    k = on.wavenumber
    # for a uniform wall the direct phasor is A exp(j k r); the indirect one 0.1 mean(P) exp(j k 600)
    amp = p_off.amplitude.astype(float)
    direct = amp * np.exp(1j * k * p_off.range_mm)
    shift = np.angle(1 + 0.1 * direct.mean() * np.exp(1j * k * 600) / direct) / k
    np.testing.assert_allclose(p_on.range_mm - p_off.range_mm, shift, atol=0.02)
    assert np.abs(shift).max() > 1.0


@pytest.mark.parametrize("angle_deg", [20.0, 60.0])
def test_multipath_scene_return_does_not_depend_on_the_pixel_grid(angle_deg):
    """The indirect light is the whole scene's return, each surface at its own range (``ToFSensor.returns``): its
    mean over the image is the same on the flexx2's 224 x 172 pixels and on 56 x 43 pixels of the same field, a
    PTFE plate turned by ``angle_deg`` before the curtains (the plate's outline pixels return light from both),
    within 0.5 % and 1.5 mrad. The mean of each pixel's dominant surface alone moves with the grid by several
    times that in phase (8.9 and 11.5 mrad), which is 2-5 mm of a multipath's extra path at 60 MHz."""
    means = []
    for width, height in ((224, 172), (56, 43)):
        cam = make("flexx2", effects="[effects.multipath]\nstrength = 0.0\nextra_path_mm = 600\n",
                   overrides=f"[camera_overrides]\nwidth = {width}\nheight = {height}\n")
        r = cam.render_scene(plate_scene("ptfe", cam.profile.wavelength_nm), Pose.on_circle(angle_deg, 850.0))
        range_mm, amplitude, _ = cam.expected(r, cam.profile.exposure_us)  # strength 0: the dominant range
        dominant = amplitude * np.exp(1j * cam.wavenumber * np.nan_to_num(range_mm))
        means.append((cam.returns(r, cam.profile.exposure_us).mean(), dominant.mean()))
    (every_full, dominant_full), (every_coarse, dominant_coarse) = means
    assert abs(abs(every_coarse / every_full) - 1) < 0.005
    assert abs(np.angle(every_coarse / every_full)) < 0.0015
    assert abs(np.angle(dominant_coarse / dominant_full)) > 0.005


def test_material_bias_on_ptfe():
    on = make(effects="[effects.material_bias]\nscale = 1.0\n")
    off = make()
    pose = Pose.on_circle(0.0, 850.0)
    scene = plate_scene("ptfe", 940.0)
    r_on = on.prepare(scene, pose, 1000.0, 3, 7).range_mm
    r_off = off.prepare(scene, pose, 1000.0, 3, 7).range_mm
    centre = (slice(55, 65), slice(75, 85))
    np.testing.assert_allclose(r_on[centre] - r_off[centre], get_material("ptfe").subsurface_bias_mm, atol=1e-3)


# -------------------------------------------------------------------------------------- stereo
def test_stereo_disparity_is_quantized():
    cam = make("d455", overrides=SMALL)
    z = cam.frame(prep(cam, distance=2000.0), 0, 0.0)[2]
    disparity = cam.focal_baseline / z[np.isfinite(z)]
    # z is rounded to 1 mm after the disparity step: the disparity sits on the 1/32 px grid up to that
    steps = disparity * 32
    tolerance = 32 * cam.focal_baseline / 2000.0**2 * 0.5
    assert np.all(np.abs(steps - np.round(steps)) <= tolerance + 1e-6)


def test_disparity_bias_at_known_disparities():
    biased = make("d455", effects="[effects.disparity_bias]\namplitude_px = 0.1\nphase_rad = 0.0\n")
    plain = make("d455")
    fb = biased.focal_baseline
    for disparity, bias in ((4.0, 0.0), (4.25, 0.1), (4.5, 0.0), (4.75, -0.1)):  # sin(2 pi d)
        z = fb / disparity
        on, off = prep(biased, distance=z), prep(plain, distance=z)
        centre = (slice(58, 62), slice(78, 82))
        np.testing.assert_allclose(on.disparity[centre] - off.disparity[centre], bias, atol=2e-3)


def test_ambient_light_adds_shot_noise_and_lowers_the_stereo_contrast():
    level = 2.0
    lit_effects = f"[effects.ambient_light]\nlevel = {level}\n"
    plain, lit = make(), make(effects=lit_effects)
    a, b = prep(plain), prep(lit)
    # ToF: the background joins B of eq. 2-9 as level x A_ref; the noise-free maps stay
    assert b.ambient - a.ambient == pytest.approx(level * plain.a_ref, rel=1e-6)
    np.testing.assert_array_equal(b.range_mm, a.range_mm)
    np.testing.assert_array_equal(b.amplitude, a.amplitude)
    # stereo, far wall: a uniform background of level x the projector's light at 2 m (2000 counts) on the IR image
    # lowers the window's contrast std / mean; the matching noise grows by (m + b) / m, m the window's mean light
    plain_s, lit_s = make("d455", base=False), make("d455", effects=lit_effects, base=False)
    c, d = prep(plain_s, distance=3500.0), prep(lit_s, distance=3500.0)
    np.testing.assert_allclose(d.ir - c.ir, level * 2000.0, rtol=1e-4)
    window_mean = cv2.blur(c.ir.astype(float), (7, 7), borderType=cv2.BORDER_REFLECT)
    inner = (slice(10, -10), slice(10, -10))
    np.testing.assert_allclose((d.sigma_disp / c.sigma_disp)[inner], (1 + level * 2000.0 / window_mean)[inner],
                               rtol=1e-3)
    assert d.valid.sum() < 0.5 * c.valid.sum()


def test_disparity_bias_period_is_a_parameter():
    biased = make("d455", effects="[effects.disparity_bias]\namplitude_px = 0.1\nperiod_px = 2.0\n")
    plain = make("d455")
    fb = biased.focal_baseline
    for disparity, bias in ((4.0, 0.0), (4.5, 0.1), (5.0, 0.0), (5.5, -0.1)):  # sin(2 pi d / 2)
        z = fb / disparity
        on, off = prep(biased, distance=z), prep(plain, distance=z)
        centre = (slice(58, 62), slice(78, 82))
        np.testing.assert_allclose(on.disparity[centre] - off.disparity[centre], bias, atol=2e-3)


def test_projector_off_fails_on_textureless_wall():
    cam = make("d455", overrides=SMALL)
    with_dots = cam.frame(prep(cam, distance=2000.0, projector=True), 0, 0.0)
    without = cam.frame(prep(cam, distance=2000.0, projector=False), 0, 0.0)
    assert np.isfinite(with_dots[2]).mean() > 0.9
    assert np.isfinite(without[2]).mean() < 0.01
    # the left IR image shows the dot pattern only with the projector on
    assert np.std(with_dots[3]) > 3 * np.std(without[3])


def test_projector_off_keeps_textured_edges():
    cam = make("d455", overrides="[camera_overrides]\nwidth = 320\nheight = 240\n")
    z = cam.frame(prep(cam, "checkerboard", 1000.0, projector=False), 0, 0.0)[2]
    valid = np.isfinite(z).mean()
    assert 0.05 < valid < 0.95  # matched near tile edges, failed inside tiles


def test_stereo_occlusion_beside_the_star():
    """The right camera cannot see the wall just left of the star's left edges: invalid band there."""
    cam = make("d455", overrides="[camera_overrides]\nwidth = 320\nheight = 240\n")
    p = prep(cam, "boehler_star", 1600.0, {"segments": 24, "gap_mm": 500.0})
    z = cam.frame(p, 0, 0.0)[2]
    row = z[110]  # off the segment boundary on the centre row
    star = np.where(np.nan_to_num(row, nan=1e9) < 1300)[0]
    left_edge = star.min()
    band = np.isnan(row[left_edge - 15 : left_edge])
    expected_width = cam.focal_baseline / 1100.0 - cam.focal_baseline / 1600.0  # disparity jump, px
    assert expected_width == pytest.approx(5.6, abs=0.1)
    assert abs(band.sum() - expected_width) <= 1.5
    assert not np.isnan(row[left_edge - 25 : left_edge - 15]).any()  # the wall further left is seen
