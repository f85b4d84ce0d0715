"""An effect declared in this file alone joins the library: the simulator applies it, reconcile finds it.

``column_bow`` adds ``edge_mm`` x u^2 to every range (ToF) or depth (stereo),
u = (col - (W - 1) / 2) / (W / 2) the pixel's column position, -1 ... 1 across
the sensor: a bow over the columns, 0 in the middle, ``edge_mm`` at the left
and right edges (unlike the wall's tilt, which the comparison allows for). The
mean of u^2 over a bin of b columns is the binned pixel's own u^2 plus the
constant (b^2 - 1) / (3 W^2), which the comparison's depth offset takes. It is
declared with the same :class:`~sim.effects.Effect` API as the library's
effects and registered for each test by a fixture; reconcile builds its
candidate from the declaration (re-simulated with the effect switched on).
"""

from __future__ import annotations

import numpy as np
import pytest
from pydantic import Field

from labctl.reconcile.workflow import reconcile
from sim.effects import EFFECTS, Effect, EffectParams, Observed, RangeStage, registered
from sim.geometry import Pose
from sim.model import default_model_text, parse_model
from sim.scenes.targets import build_scene
from sim.stereo import StereoSensor
from sim.tof import ToFSensor
from tests.reconcile.runs import simulated_run


class BowParams(EffectParams):
    edge_mm: float = Field(0.0, ge=-50.0, le=50.0, description="range error at the left and right edges, mm")


def column_position(width: int) -> np.ndarray:
    """u of every column: (col - (W - 1) / 2) / (W / 2)."""
    return (np.arange(width) - (width - 1) / 2) / (width / 2)


def bow(values: np.ndarray, p: BowParams, _: RangeStage) -> np.ndarray:
    return values + p.edge_mm * column_position(values.shape[1]) ** 2


COLUMN_BOW = Effect(
    "column_bow", ("tof", "stereo"), BowParams, "defined by this test",
    observed=Observed("resimulated", fitted=("edge_mm",)),
    on_range=bow,
)


@pytest.fixture
def column_bow():
    with registered(COLUMN_BOW) as effect:
        yield effect
    assert "column_bow" not in EFFECTS


def sensor(camera: str, effects: str = ""):
    model = parse_model(default_model_text(camera) + effects + "[camera_overrides]\nwidth = 80\nheight = 60\n")
    profile = model.profile()
    return (ToFSensor if profile.technology == "tof" else StereoSensor)(profile, model.effect_params())


@pytest.mark.parametrize("camera", ["blaze101", "d455"])
def test_the_simulator_applies_the_declared_effect(column_bow, camera):
    plain, bowed = sensor(camera), sensor(camera, "[effects.column_bow]\nedge_mm = 4.0\n")
    scene = build_scene("wall", {}, plain.profile.wavelength_nm, 1500.0)
    exposure = plain.profile.exposure_us
    before = plain.expected(plain.render_scene(scene, Pose.at_origin()), exposure)[0]
    after = bowed.expected(bowed.render_scene(scene, Pose.at_origin()), exposure)[0]
    valid = np.isfinite(before)
    assert valid.mean() > 0.9
    expected = np.broadcast_to(4.0 * column_position(80) ** 2, before.shape)
    np.testing.assert_allclose((after - before)[valid], expected[valid], atol=1e-6)


def test_parameter_bounds_come_from_the_declaration(column_bow):
    with pytest.raises(ValueError, match="edge_mm"):
        parse_model('camera = "d455"\n[effects.column_bow]\nedge_mm = 60.0\n')


def test_reconcile_finds_the_declared_effect(column_bow, tmp_path):
    true = 40.0
    run = simulated_run(tmp_path, "d455", {"column_bow": {"edge_mm": true}}, sweep_step_mm=400, robot=False)
    result = reconcile(run)
    assert [e.name for e in result.named] == ["column_bow"], (result.verdict, result.candidates)
    assert abs(result.named[0].parameters["edge_mm"] - true) <= 0.05 * true
    assert result.verdict == "effect_found"
