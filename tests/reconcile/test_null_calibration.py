"""Verdicts calibrated on the campaign's own null runs (docs/reconcile.md, Null calibration).

The p-value and the critical value are checked against hand-made
distributions. The end-to-end cases reconcile the test campaign (offset
calibration, 0.4-4 m sweep in 200 mm steps, PTFE and silicone plates on the
robot, 10 frames, blaze-101 at 160 x 120) with 19 null replicas, the fewest for
which p <= 0.05 is attainable: with nothing hidden the verdict is ``none``; a
0.25 mm wiggling, well under the fixed floor (0.48 mm) and ``none`` with the
fixed thresholds, is named; so is 1.5 times the minimum detectable wiggling.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from labctl.jsondoc import to_json
from labctl.reconcile.goodness import StepFit
from labctl.reconcile.null import (
    ALPHA,
    DEFAULT_NULL_RUNS,
    NullCalibration,
    Replica,
    critical_value,
    p_value,
    replica_campaign,
    seeds_for,
    standardized_max,
    step_statistics,
)
from labctl.reconcile.power import _Replicas, _Signal, phases
from labctl.reconcile.workflow import json_document, reconcile
from tests.conftest import REALTIME_GROUP
from tests.reconcile.runs import CAMPAIGN, ROBOT, reconcile_cli, simulated_run

WIGGLING = {"wiggling": {"amplitude_mm": 0.25, "period_mm": 1500.0, "phase_rad": 0.5}}

# the replicas run on a local Dask cluster that takes both cores: on one worker, never beside a realtime test, and
# the module's replicas simulated once
pytestmark = pytest.mark.xdist_group(REALTIME_GROUP)

def test_the_p_value_counts_the_null_runs_at_or_above_the_observed_value():
    null = [1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0, 9.0, 10.0]
    assert p_value(10.5, null) == pytest.approx(1 / 11)  # beyond every null run: the smallest p K = 10 can give
    assert p_value(10.0, null) == pytest.approx(2 / 11)  # a tie counts against the observed value
    assert p_value(5.5, null) == pytest.approx(6 / 11)
    assert p_value(0.0, null) == pytest.approx(1.0)


def test_the_critical_value_is_what_a_statistic_must_exceed_for_p_at_most_alpha():
    null = [float(v) for v in range(1, 20)]  # K = 19: only a value above all of them reaches p = 1 / 20 = 0.05
    assert critical_value(null, 0.05) == 19.0
    assert p_value(19.0 + 1e-9, null) <= 0.05 < p_value(19.0, null)
    null = [float(v) for v in range(1, 40)]  # K = 39: one null value may lie at or above (p = 2 / 40)
    assert critical_value(null, 0.05) == 38.0
    assert math.isinf(critical_value([1.0, 2.0, 3.0], 0.05))  # K = 3 cannot reach 0.05
    assert 1 / (DEFAULT_NULL_RUNS + 1) <= ALPHA


def test_the_combined_statistic_is_the_largest_standardized_one():
    pool = [{"a": 3.0, "b": 0.0}, {"a": 1.0, "b": 1.0}, {"a": 2.0, "b": 2.0}]
    t = standardized_max(pool)
    # a: mean 2, std sqrt(2/3); b: mean 1, std sqrt(2/3)
    s = math.sqrt(2 / 3)
    assert t == pytest.approx([1 / s, 0.0, 1 / s])


def test_a_familys_statistic_is_the_signed_root_of_its_unclipped_mean_square():
    # a step within its noise has gap 0 but a negative mean square beyond the noise; the statistic keeps it
    steps = [StepFit("a", "depth", 0.0, 1.0, -0.04), StepFit("b", "depth", 0.3, 1.0, 0.09)]
    assert step_statistics(steps)["gap:depth"] == pytest.approx(math.sqrt((0.09 - 0.04) / 2))
    quiet = [StepFit("a", "depth", 0.0, 1.0, -0.04), StepFit("b", "depth", 0.0, 1.0, -0.02)]
    assert step_statistics(quiet)["gap:depth"] == pytest.approx(-math.sqrt(0.03))  # below 0, not piled up at it
    plain = [StepFit("a", "depth", 0.1, 1.0), StepFit("b", "depth", 0.3, 1.0)]  # no excess given: the gaps' RMS
    assert step_statistics(plain)["gap:depth"] == pytest.approx(math.sqrt((0.01 + 0.09) / 2))
    assert step_statistics(steps)["worst_step_ratio"] == pytest.approx(0.3)


def _replica(seed, gaps, dbic):
    steps = [StepFit(f"s{i}", "depth", g, 1.0) for i, g in enumerate(gaps)]
    return Replica(seed, steps, dbic, None, 0.0)


def test_consistency_and_significance_against_hand_made_null_runs():
    replicas = [_replica(i, [0.1 + 0.01 * i, 0.2], {"wiggling": -5.0 + i * 0.1, "range_scale": -3.0})
                for i in range(19)]
    rule = NullCalibration(replicas)
    inside = step_statistics([StepFit("s0", "depth", 0.15, 1.0), StepFit("s1", "depth", 0.2, 1.0)])
    assert inside["gap:depth"] < max(step_statistics(r.steps)["gap:depth"] for r in replicas)
    quiet_fit = type("G", (), {"steps": [StepFit("s0", "depth", 0.15, 1.0), StepFit("s1", "depth", 0.2, 1.0)]})()
    quiet = rule.judge(quiet_fit)
    assert rule.consistent(quiet_fit) and quiet.p_value > ALPHA and quiet.null_runs == 19
    loud_fit = type("G", (), {"steps": [StepFit("s0", "depth", 0.9, 1.0), StepFit("s1", "depth", 0.9, 1.0)]})()
    loud = rule.judge(loud_fit)
    assert not rule.consistent(loud_fit) and loud.p_value == pytest.approx(1 / 20)
    best = type("F", (), {"score": -2.0})()  # above every null best (the null best is max(-5 + 0.1 i, -3) <= -3.0)
    assert rule.significance(best, {"wiggling", "range_scale"}) == (True, pytest.approx(0.05))
    best = type("F", (), {"score": -3.0})()  # ties with every replica's range_scale
    assert rule.significance(best, {"wiggling", "range_scale"})[0] is False


def test_the_power_model_crosses_the_signature_with_each_replicas_residual():
    """A replica's step mean square with the effect is its own + A^2 mean(s_a s_b) a_a a_b + 2 A mean(r s_a) a_a:
    the signature's power and its product with the replica's residual, on the bins both cover."""
    nan = math.nan
    residual = np.array([[0.2, -0.1, nan, 0.3]], np.float32)  # one step's depth residual map; one bin not compared
    replicas = [Replica(i, [StepFit("s0", "depth", 0.1, 1.0)], {}, np.zeros(5), 0.0,
                        {"depth": {"s0": residual * (i + 1)}}) for i in range(2)]
    sine, cosine = np.array([[1.0, 0.0, -1.0, 0.0]]), np.array([[0.0, 1.0, 0.0, -1.0]])
    signal = _Signal(np.ones(5), np.ones(5, int), {("s0", "depth"): [sine, cosine]})
    power, cross = _Replicas(NullCalibration(replicas), "wiggling", 3, 1, 0.0).crossing(signal)
    assert power[0] == pytest.approx(np.array([[2 / 4, 0.0], [0.0, 2 / 4]]))
    # over the three bins the residual covers: (0.2 * 1 + 0 + 0) / 3 and (0 - 0.1 * 1 - 0.3 * 1) / 3, scaled by i + 1
    assert cross[0, 0] == pytest.approx([0.2 / 3, -0.4 / 3], rel=1e-6)
    assert cross[1, 0] == pytest.approx([0.4 / 3, -0.8 / 3], rel=1e-6)
    two = phases(2)
    assert len(two) == 8 and all(np.linalg.norm(a) == pytest.approx(1.0) for a in two)
    assert np.mean([a[0] ** 2 for a in two]) == pytest.approx(0.5)  # each part carries half the power on average
    assert [list(a) for a in phases(1)] == [[1.0], [-1.0]]


def test_a_replica_runs_the_measured_campaign_with_another_seed_and_no_faults():
    text = CAMPAIGN.format(backend="blaze", seed=7, sweep_step_mm=200, robot=ROBOT).replace(
        "[sim]\nseed = 7", "[sim]\nseed = 7\n[sim.faults]\ndropped_frame = 0.5")
    replica = replica_campaign(text.replace("frames = 10", "frames = 100"), 1000003)
    assert "seed = 1000003" in replica and "faults" not in replica and "frames = 100" not in replica
    assert 7 not in seeds_for(text.replace("seed = 7", "seed = 1000004"), 3)
    assert seeds_for(text.replace("seed = 7", "seed = 1000004"), 3) == [1000003, 1000005, 1000006]


def test_no_null_runs_says_fixed_thresholds(tmp_path):
    run = simulated_run(tmp_path / "run", "blaze101", sweep_step_mm=600, robot=False)
    doc = reconcile_cli(run, tmp_path / "out", null_runs=0)
    assert doc["calibration"] == "fixed thresholds"
    assert doc["null_calibration"]["method"] == "fixed thresholds" and doc["null_calibration"]["null_runs"] == 0
    assert "minimum_detectable" not in doc
    assert "p_value" not in doc["goodness_of_fit"]["before"]


@pytest.fixture(scope="module")
def null_result(tmp_path_factory):
    """A run of the test campaign with nothing hidden, reconciled with 19 null replicas (the replicas depend only on
    the campaign and the model: the tests below judge other runs of the same campaign against them)."""
    run = simulated_run(tmp_path_factory.mktemp("null"), "blaze101", seed=21)
    return reconcile(run, null_runs=DEFAULT_NULL_RUNS)


@pytest.mark.slow
def test_null_replicas_of_the_test_campaign_give_none(null_result, tmp_path):
    doc = to_json(json_document(null_result, tmp_path / "model.toml"))
    assert doc["calibration"] == "null runs" and doc["null_calibration"]["null_runs"] == DEFAULT_NULL_RUNS
    assert doc["verdict"] == "none", doc["goodness_of_fit"]["before"]
    before = doc["goodness_of_fit"]["before"]
    assert before["consistent_with_noise"] and before["p_value"] > ALPHA and before["null_runs"] == DEFAULT_NULL_RUNS
    assert doc["minimum_detectable"]["wiggling"] > 0
    assert any(n.startswith("with 90 % probability this campaign would have named: no ") for n in doc["notes"])


@pytest.mark.slow
def test_a_quarter_millimetre_wiggling_is_named_with_null_runs(null_result, tmp_path):
    run = simulated_run(tmp_path, "blaze101", WIGGLING)
    assert reconcile(run).verdict == "none"  # under the fixed floor (0.48 mm): missed without null runs
    result = reconcile(run, null=null_result.rule)
    assert [e.name for e in result.named] == ["wiggling"], (result.verdict, result.candidates)
    evidence = result.named[0].evidence
    assert evidence.p_value <= ALPHA and evidence.null_runs == DEFAULT_NULL_RUNS
    assert result.named[0].parameters["period_mm"] == pytest.approx(1500.0, rel=0.1)


@pytest.mark.slow
def test_one_and_a_half_times_the_minimum_detectable_wiggling_is_named(null_result, tmp_path):
    """One seed here; bench/reconcile_power.py checks 9 of 10 seeds (docs/reconcile.md)."""
    detail = null_result.minimum_detectable["wiggling"]
    hidden = {"wiggling": {**detail.at, "amplitude_mm": 1.5 * detail.amplitude}}
    result = reconcile(simulated_run(tmp_path, "blaze101", hidden, seed=31), null=null_result.rule)
    assert "wiggling" in [e.name for e in result.named], (hidden, result.verdict, result.candidates)
    evidence = next(e for e in result.named if e.name == "wiggling").evidence
    assert evidence.p_value <= ALPHA and evidence.null_runs == DEFAULT_NULL_RUNS
