"""A run whose frames go to a frame sink instead of its file (``RunWriter.frame_sink``; reconcile's null replicas
are observed so, labctl/reconcile/null.py): the sink receives, at each commit, exactly the stacks the same run
stores when it keeps its frames, an alignment step reads its own stack back from them, and the file keeps the
steps' metadata and timestamps but not one chunk of frames."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import h5py
import hdf5plugin  # noqa: F401 (the run file's compression filter)
import numpy as np
import pytest

from labctl.errors import InputError
from labctl.run.campaign import run_campaign
from labctl.run.config import load_campaign
from labctl.run.lab import simulated_lab
from labctl.run.progress import Reporter
from labctl.run.store import CHANNELS, RunReader, StepRecord
from tests.conftest import BEST_FOCUS_PROCEDURES

PROCEDURES = """
[[procedure]]
kind = "alignment"
frames = 3
field_px = 4

[[procedure]]
kind = "offset_calibration"
frames = 4

[[procedure]]
kind = "depth_sweep"
start_mm = 1000
stop_mm = 2000
step_mm = 500
frames = 4
""" + BEST_FOCUS_PROCEDURES


def _run(campaign_path: Path, model_path: Path, out: Path, sink=None) -> None:
    campaign, text = load_campaign(campaign_path)
    lab = simulated_lab(campaign, model_path.read_text(), seed=5, source=str(model_path))
    run_campaign(campaign, text, lab, out, reporter=Reporter(quiet=True), frame_sink=sink)


def test_the_sink_receives_the_stacks_the_file_would_hold(tmp_path, write_campaign, focused_model):
    campaign, model = write_campaign(procedures=PROCEDURES), focused_model()
    _run(campaign, model, tmp_path / "kept.h5")
    handed: dict[str, dict[str, np.ndarray]] = {}
    attrs: dict[str, dict] = {}

    def sink(step: StepRecord, stack: Callable[[str], np.ndarray]) -> None:
        assert step.step_id not in handed, "a step is handed over once, at its commit"
        assert step.attrs["complete"]
        handed[step.step_id] = {name: stack(name).copy() for name in CHANNELS}
        attrs[step.step_id] = step.attrs

    _run(campaign, model, tmp_path / "sunk.h5", sink)
    with h5py.File(tmp_path / "kept.h5", "r") as kept, h5py.File(tmp_path / "sunk.h5", "r") as sunk:
        assert sunk.attrs["status"] == "complete"
        assert sorted(handed) == sorted(kept["steps"]) == sorted(sunk["steps"])
        assert len(handed) == len(load_campaign(campaign)[0].steps())
        assert "alignment_fields_json" in attrs["00000_alignment"]  # read back from the held stack
        for step_id, stacks in handed.items():
            for name in CHANNELS:
                recorded = kept["steps"][step_id][name][()]
                assert stacks[name].dtype == recorded.dtype
                assert np.array_equal(stacks[name], recorded, equal_nan=True), (step_id, name)
                # the slanted edge's frames are read back by the run (the best focus): the file keeps them too
                kept_here = "slanted_edge" in step_id
                assert (sunk["steps"][step_id][name].id.get_num_chunks() == 0) != kept_here
            np.testing.assert_array_equal(sunk["steps"][step_id]["timestamp"][()],
                                          kept["steps"][step_id]["timestamp"][()])
            for key in ("distance_mm", "laser_distance_mm", "alignment_fields_json"):
                if key in kept["steps"][step_id].attrs:
                    assert attrs[step_id][key] == kept["steps"][step_id].attrs[key]
        checkerboard = next(s for s in handed if "checkerboard" in s)
        assert attrs[checkerboard]["distance_mm"] == kept["steps"][checkerboard].attrs["distance_mm"]
    frames = sum(a.nbytes for step_id, stacks in handed.items() if "slanted_edge" not in step_id
                 for a in stacks.values())
    assert (tmp_path / "sunk.h5").stat().st_size < (tmp_path / "kept.h5").stat().st_size - frames / 2


def test_a_file_without_frames_is_refused_by_name(tmp_path, write_campaign, small_model):
    """Its frames read as zeros: evaluating it would state figures of nothing."""
    _run(write_campaign(), small_model(), tmp_path / "sunk.h5", lambda step, stack: None)
    with h5py.File(tmp_path / "sunk.h5", "r") as f:
        assert not f.attrs["frames_kept"]
    with pytest.raises(InputError, match=r"sunk\.h5 keeps no frames"):
        RunReader(tmp_path / "sunk.h5")
