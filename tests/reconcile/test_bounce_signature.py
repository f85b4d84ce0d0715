"""The diffuse bounce's signature on the bin grid, the simulator's bounce phasor evaluated for its imaginary part
alone (``imag_only``: the sines alone), is the full phasor's imaginary part bit for bit, and the plane on one side of
an axis at a point is the plane on the other side at the point's mirror image."""

import numpy as np
import pytest

from labctl.reconcile.candidates import SIGNATURE_NODES, unique_columns
from sim.effects.diffuse_floor_multipath import NODES, bounce_phasor
from sim.effects.floor_multipath import PLANES
from sim.model import default_model_text, parse_model
from sim.tof import ToFSensor


def _sensor() -> ToFSensor:
    model = parse_model(default_model_text("blaze101"))
    return ToFSensor(model.profile(), model.effect_params())


def bounce_imag(x: np.ndarray, y: np.ndarray, z: np.ndarray, plane: str, distance: float, sensor: ToFSensor,
                nodes: int) -> np.ndarray:
    """The imaginary part as the candidate evaluates it; its real part is left 0."""
    m = bounce_phasor(x, y, z, plane, distance, sensor, nodes=nodes, imag_only=True)
    assert not np.any(m.real)
    return m.imag


def _points(n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Points of walls and plates from 0.3 to 4.5 m across the field of view, the first one missing."""
    rng = np.random.default_rng(5)
    z = rng.uniform(300.0, 4500.0, n)
    x, y = rng.uniform(-0.6, 0.6, n) * z, rng.uniform(-0.45, 0.45, n) * z
    x[0] = y[0] = z[0] = np.nan
    return x, y, z


@pytest.mark.parametrize("plane", ["floor", "ceiling", "left", "right"])
@pytest.mark.parametrize("nodes", [SIGNATURE_NODES, NODES])
def test_bounce_imag_equals_the_phasor_s_imaginary_part(plane, nodes):
    sensor, n = _sensor(), 400
    x, y, z = _points(n)
    for distance in (100.0, 320.0, 1500.0):
        expected = bounce_phasor(x, y, z, plane, distance, sensor, nodes=nodes).imag
        got = bounce_imag(x, y, z, plane, distance, sensor, nodes)
        assert np.count_nonzero(got) > n / 4
        np.testing.assert_array_equal(got, expected)


@pytest.mark.parametrize("axis", [0, 1])
def test_the_plane_on_the_negative_side_is_the_positive_one_at_the_mirror_image(axis):
    sensor = _sensor()
    positive, negative = (next(p for p, (a, side) in PLANES.items() if a == axis and side * sign > 0) for sign in (1, -1))
    points = _points(400)
    mirror = list(points)
    mirror[axis] = -mirror[axis]
    for distance in (100.0, 320.0, 1500.0):
        on_negative = bounce_imag(*points, negative, distance, sensor, SIGNATURE_NODES)
        assert np.count_nonzero(on_negative) > 100
        np.testing.assert_array_equal(on_negative, bounce_imag(*mirror, positive, distance, sensor, SIGNATURE_NODES))


def test_unique_columns_is_numpy_s_unique_along_columns():
    rng = np.random.default_rng(7)
    a = rng.integers(0, 3, (3, 500)).astype(float)
    a[:, 7] = [-0.0, 1.0, 2.0]
    expected, expected_inverse = np.unique(a, axis=1, return_inverse=True)
    got, inverse = unique_columns(a)
    np.testing.assert_array_equal(got, expected)
    np.testing.assert_array_equal(inverse, expected_inverse.ravel())
    np.testing.assert_array_equal(got[:, inverse], a)
