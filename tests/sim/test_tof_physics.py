"""The simulated ToF/stereo depth noise follows the published noise laws.

Eq. 2-9 of Thesis 2024 (Li 2014) is re-implemented here from its text, on
purpose independently of sim/tof.py, and compared with what a simulated
campaign records.
"""

import math

import h5py
import numpy as np
import pytest
from scipy.stats import chi2

from labctl.cli import main
from metrics.stack import stack_stats
from sim.profiles import PROFILES

C = 299_792_458_000.0  # mm/s


def eq_2_9(amplitude, offset, f_mod_hz, contrast):
    """sigma = c / (4 sqrt(2) pi f_mod) * sqrt(A + B) / (c_d A)."""
    return C / (4 * math.sqrt(2) * math.pi * f_mod_hz) * np.sqrt(amplitude + offset) / (contrast * amplitude)


def predicted_z_noise(profile, distance_mm, width, height):
    """Per-pixel z noise of a fronto-parallel 90 % wall at ``distance_mm``.

    The profile fixes the centre-pixel noise at 2 m; A ~ cos(theta) / r^2;
    B = A + ambient; range noise projects onto z by the ray's z component.
    """
    f = profile.modulation_mhz * 1e6
    k = C / (4 * math.sqrt(2) * math.pi * f)
    ra = profile.ambient_ratio
    a_ref = (k * math.sqrt(2 + ra) / (profile.modulation_contrast * profile.noise_mm_at_2m)) ** 2
    fx = (width / 2) / math.tan(math.radians(profile.fov_h_deg) / 2)
    fy = (height / 2) / math.tan(math.radians(profile.fov_v_deg) / 2)
    u = (np.arange(width) - (width - 1) / 2) / fx
    v = (np.arange(height) - (height - 1) / 2) / fy
    norm = np.sqrt(1 + u[None, :] ** 2 + v[:, None] ** 2)
    cos_theta = 1 / norm
    r = distance_mm * norm
    amplitude = a_ref * cos_theta * (2000 / r) ** 2
    return eq_2_9(amplitude, amplitude + ra * a_ref, f, profile.modulation_contrast) * cos_theta


def run_sweep(tmp_path, write_campaign, small_model, camera, backend, frames=60, extra_overrides=""):
    procedures = f"""
    [[procedure]]
    kind = "offset_calibration"
    frames = 4

    [[procedure]]
    kind = "depth_sweep"
    start_mm = 1000
    stop_mm = 4000
    step_mm = 1000
    frames = {frames}
    """
    out = tmp_path / f"{camera}.h5"
    model = small_model(camera, 64, 48)
    model.write_text(model.read_text() + extra_overrides)
    with pytest.raises(SystemExit) as info:
        main(["run", str(write_campaign(backend=backend, procedures=procedures)), "--sim",
              "--model", str(model), "-o", str(out), "--quiet"])
    code = info.value.code
    assert code == 0
    return out


@pytest.mark.parametrize("camera,backend", [("blaze101", "blaze"), ("flexx2", "flexx2")])
def test_depth_noise_follows_eq_2_9_over_distance(tmp_path, write_campaign, small_model, camera, backend):
    """Per pixel, measured std / eq. 2-9 prediction is distributed like sqrt(chi2(n-1)/(n-1))."""
    frames = 60
    out = run_sweep(tmp_path, write_campaign, small_model, camera, backend, frames)
    profile = PROFILES[camera]
    expected_median = math.sqrt(chi2.ppf(0.5, frames - 1) / (frames - 1))
    medians, predicted = [], []
    with h5py.File(out, "r") as f:
        for sid, g in sorted(f["steps"].items()):
            if g.attrs["procedure"] != "depth_sweep":
                continue
            true_distance = g.attrs["distance_mm"] + 6.0  # the simulated lab's camera mount error
            stats = stack_stats(g["z"][()])
            sigma = predicted_z_noise(profile, true_distance, 64, 48)
            assert np.median(stats.std / sigma) == pytest.approx(expected_median, rel=0.03), sid
            medians.append(np.nanmedian(stats.std))
            predicted.append(np.median(sigma))
    assert all(b > a for a, b in zip(medians, medians[1:])), "precision must grow with distance"
    # between ~r (signal-dominated) and ~r^2 (ambient-dominated), as eq. 2-9 predicts
    assert 4.0 < medians[-1] / medians[0] < 16.0
    assert medians[-1] / medians[0] == pytest.approx(predicted[-1] / predicted[0], rel=0.05)


def test_stereo_noise_grows_with_z_squared(tmp_path, write_campaign, small_model):
    """sigma_z = z^2 s (1 + g theta^2 / (pi/2 - theta)^2) / (f b), disparity quantization off.

    (On a 64 px wide test sensor f is only 42 px, so the sub-pixel noise s is
    comparable to the 1/32 px disparity step; quantization is tested apart.)
    """
    out = run_sweep(tmp_path, write_campaign, small_model, "d455", "realsense", frames=60,
                    extra_overrides="disparity_step_px = 0.0\n")
    profile = PROFILES["d455"]
    fx = 32 / math.tan(math.radians(profile.fov_h_deg) / 2)
    fy = 24 / math.tan(math.radians(profile.fov_v_deg) / 2)
    fb = fx * profile.baseline_mm
    s = profile.noise_mm_at_2m * fb / 2000**2
    u = (np.arange(64) - 31.5) / fx
    v = (np.arange(48) - 23.5) / fy
    theta = np.arccos(1 / np.sqrt(1 + u[None, :] ** 2 + v[:, None] ** 2))  # incidence on the frontal wall
    sigma_d = s * (1 + profile.angle_noise_gain * theta**2 / (math.pi / 2 - theta) ** 2)
    expected_median = math.sqrt(chi2.ppf(0.5, 59) / 59)
    medians = []
    with h5py.File(out, "r") as f:
        for g in f["steps"].values():
            if g.attrs["procedure"] != "depth_sweep":
                continue
            z = g.attrs["distance_mm"] + 6.0
            stats = stack_stats(g["z"][()])
            predicted = z**2 * sigma_d / fb
            ok = np.isfinite(stats.std)
            assert np.median(stats.std[ok] / predicted[ok]) == pytest.approx(expected_median, rel=0.04)
            medians.append(np.median(stats.std[ok]))
    assert medians[-1] / medians[0] == pytest.approx(16.0, rel=0.1)  # 4 m vs 1 m: z^2
