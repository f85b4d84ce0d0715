"""A null replica is observed as it is simulated (``StepObserver`` as the run's frame sink,
labctl/reconcile/null.py), none of its frames written: its observations must be those ``observe_run`` makes of the
same run recorded in full, to the last bit, or the null replicas would judge another run than the measured one."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from labctl.reconcile.observe import StepObserver, observe_run
from labctl.run.campaign import run_campaign
from labctl.run.config import load_campaign
from labctl.run.lab import simulated_lab
from labctl.run.progress import Reporter
from tests.reconcile.runs import simulated_run


def test_observed_as_made_equals_observed_from_the_file(tmp_path: Path) -> None:
    recorded = simulated_run(tmp_path, "d455", seed=11, sweep_step_mm=900)
    observations, info, _ = observe_run(recorded)
    wanted = [o.scene.step_id for o in observations][::2]  # a replica observes the steps the comparison uses
    campaign, text = load_campaign(tmp_path / "campaign.toml")
    observer = StepObserver(info["bin_px"], wanted)
    lab = simulated_lab(campaign, (tmp_path / "hidden.toml").read_text(), seed=11, source="hidden.toml")
    run_campaign(campaign, text, lab, tmp_path / "replica.h5", reporter=Reporter(quiet=True), frame_sink=observer)
    made = observer.observations()
    assert [o.scene.step_id for o in made] == wanted
    expected = [o for o in observations if o.scene.step_id in set(wanted)]
    for mine, theirs in zip(made, expected, strict=True):
        for field in dataclasses.fields(mine):
            a, b = getattr(mine, field.name), getattr(theirs, field.name)
            if isinstance(a, np.ndarray):
                assert a.dtype == b.dtype and np.array_equal(a, b, equal_nan=True), (mine.scene.step_id, field.name)
            else:
                assert a == b, (mine.scene.step_id, field.name)
