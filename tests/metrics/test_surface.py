"""ISO 25178 surface texture: known answers from sinusoids and the ISO 16610-61 Gaussian."""

import math

import numpy as np
import pytest

from metrics.surface import (
    SIGMA_PER_CUTOFF,
    fit_plane,
    gaussian_transmission,
    lateral_pixel_size_mm,
    normalized_gaussian,
    surface_texture,
)

PX = 2.0  # mm per pixel


def grid(h: int, w: int, px: float = PX):
    """Pixel centres symmetric about the image centre, ``px`` mm apart."""
    u, v = np.arange(w) - (w - 1) / 2, np.arange(h) - (h - 1) / 2
    x = np.broadcast_to(u[None, :] * px, (h, w)).copy()
    y = np.broadcast_to(v[:, None] * px, (h, w)).copy()
    return x, y


def test_sigma_constant_is_iso_16610_61():
    assert SIGMA_PER_CUTOFF == pytest.approx(0.18739, abs=1e-5)
    assert gaussian_transmission(25.0, 25.0) == pytest.approx(0.5)


def test_plane_fit_recovers_tilt():
    x, y = grid(40, 50)
    z = 1500 + 0.03 * x - 0.01 * y
    a, b, c = fit_plane(x, y, z, np.ones_like(z, bool))
    assert (a, b, c) == pytest.approx((1500, 0.03, -0.01))


@pytest.mark.parametrize("wavelength", [30.0, 40.0, 60.0])
def test_sinusoidal_waviness_splits_by_gaussian_transmission(wavelength):
    """A cosine of amplitude A: Sq_primary = A/sqrt2, waviness keeps T(lambda), roughness 1 - T.

    The cosine is even about the image centre (so the form plane takes none of
    it) and the evaluated span after the lambda_c/2 crop holds whole periods.
    """
    cutoff, amp = 25.0, 1.0
    period_px = int(wavelength / PX)
    w = 6 * period_px + 14  # crop = ceil(12.5 px / 2) = 7 px per side
    x, y = grid(60, w)
    z = 2000 + 0.02 * y + 0.01 * x + amp * np.cos(2 * np.pi * x / wavelength)
    s = surface_texture(x, y, z, np.ones_like(z, bool), cutoff)
    t = gaussian_transmission(wavelength, cutoff)
    assert s.crop_px == (7, 7)
    assert s.sq_primary_mm == pytest.approx(amp / math.sqrt(2), rel=1e-6)
    assert s.sq_waviness_mm == pytest.approx(amp / math.sqrt(2) * t, rel=0.003)
    assert s.sq_roughness_mm == pytest.approx(amp / math.sqrt(2) * (1 - t), rel=0.003)


def test_short_wavelength_is_roughness():
    x, y = grid(80, 100)
    z = 2000 + 0.5 * np.sin(2 * np.pi * x / 8.0)  # 8 mm << 25 mm cut-off: T = 0.001
    s = surface_texture(x, y, z, np.ones_like(z, bool), 25.0)
    # what leaks into the waviness comes from the image border inside the lambda_c/2 crop
    assert s.sq_waviness_mm < 0.03 * s.sq_primary_mm
    assert s.sq_roughness_mm == pytest.approx(s.sq_primary_mm, rel=0.02)


def test_white_noise_is_roughness_and_tilt_is_form():
    rng = np.random.default_rng(5)
    x, y = grid(120, 160)
    z = 2000 + 0.05 * x + 0.3 * rng.standard_normal(x.shape)
    s = surface_texture(x, y, z, np.ones_like(z, bool), 25.0)
    assert s.sq_primary_mm == pytest.approx(0.3, rel=0.03)
    assert s.sq_roughness_mm == pytest.approx(0.3, rel=0.05)


def test_invalid_pixels_are_filled_not_zeroed():
    """Holes must not drag the waviness towards zero (normalized convolution)."""
    x, y = grid(60, 214)
    z = 2000 + np.sin(2 * np.pi * x / 200.0)
    valid = np.ones_like(z, bool)
    valid[20:30, 50:70] = False
    full = surface_texture(x, y, z, np.ones_like(z, bool), 25.0)
    holed = surface_texture(x, y, np.where(valid, z, np.nan), valid, 25.0)
    assert holed.sq_waviness_mm == pytest.approx(full.sq_waviness_mm, rel=0.01)
    assert np.isnan(holed.waviness[25, 60])


def test_normalized_gaussian_keeps_constant_under_holes():
    values = np.full((30, 30), 7.0)
    valid = np.ones((30, 30), bool)
    valid[::3, ::2] = False
    out = normalized_gaussian(np.where(valid, values, -1e6), valid, (2.0, 2.0))
    np.testing.assert_allclose(out, 7.0)


def test_pixel_size_from_cloud():
    x, y = grid(10, 12, px=1.7)
    assert lateral_pixel_size_mm(x, y) == pytest.approx((1.7, 1.7))


def test_cutoff_too_large_for_image_is_an_error():
    x, y = grid(10, 10, px=1.0)
    with pytest.raises(ValueError, match="leaves nothing"):
        surface_texture(x, y, 2000 + 0 * x, np.ones_like(x, bool), 25.0)
