"""The batch's local Dask cluster: its own log lines stay off the batch's stderr."""

from __future__ import annotations

import logging

import pytest

from labctl.batch.cluster import Cluster, open_client

PROBE = "a log line of the cluster's own"


@pytest.mark.parametrize("logger", ["distributed.worker", "distributed.scheduler", "distributed.nanny"])
def test_the_cluster_s_error_logs_stay_off_stderr(capfd: pytest.CaptureFixture[str], logger: str) -> None:
    """Dask's scheduler, nannies and workers log their own errors, e.g. a worker's heartbeat that meets the
    scheduler already closing after a Ctrl-C, with a traceback. The batch reports every run's outcome
    itself (a task lost on the cluster included), so none of these lines reaches its stderr: one logged at
    ERROR in a worker process and in the batch's own process (where the scheduler runs) shows nowhere."""
    with open_client(Cluster(workers=1)) as client:
        client.run(logging.getLogger(logger).error, PROBE)  # in the worker process, whose stderr is ours
        logging.getLogger(logger).error(PROBE)
    out, err = capfd.readouterr()
    assert PROBE not in out + err
