"""The simulation-based calibration's tables (bench/reconcile_sbc.py) count what they say they count."""

from __future__ import annotations

from bench.reconcile_sbc import named_right, table


def _draw(hidden: list[str], named: list[str], not_tested: list[str] | None = None) -> dict:
    draw = {"label": "pairs", "hidden": hidden, "named": named, "covered": [True], "within_floor": True,
            "verdict": "effect_found" if named else "none"}
    if not_tested is not None:  # records written before the field existed have none
        draw["not_tested"] = not_tested
    return draw


def test_an_unnamed_effect_is_right_only_when_stated_not_tested():
    assert named_right(_draw(["a", "b"], ["a", "b"]))
    assert named_right(_draw(["a", "b"], ["a"], ["b"]))
    assert not named_right(_draw(["a", "b"], ["a"], []))
    assert not named_right(_draw(["a", "b"], ["a"]))
    assert not named_right(_draw(["a"], ["a", "c"], []))  # something else named
    assert not named_right(_draw(["a", "b"], ["a", "b"], ["b"]))  # named although stated not tested


def test_the_table_counts_right_draws_and_those_with_an_effect_not_tested():
    draws = [_draw(["a", "b"], ["a", "b"], []), _draw(["a", "b"], ["a"], ["b"]), _draw(["a", "b"], [], [])]
    row = table(draws).splitlines()[-1]
    assert row == "| pairs | 3 | 2/3 (67%) | 3/3 (100%) | 3/3 (100%) | 1 | 0 |"
