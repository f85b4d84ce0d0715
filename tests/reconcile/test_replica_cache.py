"""A second reconcile of a campaign against the same model takes its null replicas from the cache; another
model, more null runs or a damaged cache file make only what they lack (labctl/reconcile/replica_cache.py)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from labctl.reconcile import null
from labctl.reconcile.replica_cache import cache_directory
from labctl.reconcile.workflow import reconcile
from sim.model import default_model_text, parse_model
from tests.conftest import REALTIME_GROUP
from tests.reconcile.runs import simulated_run


def test_null_replicas_are_simulated_once_per_model_and_campaign(tmp_path: Path, monkeypatch: pytest.MonkeyPatch):
    monkeypatch.setenv("LABCTL_CACHE_DIR", str(tmp_path / "cache"))
    run = simulated_run(tmp_path / "run", "blaze101", sweep_step_mm=900, robot=False)
    simulated: list[int] = []
    real = null.null_replica

    def counted(*args):  # type: ignore[no-untyped-def]
        simulated.append(args[2])  # the seed
        return real(*args)

    monkeypatch.setattr(null, "null_replica", counted)
    first = reconcile(run, null_runs=2, workers=1)
    assert len(simulated) == 2 and first.rule.cached == 0
    second = reconcile(run, null_runs=2, workers=1)
    assert len(simulated) == 2 and second.rule.cached == 2  # nothing simulated again
    assert second.rule.null_statistics() == first.rule.null_statistics()
    assert second.verdict == first.verdict

    directory = cache_directory()
    assert directory is not None and len(list(directory.glob("*.pickle"))) == 2
    sorted(directory.glob("*.pickle"))[0].write_bytes(b"not a replica")
    more = reconcile(run, null_runs=3, workers=1)  # one kept, the damaged one and a third made
    assert len(simulated) == 4 and more.rule.cached == 1
    assert set(simulated[2:]) < {replica.seed for replica in more.rule.replicas}

    other = parse_model(default_model_text("blaze101") + "\n[effects.range_scale]\nscale = 0.001\n")
    reconcile(run, other, null_runs=1, workers=1)
    assert len(simulated) == 5  # another model: its own replica


def test_a_reconcile_stopped_while_making_replicas_keeps_those_it_made(tmp_path: Path,
                                                                      monkeypatch: pytest.MonkeyPatch):
    monkeypatch.setenv("LABCTL_CACHE_DIR", str(tmp_path / "cache"))
    run = simulated_run(tmp_path / "run", "blaze101", sweep_step_mm=900, robot=False)
    simulated: list[int] = []
    real = null.null_replica

    def stopped_at_the_third(*args):  # type: ignore[no-untyped-def]
        if len(simulated) == 2:
            raise KeyboardInterrupt  # the operator's Ctrl-C while the third replica is made
        simulated.append(args[2])
        return real(*args)

    monkeypatch.setattr(null, "null_replica", stopped_at_the_third)
    with pytest.raises(KeyboardInterrupt):
        reconcile(run, null_runs=3, workers=1)
    directory = cache_directory()
    assert directory is not None and len(list(directory.glob("*.pickle"))) == 2
    monkeypatch.setattr(null, "null_replica", real)
    again = reconcile(run, null_runs=3, workers=1)
    assert again.rule.cached == 2 and [r.seed for r in again.rule.replicas][:2] == simulated


def test_an_empty_cache_directory_setting_switches_the_cache_off(monkeypatch: pytest.MonkeyPatch):
    monkeypatch.setenv("LABCTL_CACHE_DIR", "")
    assert cache_directory() is None
    monkeypatch.delenv("LABCTL_CACHE_DIR")
    monkeypatch.setenv("XDG_CACHE_HOME", "/somewhere")
    assert cache_directory() == Path("/somewhere/labctl/null-replicas")


@pytest.mark.xdist_group(REALTIME_GROUP)  # a local Dask cluster: never beside a realtime test
def test_replicas_made_here_and_on_a_cluster_are_those_made_one_after_the_other(tmp_path: Path,
                                                                               monkeypatch: pytest.MonkeyPatch):
    """With two workers this process makes replicas while a cluster of one more worker makes the others
    (labctl/batch/here_and_cluster.py): each seed's replica is the one the serial path makes."""
    monkeypatch.setenv("LABCTL_CACHE_DIR", "")
    run = simulated_run(tmp_path / "run", "blaze101", sweep_step_mm=900, robot=False)
    serial = reconcile(run, null_runs=4, workers=1).rule.replicas
    shared = reconcile(run, null_runs=4, workers=2).rule.replicas
    assert [r.seed for r in shared] == [r.seed for r in serial]
    for a, b in zip(serial, shared, strict=True):
        assert a.delta_bic == b.delta_bic and a.steps == b.steps
        np.testing.assert_array_equal(a.cell_rss, b.cell_rss)
        assert a.maps.keys() == b.maps.keys()
        for family, by_step in a.maps.items():
            for step, values in by_step.items():
                np.testing.assert_array_equal(values, b.maps[family][step])
