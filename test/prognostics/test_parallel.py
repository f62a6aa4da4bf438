"""Many independent runs on local processes or a Dask cluster
(servovalve_twin.prognostics.parallel): every result once, taken as it finishes, in batches
on a cluster, and one line for a cluster that cannot serve."""

from __future__ import annotations

import math
import os
import time

import pytest

from servovalve_twin.errors import TwinError
from servovalve_twin.prognostics import parallel
from servovalve_twin.prognostics.parallel import map_unordered


def _slow_first(x):
    """Item 0 waits until every other item has finished (a file each), then finishes."""
    directory, i = x
    if i == 0:
        deadline = time.monotonic() + 60
        while len(os.listdir(directory)) < 5 and time.monotonic() < deadline:
            time.sleep(0.01)
    else:
        open(os.path.join(directory, str(i)), 'w').close()
    return i


def test_results_come_as_they_finish_not_in_order(tmp_path):
    """Item 0 cannot finish before the five after it: taken in submission order the stream
    would yield nothing until it did; as they finish, 0 comes last."""
    got = list(map_unordered(_slow_first, [(str(tmp_path), i) for i in range(6)], workers=2))
    assert sorted(got) == list(range(6)) and got[-1] == 0


def test_one_worker_runs_here_in_order():
    assert list(map_unordered(math.sqrt, [4.0, 9.0, 16.0], workers=1)) == [2.0, 3.0, 4.0]


@pytest.mark.slow
def test_a_cluster_of_processes_returns_every_item_once_in_batches():
    import distributed
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                  dashboard_address=None) as cluster:
        items = [float(i) for i in range(23)]
        got = list(map_unordered(math.sqrt, items, scheduler=cluster.scheduler_address,
                                 batch=5))
    assert sorted(got) == [math.sqrt(x) for x in items]


@pytest.mark.slow
def test_a_dask_cluster_without_workers_is_a_clear_error(monkeypatch):
    """A cluster whose workers are gone (died, never started) would leave the work waiting
    for ever: after NO_WORKER_S without any worker it is one error naming what to do."""
    import distributed
    monkeypatch.setattr(parallel, 'NO_WORKER_S', 1.0)
    with distributed.LocalCluster(n_workers=0, processes=False,
                                  dashboard_address=None) as cluster:
        with pytest.raises(TwinError, match='has had no worker'):
            list(map_unordered(math.sqrt, [1.0], scheduler=cluster.scheduler_address))


def test_an_unreachable_or_malformed_scheduler_is_one_line():
    with pytest.raises(TwinError, match='cannot reach the Dask scheduler'):
        list(map_unordered(math.sqrt, [1.0], scheduler='tcp://127.0.0.1:9'))
    with pytest.raises(TwinError, match='is not an address'):
        parallel.check_scheduler('::::')


@pytest.mark.slow
def test_a_scheduler_lost_midway_is_one_error_not_a_traceback():
    """The cluster goes away while its tasks run: SchedulerLost (a TwinError: one line, the
    items finished before kept by the caller), not FutureCancelledError's traceback."""
    import threading
    import distributed
    cluster = distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=True,
                                       dashboard_address=None)
    stopper = threading.Timer(3.0, cluster.close)
    stopper.start()
    try:
        with pytest.raises(parallel.SchedulerLost, match='lost the Dask scheduler'):
            list(map_unordered(time.sleep, [1.0] * 30, scheduler=cluster.scheduler_address))
    finally:
        stopper.join()
        cluster.close()
