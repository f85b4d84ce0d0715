"""reconcile.json's keys as the documented contract names them (docs/reconcile.md, JSON): the contract fields
first and in their documented order, a named effect as name / parameters / evidence, a candidate as name /
score; the extensions after them, an optional section only where it applies. No run is simulated: the result
is put together by hand."""

from __future__ import annotations

import math
from pathlib import Path

from labctl.jsondoc import to_json
from labctl.reconcile.results import (
    Ambiguity,
    CandidateScore,
    Determination,
    EmpiricalCorrection,
    Evidence,
    NamedEffect,
    NotComparable,
)
from labctl.reconcile.workflow import ReconcileResult, json_document
from sim.model import parse_model

CONTRACT = ["verdict", "named_effects", "candidates", "gap_before", "gap_after", "gap_unit", "model_toml"]


def _result(**extra) -> ReconcileResult:
    model = parse_model('camera = "blaze101"\n', "test model")
    return ReconcileResult(extra.pop("verdict", "effect_found"), extra.pop("named", []), extra.pop("candidates", []),
                           extra.pop("gap_before", 2.0), extra.pop("gap_after", 0.5), math.nan, math.nan, model,
                           [], [], [], **extra)


def _wiggling() -> NamedEffect:
    evidence = Evidence(delta_bic=120.0, loso_gain=0.8, runner_up="range_scale", runner_up_delta_bic=12.0,
                        stderr={"amplitude_mm": 0.05}, rss_before=10.0, rss_after=1.0, gap_before_mm=2.0,
                        gap_after_mm=0.5, intensity_gap_before_pct=1.0, intensity_gap_after_pct=math.nan, steps=19,
                        determination=Determination(well_determined=True, interval_95={"amplitude_mm": [2.9, 3.1]},
                                                    correlations=[], problems=[], capture=None))
    return NamedEffect(name="wiggling", parameters={"amplitude_mm": 3.0, "period_mm": 900.0, "phase_rad": 0.5},
                       evidence=evidence)


def test_the_contract_fields_come_first_in_their_order():
    doc = to_json(json_document(_result(named=[_wiggling()], candidates=[CandidateScore(name="wiggling",
                                                                                        score=120.0)]),
                                Path("out/model.toml")))
    assert list(doc)[:len(CONTRACT)] == CONTRACT
    assert doc["verdict"] == "effect_found" and doc["gap_unit"] == "mm" and doc["model_toml"] == "out/model.toml"
    assert list(doc["named_effects"][0]) == ["name", "parameters", "evidence"]
    assert doc["named_effects"][0]["parameters"] == {"amplitude_mm": 3.0, "period_mm": 900.0, "phase_rad": 0.5}
    assert doc["candidates"] == [{"name": "wiggling", "score": 120.0}]
    evidence = doc["named_effects"][0]["evidence"]
    assert "family" not in evidence and "gap_before_px" not in evidence  # depth rounds: no corner fields
    assert evidence["intensity_gap_after_pct"] is None  # non-finite: null, never NaN
    assert list(evidence["determination"]) == ["well_determined", "interval_95", "correlations", "problems", "capture"]
    for optional in ("corners", "unexplained", "not_comparable", "ambiguity"):
        assert optional not in doc


def test_an_empirical_correction_carries_its_empirical_name_and_flag():
    fix = EmpiricalCorrection(name="empirical_range", parameters={"range_mm": [0.0, 1.0]}, gap_before_mm=2.0,
                              gap_after_mm=0.4)
    doc = to_json(json_document(_result(verdict="unexplained", empirical=[fix]), Path("m.toml")))
    assert doc["empirical_corrections"] == [{"name": "empirical_range", "parameters": {"range_mm": [0.0, 1.0]},
                                             "empirical": True, "gap_before_mm": 2.0, "gap_after_mm": 0.4}]


def test_not_comparable_and_ambiguous_runs_say_what_would_help():
    needs = NotComparable(reason="no step", comparable_steps=[], procedures_needed={"depth_sweep": "a wall"},
                          not_compared="edge sharpness")
    doc = to_json(json_document(_result(verdict="not_comparable", gap_before=math.nan, gap_after=math.nan,
                                        not_comparable=needs), Path("m.toml")))
    assert doc["gap_before"] is None and doc["gap_after"] is None
    assert doc["not_comparable"] == {"reason": "no step", "comparable_steps": [],
                                     "procedures_needed": {"depth_sweep": "a wall"}, "not_compared": "edge sharpness"}
    both = Ambiguity(between=["wiggling", "multipath"], scores=[80.0, 78.0], separating_capture="00003 at 900 mm")
    doc = to_json(json_document(_result(verdict="ambiguous", ambiguity=both), Path("m.toml")))
    assert list(doc)[-1] == "ambiguity"
    assert doc["ambiguity"] == {"between": ["wiggling", "multipath"], "scores": [80.0, 78.0],
                                "separating_capture": "00003 at 900 mm"}
