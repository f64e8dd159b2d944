#!/usr/bin/env python3
"""The Python module's cost per element with parameters given three ways, on the catalogue: ns/element.

    pip install ./python                       # the module (and numpy)
    python benches/python_params.py [--points 1048576] [--rounds 5] [--formulas a.brdf …]

For each formula, 2²⁰ points (the cosines uniform in [0, 1], one seed) through `kernel(**cosines, n=…)` with n
(the parameter every catalogue formula has, 1..1000) given as
- one value (the batched kernel, its parameter-only work done once);
- an array of runs of 1024 equal values (a table over n: one batched call per run);
- an array of a different value per point (one batched call per point, each doing the parameter-only work).
One thread (RAYON_NUM_THREADS=1, set here); the process's CPU time, as the work runs on rayon's thread; each
sample after a warm-up call, the table shows the median of --rounds samples.
"""

import argparse
import glob
import os
import statistics
import time

os.environ["RAYON_NUM_THREADS"] = "1"

import numpy as np  # noqa: E402

import lobe  # noqa: E402

ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), ".."))


def cost(f, points, rounds):
    f()
    samples = []
    for _ in range(rounds):
        t = time.process_time()
        f()
        samples.append((time.process_time() - t) / points * 1e9)
    return statistics.median(samples)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--points", type=int, default=1 << 20)
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--formulas", nargs="*", default=sorted(glob.glob(os.path.join(ROOT, "examples", "brdfs", "*.brdf"))))
    a = ap.parse_args()
    n = a.points
    rng = np.random.default_rng(1)
    cos = {c: rng.uniform(0, 1, n) for c in ("NL", "NV", "NH", "VR", "VH")}
    runs = np.repeat(rng.uniform(1, 1000, n // 1024 + 1), 1024)[:n]
    each = rng.uniform(1, 1000, n)
    print(f"{n} points, one thread, ns/element (median of {a.rounds})")
    print("| formula | one value | runs of 1024 | one per point | per point / one |")
    print("|---|---:|---:|---:|---:|")
    for path in a.formulas:
        k = lobe.compile(path)
        kw = {c: cos[c] for c in k.inputs}
        row = [cost(lambda: k(**kw, n=v), n, a.rounds) for v in (50.0, runs, each)]
        print(f"| {k.name} | {row[0]:.2f} | {row[1]:.2f} | {row[2]:.2f} | {row[2] / row[0]:.1f} |")


if __name__ == "__main__":
    main()
