"""Fits on a Dask LocalCluster (2 worker processes, loopback) give the serial run's parameters exactly."""

import os
import sys

import pytest

sys.path.insert(0, os.path.join(os.path.dirname(__file__), "..", "examples"))

distributed = pytest.importorskip("dask.distributed")

import dask_fit  # noqa: E402


def test_dask_fits_equal_serial():
    js = dask_fit.jobs(points=1500, seed=3)
    serial = dask_fit.run_serial(js)
    cluster = distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1", dashboard_address=None)
    with cluster, distributed.Client(cluster) as client:
        on_dask = dask_fit.run_dask(client, js)
        # The jobs ran on the workers (other processes), not here.
        pids = set(client.run(os.getpid).values())
        assert os.getpid() not in pids and len(pids) == 2
    assert serial.keys() == on_dask.keys() and len(serial) == 9
    for name in serial:
        assert serial[name] == on_dask[name], name
    # The fits found something: each score is finite and its parameters are inside the searched ranges.
    for name, k, t, free, _ in js:
        r = serial[name]
        assert r["score"] < float("inf")
        for p, (lo, hi) in free.items():
            assert lo <= r["params"][p] <= hi
