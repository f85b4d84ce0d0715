"""The characterization's disparity and exposure axes, on residual maps written here.

Fifteen wall positions, 1000 ... 4500 mm, each seen at 100 us and then at 400 us (30 steps, 10 s apart), each
step a 6 x 8 bin map. A residual of 0.5 mm on the 400 us steps only follows the exposure: every distance holds
both exposures, and the time's 24 groups cannot resolve the 30 steps. A residual of c / z (constant per step) is
a straight line over the disparity axis (1000 / z, 1/m).
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from labctl.reconcile.characterize import characterize

DISTANCES = np.repeat(np.linspace(1000.0, 4500.0, 15), 2)
EXPOSURES = [100.0, 400.0] * 15
SHAPE = (6, 8)


def _run():
    observations, predictions = [], []
    for i, (d, e) in enumerate(zip(DISTANCES, EXPOSURES, strict=True)):
        scene = SimpleNamespace(wall_distance_mm=d, robot_angle_deg=None, reference="laser", target="wall",
                                exposure_us=e)
        observations.append(SimpleNamespace(scene=scene, z=np.full(SHAPE, d), z_var=np.full(SHAPE, 0.01),
                                            intensity=np.full(SHAPE, 1e6 / d**2), times_s=np.array([10.0 * i])))
        predictions.append(SimpleNamespace(z=np.full(SHAPE, d), range_mm=np.full(SHAPE, d)))
    return observations, predictions


def _axes(found):
    return {a.axis: a for a in found.axes}


def test_a_residual_constant_in_exposure_is_carried_by_the_exposure():
    observations, predictions = _run()
    maps = [np.full(SHAPE, 0.5 if e == 400.0 else 0.0) for e in EXPOSURES]
    found = characterize(observations, predictions, maps, 0.0)
    assert found.carrying_axis == "exposure"
    exposure = _axes(found)["exposure"]
    assert exposure.unit == "us"
    assert exposure.eta2 == pytest.approx(1.0, abs=1e-6)
    assert exposure.effect_mm == pytest.approx(0.5, abs=1e-6)
    assert _axes(found)["distance"].eta2 == pytest.approx(0.0, abs=1e-6)  # both exposures at every distance
    assert _axes(found)["time"].eta2 < 1.0


def test_the_disparity_axis_is_the_inverse_depth():
    observations, predictions = _run()
    c = 2000.0  # mm^2: 2 mm at 1 m, 0.44 mm at 4.5 m
    maps = [np.full(SHAPE, c / d) for d in DISTANCES]
    found = characterize(observations, predictions, maps, 0.0)
    disparity = _axes(found)["disparity"]
    assert disparity.unit == "1/m"
    # 24 groups of equal width in 1/z: the far positions, close in disparity, share groups, so the group means
    # follow the line to within the spread of a group and carry nearly all of it
    assert disparity.eta2 == pytest.approx(1.0, abs=0.01)
    assert disparity.effect_mm == pytest.approx(c / DISTANCES[0] - c / DISTANCES[-1], rel=0.05)
    # one axis on two scales: never listed as confounded with the distance
    assert "disparity" not in [c.axis for c in found.confounded_with or []]
    assert "distance" not in [c.axis for c in found.confounded_with or []]
