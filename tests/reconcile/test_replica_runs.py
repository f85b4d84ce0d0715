"""How a null replica runs (labctl/reconcile/null.py). It is observed as it is simulated (``StepObserver`` as the
run's frame sink), none of its frames written: its observations must be those ``observe_run`` makes of the same run
recorded in full, to the last bit, or the null replicas would judge another run than the measured one. And it runs
the measured run's steps, its best-focus steps included."""

from __future__ import annotations

import dataclasses
import re
from pathlib import Path

import numpy as np
import pytest

from labctl.cli import main
from labctl.reconcile.null import replica_campaign
from labctl.reconcile.observe import StepObserver, measured_best_focus, observe_run
from labctl.run.campaign import run_campaign
from labctl.run.config import load_campaign, parse_campaign
from labctl.run.lab import simulated_lab
from labctl.run.progress import Reporter
from labctl.run.store import RunReader
from tests.conftest import BEST_FOCUS_PROCEDURES
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


def test_a_replica_places_best_focus_steps_where_the_measured_run_did(tmp_path, write_campaign, focused_model,
                                                                        capsys) -> None:
    """The sharpest distance is found on the run's own slanted edge, so it moves with the noise; a replica takes
    the measured run's (the distance it logged), the star its gap beyond."""
    model = focused_model()
    out = tmp_path / "measured.h5"
    with pytest.raises(SystemExit) as code:
        main(["run", str(write_campaign(procedures=BEST_FOCUS_PROCEDURES)), "--sim", "--model", str(model), "-o", str(out)])
    assert code.value.code == 0
    logged = re.search(r"best focus: (\d+) mm", "".join(capsys.readouterr()))
    assert logged is not None
    with RunReader(out) as run:
        focus = measured_best_focus(run)
        text = run.attrs["campaign_toml"]
    assert focus == float(logged.group(1))
    steps = parse_campaign(replica_campaign(text, 1000003, focus), "replica").steps()
    placed = {s.procedure: s.distance_mm for s in steps if s.procedure != "slanted_edge"}
    assert placed == {"checkerboard": focus, "boehler_star": focus + 250}
    assert all(s.distance_from is None for s in steps)
