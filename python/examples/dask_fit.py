"""Fit several formulas to several targets, serially and on a Dask cluster, and check the results agree.

    python python/examples/dask_fit.py                     # a LocalCluster of 2 worker processes
    python python/examples/dask_fit.py tcp://scheduler:8786 # an existing cluster

Each job is one `lobe.fit` call. A `lobe.Kernel` pickles as its source text, so it travels to the worker,
which compiles it again; the fit is deterministic, so every job gives the same parameters wherever it runs.
"""

import os
import sys

import numpy as np

import lobe

HERE = os.path.dirname(os.path.abspath(__file__))
BRDFS = os.path.join(HERE, "..", "..", "examples", "brdfs")

# (formula fitted, parameters searched) × (reference formula, its parameters): the targets.
FORMULAS = [("modified_schlick.brdf", {"n": (1, 1000)}), ("schlick.brdf", {"n": (1, 1000)}), ("fst.brdf", {"a": (1, 200)})]
TARGETS = [("blinn.brdf", {"n": 100.0}), ("gaussian.brdf", {"n": 40.0}), ("beckmann.brdf", {"m": 0.3})]


def jobs(points=2000, seed=1):
    """Every (name, kernel, target values, params to fit, inputs) job."""
    rng = np.random.default_rng(seed)
    nh = np.sort(rng.uniform(0, 1, points))
    out = []
    for tname, tparams in TARGETS:
        target = lobe.compile(os.path.join(BRDFS, tname))(NH=nh, **tparams)
        target = target / np.max(target)
        for fname, free in FORMULAS:
            k = lobe.compile(os.path.join(BRDFS, fname))
            out.append((f"{fname} to {tname}", k, target, free, {"NH": nh}))
    return out


def run_serial(js):
    return {name: lobe.fit(k, t, free, **inputs) for name, k, t, free, inputs in js}


def run_dask(client, js):
    futures = {name: client.submit(lobe.fit, k, t, free, pure=False, **inputs) for name, k, t, free, inputs in js}
    return {name: f.result() for name, f in futures.items()}


def main(address=None):
    from dask.distributed import Client, LocalCluster

    js = jobs()
    serial = run_serial(js)
    if address:
        client = Client(address)
    else:
        cluster = LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1", dashboard_address=None)
        client = Client(cluster)
    with client:
        distributed = run_dask(client, js)
    free = {name: f for name, _, _, f, _ in js}
    for name in serial:
        s, d = serial[name], distributed[name]
        mark = "same" if s == d else "DIFFERENT"
        # The parameters this job fitted (F_ST's `a`, the others' `n`), not the first job's.
        shown = ", ".join(f"{p}={s['params'][p]:.6g}" for p in free[name])
        print(f"{name:40s} score {s['score']:.3e}  {shown}  ({mark} on Dask)")
    assert serial == distributed, "the cluster's fits differ from the serial ones"


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else None)
