"""The NIR material table holds physical values in the order Thesis 2024's physics relies on."""

import dataclasses
import math

import numpy as np
import pytest

from sim.materials import MATERIALS, Material, angle_factor, get_material, remission

REQUIRED = ("ptfe", "molleton", "silicone", "gelatine", "collagen", "wall", "chart_white", "chart_black", "paper_white")
SKIN_LIKE = ("silicone", "gelatine", "collagen")
OPAQUE = ("molleton", "wall", "chart_white", "chart_black", "paper_white")


def test_every_required_material_is_present_under_its_own_name():
    assert set(REQUIRED) <= set(MATERIALS)
    for name, material in MATERIALS.items():
        assert material.name == name


@pytest.mark.parametrize("name", REQUIRED)
def test_values_are_physical_and_sourced(name):
    m = MATERIALS[name]
    assert 0.0 < m.remission_850 <= 1.0 and 0.0 < m.remission_940 <= 1.0
    assert 0.0 <= m.subsurface_bias_mm < 50.0
    assert 0.5 <= m.lambertian_exponent <= 4.0
    assert len(m.source) > 20


@pytest.mark.parametrize("wavelength", [850.0, 940.0])
def test_remission_order_ptfe_wall_skin_like_molleton(wavelength):
    ptfe, wall, molleton = (remission(n, wavelength) for n in ("ptfe", "wall", "molleton"))
    assert ptfe > wall
    for name in SKIN_LIKE:
        assert wall > remission(name, wavelength) > molleton


def test_values_the_thesis_states():
    assert remission("wall", 850) == remission("wall", 940) == pytest.approx(0.90)  # 4.1.1
    assert remission("molleton", 850) == remission("molleton", 940) == pytest.approx(0.10)  # 4.1.1


@pytest.mark.parametrize("wavelength", [850.0, 940.0])
def test_chart_black_white_ratio_is_about_1_to_105(wavelength):
    ratio = remission("chart_white", wavelength) / remission("chart_black", wavelength)
    assert ratio == pytest.approx(105.0, rel=0.02)


def test_subsurface_bias_positive_for_scattering_materials_and_about_zero_for_opaque_ones():
    assert MATERIALS["ptfe"].subsurface_bias_mm > 0.0
    for name in SKIN_LIKE:
        assert MATERIALS[name].subsurface_bias_mm > 0.0
    for name in OPAQUE:
        assert MATERIALS[name].subsurface_bias_mm < 1.0


@pytest.mark.parametrize("name", REQUIRED)
def test_interpolation_is_exact_at_850_and_940_and_linear_between(name):
    m = MATERIALS[name]
    assert remission(m, 850.0) == m.remission_850
    assert remission(m, 940.0) == m.remission_940
    for wl in np.linspace(800.0, 1000.0, 21):
        expected = m.remission_850 + (m.remission_940 - m.remission_850) * (wl - 850.0) / 90.0
        assert remission(name, float(wl)) == pytest.approx(expected, abs=1e-12)
    assert remission(m, 895.0) == pytest.approx((m.remission_850 + m.remission_940) / 2, abs=1e-12)


@pytest.mark.parametrize("wavelength", [799.9, 1000.1, 532.0, 1550.0, math.nan])
def test_wavelength_outside_800_to_1000_nm_is_rejected(wavelength):
    with pytest.raises(ValueError, match="800-1000 nm"):
        remission("ptfe", wavelength)


def test_unknown_names_raise_key_error_listing_the_known_ones():
    with pytest.raises(KeyError) as err:
        get_material("teflon")
    for name in REQUIRED:
        assert name in str(err.value)
    with pytest.raises(KeyError, match="teflon"):
        remission("teflon", 850.0)


def test_get_material_returns_the_table_entry():
    assert get_material("silicone") is MATERIALS["silicone"]


def test_material_is_frozen_and_validated():
    with pytest.raises(dataclasses.FrozenInstanceError):
        MATERIALS["ptfe"].remission_850 = 0.5  # type: ignore[misc]
    with pytest.raises(ValueError, match="remission"):
        Material("x", 1.2, 0.5, 0.0, 1.0, "test")
    with pytest.raises(ValueError, match="bias"):
        Material("x", 0.5, 0.5, -1.0, 1.0, "test")
    with pytest.raises(ValueError, match="exponent"):
        Material("x", 0.5, 0.5, 0.0, 0.0, "test")


def test_angle_factor_is_cos_to_the_lambertian_exponent():
    theta = np.array([-80.0, -40.0, 0.0, 40.0, 70.0, 80.0])
    assert np.allclose(angle_factor("wall", theta), np.cos(np.radians(theta)))
    m = MATERIALS["collagen"].lambertian_exponent
    assert np.allclose(angle_factor("collagen", theta), np.cos(np.radians(theta)) ** m)
    assert angle_factor("ptfe", 0.0) == 1.0
    assert angle_factor("ptfe", 95.0) == 0.0
