"""The simulation-based calibration's tables (bench/reconcile_sbc.py) count what they say they count."""

from __future__ import annotations

import tomllib

from bench.reconcile_sbc import ambiguous_with_hidden, example_campaign, example_campaigns, named_right, plan, table
from labctl.reconcile.observe import MAX_FRAMES


def _draw(hidden: list[str], named: list[str], not_tested: list[str] | None = None,
          ambiguous: list[str] | None = None) -> dict:
    draw = {"label": "pairs", "hidden": hidden, "named": named, "covered": [True], "within_floor": True,
            "verdict": "effect_found" if named else "ambiguous" if ambiguous else "none"}
    if not_tested is not None:  # records written before the field existed have none
        draw["not_tested"] = not_tested
    if ambiguous is not None:  # nor this one
        draw["ambiguous"] = ambiguous
    return draw


def test_an_unnamed_effect_is_right_only_when_stated_not_tested():
    assert named_right(_draw(["a", "b"], ["a", "b"]))
    assert named_right(_draw(["a", "b"], ["a"], ["b"]))
    assert not named_right(_draw(["a", "b"], ["a"], []))
    assert not named_right(_draw(["a", "b"], ["a"]))
    assert not named_right(_draw(["a"], ["a", "c"], []))  # something else named
    assert not named_right(_draw(["a", "b"], ["a", "b"], ["b"]))  # named although stated not tested


def test_the_table_counts_right_draws_and_those_with_an_effect_not_tested():
    draws = [_draw(["a", "b"], ["a", "b"], []), _draw(["a", "b"], ["a"], ["b"]), _draw(["a", "b"], [], []),
             _draw(["a"], [], [], ["a", "c"]), _draw(["a"], [], [], ["c", "d"])]
    row = table(draws).splitlines()[-1]
    assert row == "| pairs | 5 | 2/5 (40%) | 5/5 (100%) | 5/5 (100%) | 1 | 1 | 0 |"


def test_an_ambiguous_draw_counts_only_with_a_hidden_effect_among_the_candidates():
    assert ambiguous_with_hidden(_draw(["a"], [], [], ["a", "c"]))
    assert ambiguous_with_hidden(_draw(["a", "b"], [], [], ["c", "b"]))
    assert not ambiguous_with_hidden(_draw(["a"], [], [], ["c", "d"]))  # between two it was not given
    assert not ambiguous_with_hidden(_draw(["a"], ["a"], []))  # named
    assert not ambiguous_with_hidden(_draw(["a"], [], []))  # a record written before the field


def test_a_draw_on_an_example_campaign_takes_its_cameras_campaigns_with_the_reconciles_frames():
    """Each draw's campaign is one of examples/ whose camera backend is the draw's camera, with every stack cut to
    the frames reconcile reads and the draw's seed."""
    assert example_campaigns("blaze101") == ["blaze101.toml", "depth_blaze101.toml"]
    assert example_campaigns("d455") == ["d455.toml"]
    campaign = tomllib.loads(example_campaign("d455.toml", 1234))
    assert campaign["sim"]["seed"] == 1234
    assert {p["frames"] for p in campaign["procedure"]} == {MAX_FRAMES}
    tasks = plan(1, 2, 2, examples=True)
    assert [t[:4] for t in tasks] == [t[:4] for t in plan(1, 2, 2)]  # the same draws as on the test campaign
    assert all(t[4] in example_campaigns(t[1]) for t in tasks)
