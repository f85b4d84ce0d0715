"""The backward step (labctl/reconcile/workflow.py ``_drop_redundant``): a named effect that explains nothing beside
the others is taken out of the model, and one that does stays."""

from __future__ import annotations

from pathlib import Path

import pytest

from labctl.reconcile.candidates import candidates_for
from labctl.reconcile.null import FixedThresholds
from labctl.reconcile.observe import observe_run
from labctl.reconcile.residuals import layout
from labctl.reconcile.results import NamedEffect
from labctl.reconcile.workflow import Iteration, Simulation, _drop_redundant, _State, base_model, redundant, refine_jointly
from labctl.run.store import RunReader
from tests.reconcile.runs import simulated_run

WIGGLING = {"amplitude_mm": 2.0, "period_mm": 1500.0, "phase_rad": 0.4}


@pytest.fixture(scope="module")
def named_with_a_spare(tmp_path_factory: pytest.TempPathFactory):
    """A blaze-101 test campaign with a hidden 2 mm wiggling (nothing else), and its base model with the wiggling
    and a range scale, an effect the run does not hold, named and refitted together as reconcile refits them
    (``refine_jointly``, from a scale of 1e-3)."""
    run = simulated_run(Path(tmp_path_factory.mktemp("backward")), "blaze101", hidden={"wiggling": WIGGLING}, seed=11)
    with RunReader(run) as reader:
        observations, info, _ = observe_run(reader)
    model = base_model(info)
    sim = Simulation(observations, info)
    state = _State(sim, layout(observations, sim.predict(model), "tof"), model)
    candidates = {c.name: c for c in candidates_for(state.context())}
    found = [(candidates["range_scale"], {"scale": 1e-3}), (candidates["wiggling"], WIGGLING)]
    joint = refine_jointly(found, model, sim, state.lay)
    state.set(joint.model)
    state.named_slopes = joint.slopes
    return state, model, [(c, dict(joint.model.effects[c.name])) for c, _ in found]


def test_an_effect_the_run_does_not_hold_is_the_one_found_redundant(named_with_a_spare):
    """Beside the wiggling the range scale explains nothing: its dBIC is about -ln(steps) (one parameter's
    penalty, nothing gained), under the threshold; the wiggling, tested alone, stays significant."""
    state, _, found = named_with_a_spare
    rule = FixedThresholds(30.0)
    weakest = redundant(state, found, set(), rule)
    assert weakest is not None and weakest[0] == "range_scale", weakest
    assert weakest[1] < 5.0 and weakest[2] == 30.0, weakest
    assert redundant(state, found, {"range_scale"}, rule) is None


def test_the_redundant_effect_is_taken_out_and_the_rest_refitted(named_with_a_spare):
    """``_drop_redundant`` takes the range scale out of the named effects and the model, says so in the round's
    decision and the notes, refits the wiggling alone (near its hidden value) and keeps the range scale from being
    named again."""
    state, model, found = named_with_a_spare
    found = list(found)
    named = [NamedEffect(name=c.name, parameters=p, evidence=None) for c, p in found]
    iteration = Iteration(sorted(state.model.effects), state.good.gap_mm, [], "added wiggling", [])
    taken_out: set[str] = set()
    notes: list[str] = []
    joint = _drop_redundant(state, found, named, {"wiggling"}, FixedThresholds(30.0), model, iteration, taken_out,
                            notes, lambda _: None)
    assert joint is not None and joint.determinations is not None and len(joint.determinations) == 1
    assert [c.name for c, _ in found] == ["wiggling"] and [e.name for e in named] == ["wiggling"]
    assert "range_scale" not in state.model.effects and taken_out == {"range_scale"}
    assert iteration.decision == "added wiggling; took out range_scale"
    assert len(notes) == 1 and notes[0].startswith("range_scale taken out"), notes
    fitted = state.model.effects["wiggling"]
    assert fitted["amplitude_mm"] == pytest.approx(2.0, abs=0.1)
    assert fitted["period_mm"] == pytest.approx(1500.0, abs=30.0)
