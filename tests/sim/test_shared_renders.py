"""Noise-free step maps shared between runs of one model (sim/shared_renders.py, reconcile's null replicas): a run
that takes them from an earlier run of another seed gives the very frames it gives when it makes them itself, and a
run of another model never takes them."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from labctl.run.campaign import run_campaign
from labctl.run.config import load_campaign
from labctl.run.lab import simulated_lab
from labctl.run.progress import Reporter
from labctl.run.store import CHANNELS, StepRecord
from sim import shared_renders
from sim.stereo import StereoSensor
from sim.tof import ToFSensor


def _frames(tmp_path: Path, campaign: Path, model_text: str, seed: int) -> dict[str, dict[str, np.ndarray]]:
    """Every step's stacks of a simulated run of ``campaign`` (handed over, none written)."""
    stacks: dict[str, dict[str, np.ndarray]] = {}

    def sink(step: StepRecord, stack: Callable[[str], np.ndarray]) -> None:
        stacks[step.step_id] = {name: stack(name).copy() for name in CHANNELS}

    config, text = load_campaign(campaign)
    out = tmp_path / f"run-{seed}-{len(list(tmp_path.iterdir()))}.h5"
    run_campaign(config, text, simulated_lab(config, model_text, seed=seed, source="model"), out,
                 reporter=Reporter(quiet=True), frame_sink=sink)
    return stacks


@pytest.mark.parametrize(("camera", "sensor"), [("blaze101", ToFSensor), ("d455", StereoSensor)])
def test_shared_maps_give_the_frames_the_run_makes_alone(tmp_path, write_campaign, small_model, monkeypatch,
                                                         camera, sensor):
    campaign, model = write_campaign(), small_model(camera).read_text()
    alone = _frames(tmp_path, campaign, model, seed=12)
    made = []
    real = sensor.prepare
    monkeypatch.setattr(sensor, "prepare", lambda self, *a, **k: made.append(a) or real(self, *a, **k))
    try:
        with shared_renders.shared_renders(1 << 28):
            _frames(tmp_path, campaign, model, seed=11)
            first = len(made)
            shared = _frames(tmp_path, campaign, model, seed=12)
            assert first > 0 and len(made) == first  # the second run made no map of its own
            other = model.replace("[camera_overrides]", "[effects.vignetting]\nexponent = 4.0\n[camera_overrides]")
            _frames(tmp_path, campaign, other, seed=12)
            assert len(made) == 2 * first  # another model makes its own
    finally:
        shared_renders.forget()
    assert shared.keys() == alone.keys()
    for step_id, stacks in alone.items():
        for name in CHANNELS:
            assert np.array_equal(shared[step_id][name], stacks[name], equal_nan=True), (step_id, name)


def test_nothing_is_shared_outside_or_beyond_the_budget(tmp_path, write_campaign, small_model, monkeypatch):
    campaign, model = write_campaign(), small_model().read_text()
    made = []
    real = ToFSensor.prepare
    monkeypatch.setattr(ToFSensor, "prepare", lambda self, *a, **k: made.append(a) or real(self, *a, **k))
    _frames(tmp_path, campaign, model, seed=11)
    _frames(tmp_path, campaign, model, seed=12)
    assert len(made) % 2 == 0 and made[: len(made) // 2] != []
    n = len(made) // 2
    try:
        with shared_renders.shared_renders(1):  # room for no map
            _frames(tmp_path, campaign, model, seed=11)
            _frames(tmp_path, campaign, model, seed=12)
    finally:
        shared_renders.forget()
    assert len(made) == 4 * n
