"""Tasks made in this process and on a local cluster from one queue (labctl/batch/here_and_cluster.py): every item
made once, by both sides; a task's error raised here; a cluster that cannot start leaves its items to this
process; Ctrl-C here stops the cluster's thread."""

from __future__ import annotations

import os
import threading

import pytest

from labctl.batch import here_and_cluster
from labctl.batch.here_and_cluster import make_here_and_on_cluster
from tests.conftest import REALTIME_GROUP

pytestmark = pytest.mark.xdist_group(REALTIME_GROUP)  # a local Dask cluster: never beside a realtime test

#: seconds to wait for the cluster's first result (its start on a loaded machine included)
CLUSTER_WAIT_S = 120.0


def made_where(item: int) -> tuple[int, int]:
    """The item and the process that made it."""
    if item < 0:
        raise ValueError(f"item {item} cannot be made")
    return item, os.getpid()


class Record:
    """The results kept, and an event set once the cluster (another process) has made one."""

    def __init__(self) -> None:
        self.kept: dict[int, int] = {}
        self.elsewhere = threading.Event()

    def keep(self, item: int, result: tuple[int, int]) -> None:
        assert result[0] == item and item not in self.kept
        self.kept[item] = result[1]
        if result[1] != os.getpid():
            self.elsewhere.set()


def test_every_item_is_made_once_here_and_on_the_cluster() -> None:
    record = Record()
    made_here: list[int] = []

    def here(item: int) -> None:  # this process waits at its second item until the cluster has made one
        made_here.append(item)
        if len(made_here) == 2:
            assert record.elsewhere.wait(CLUSTER_WAIT_S)

    items = list(range(12))
    problems = make_here_and_on_cluster(made_where, items, 2, record.keep, here)
    assert problems == []
    assert sorted(record.kept) == items
    here_made = {i for i, pid in record.kept.items() if pid == os.getpid()}
    assert here_made == set(made_here) and 0 < len(here_made) < len(items)


def test_a_task_that_fails_on_the_cluster_raises_its_error_here() -> None:
    record = Record()

    def here(item: int) -> None:  # this process holds item 0 until the cluster has met item -1 and stopped
        if item == 0:
            for thread in [t for t in threading.enumerate() if t.name == "labctl-cluster"]:
                thread.join(CLUSTER_WAIT_S)
                assert not thread.is_alive()

    with pytest.raises(ValueError, match="item -1 cannot be made"):
        make_here_and_on_cluster(made_where, [0, -1, 1, 2, 3, 4, 5, 6], 2, record.keep, here)
    assert not any(t.name == "labctl-cluster" for t in threading.enumerate())


def test_a_cluster_that_cannot_start_leaves_its_items_here(monkeypatch: pytest.MonkeyPatch) -> None:
    def no_cluster(_):  # type: ignore[no-untyped-def]
        raise OSError("no processes can be started")

    monkeypatch.setattr(here_and_cluster, "open_client", no_cluster)
    record = Record()
    problems = make_here_and_on_cluster(made_where, list(range(5)), 2, record.keep)
    assert problems == ["OSError: no processes can be started"]
    assert record.kept == {i: os.getpid() for i in range(5)}


def test_ctrl_c_here_stops_the_cluster_s_thread() -> None:
    record = Record()

    def here(item: int) -> None:  # the operator's Ctrl-C once the cluster works
        assert record.elsewhere.wait(CLUSTER_WAIT_S)
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        make_here_and_on_cluster(made_where, list(range(50)), 2, record.keep, here)
    assert not any(t.name == "labctl-cluster" for t in threading.enumerate())
    assert len(record.kept) < 50
