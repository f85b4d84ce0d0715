"""Reading the next step's arrays while the caller evaluates the current one (labctl/evaluation/read_ahead.py)."""

from __future__ import annotations

import threading

import pytest

from labctl.evaluation.read_ahead import read_ahead


def test_each_step_comes_with_its_own_arrays_in_order_and_the_next_is_read_meanwhile():
    steps = ["a", "b", "c"]
    loaded: list[str] = []
    second_started = threading.Event()
    done_with_first = threading.Event()

    def load(step, slot):
        loaded.append((step, slot))
        if step == "b":
            second_started.set()
        if step == "c":  # into the first step's slot: only once the caller is done with that step
            assert done_with_first.is_set()
        return step.upper()

    seen = []
    for step, arrays in read_ahead(steps, load):  # type: ignore[arg-type]
        if step == "a":  # while the caller holds the first step, the second is read in the background
            assert second_started.wait(5.0)
        seen.append((step, arrays))
        if step == "a":
            done_with_first.set()
    assert seen == [("a", "A"), ("b", "B"), ("c", "C")]
    assert loaded == [("a", 0), ("b", 1), ("c", 0)]  # "c" into "a"'s buffers, read once the caller was done with "a"


def test_no_steps_read_nothing_and_a_failed_read_surfaces_at_its_step():
    assert list(read_ahead([], lambda step, slot: step)) == []

    def load(step, slot):
        if step == "b":
            raise OSError("damaged chunk")
        return step

    seen = []
    with pytest.raises(OSError, match="damaged chunk"):
        for step, _ in read_ahead(["a", "b", "c"], load):  # type: ignore[arg-type]
            seen.append(step)
    assert seen == ["a"]
