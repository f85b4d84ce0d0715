"""Reading the next steps' arrays while the caller evaluates the current one (labctl/evaluation/read_ahead.py)."""

from __future__ import annotations

import threading

import pytest

from labctl.evaluation.read_ahead import SLOTS, read_ahead


def test_each_step_comes_with_its_own_arrays_in_order_and_the_next_two_are_read_meanwhile():
    steps = ["a", "b", "c", "d"]
    loaded: list[tuple[str, int]] = []
    third_read = threading.Event()
    done_with_first = threading.Event()

    def load(step, slot):
        loaded.append((step, slot))
        if step == "c":
            third_read.set()
        if step == "d":  # into the first step's slot: only once the caller is done with that step
            assert done_with_first.is_set()
        return step.upper()

    seen = []
    for step, arrays in read_ahead(steps, load):  # type: ignore[arg-type]
        if step == "a":  # while the caller holds the first step, the next two are read in the background
            assert third_read.wait(5.0)
        seen.append((step, arrays))
        if step == "a":
            done_with_first.set()
    assert SLOTS == 3
    assert seen == [("a", "A"), ("b", "B"), ("c", "C"), ("d", "D")]
    # "d" into "a"'s buffers, once the caller was done; two loads may run at once, so their order is not asserted
    assert sorted(loaded) == [("a", 0), ("b", 1), ("c", 2), ("d", 0)]


def test_the_first_two_steps_are_read_at_the_same_time():
    """Each of the first two loads waits until the other has started: with the steps read one after the other
    (a single reading thread), neither would ever return."""
    started = {"a": threading.Event(), "b": threading.Event()}

    def load(step, slot):
        started[step].set()
        assert started["b" if step == "a" else "a"].wait(5.0), f"{step} was read alone"
        return step

    assert [step for step, _ in read_ahead(["a", "b"], load)] == ["a", "b"]  # type: ignore[arg-type]


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
