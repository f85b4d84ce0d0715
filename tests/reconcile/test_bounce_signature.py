"""The diffuse bounce's signature on the bin grid is the simulator's bounce phasor's imaginary part, bit for bit."""

import numpy as np
import pytest

from labctl.reconcile.bounce import bounce_imag
from labctl.reconcile.candidates import SIGNATURE_NODES
from sim.effects.diffuse_floor_multipath import NODES, bounce_phasor
from sim.model import default_model_text, parse_model
from sim.tof import ToFSensor


@pytest.mark.parametrize("plane", ["floor", "ceiling", "left", "right"])
@pytest.mark.parametrize("nodes", [SIGNATURE_NODES, NODES])
def test_bounce_imag_equals_the_phasor_s_imaginary_part(plane, nodes):
    model = parse_model(default_model_text("blaze101"))
    sensor = ToFSensor(model.profile(), model.effect_params())
    rng = np.random.default_rng(5)
    n = 400
    # points of walls and plates from 0.3 to 4.5 m across the field of view, some beyond the plane, one missing
    z = rng.uniform(300.0, 4500.0, n)
    x, y = rng.uniform(-0.6, 0.6, n) * z, rng.uniform(-0.45, 0.45, n) * z
    x[0] = y[0] = z[0] = np.nan
    for distance in (100.0, 320.0, 1500.0):
        expected = bounce_phasor(x, y, z, plane, distance, sensor, nodes=nodes).imag
        got = bounce_imag(x, y, z, plane, distance, sensor, nodes)
        assert np.count_nonzero(got) > n / 4
        np.testing.assert_array_equal(got, expected)
