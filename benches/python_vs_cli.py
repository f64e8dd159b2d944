"""2^20 points of every catalogue formula from Python against `lobe eval --points` on the same points.

    RAYON_NUM_THREADS=1 python benches/python_vs_cli.py [--lobe target/release/lobe] [--rounds 5] [--cpu]

Both sides on one thread. Python: the best of ROUNDS calls `k(**columns)` on contiguous float64 columns, the
output returned as a new array, and `k(**columns, out=buffer)` into one reused buffer (the command line's kernel
also writes a reused buffer). The command line: `eval_ns_per_point` of
`lobe eval FILE --points CSV --json`, the kernel's steady state over the same points (the CSV's parsing is
not counted). Prints one row per formula and the ratio Python / CLI.

With --cpu, CPU time instead of wall time on both sides (a shared machine's other work does not count): the
Python process's CPU time (page faults of new memory included, as system time) and the command's
`eval_cpu_ns_per_point`.
"""

import argparse
import glob
import json
import os
import subprocess
import tempfile
import time

import numpy as np

import lobe

ROOT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..")


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--lobe", default=os.path.join(ROOT, "target", "release", "lobe"))
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--points", type=int, default=1 << 20)
    ap.add_argument("--cpu", action="store_true", help="CPU time on both sides instead of wall time")
    a = ap.parse_args()
    rng = np.random.default_rng(1)
    print(f"{'formula':<26} {'python ns/pt':>13} {'out= ns/pt':>11} {'cli ns/pt':>10} {'ratio':>6} {'out= ratio':>10}")
    with tempfile.TemporaryDirectory() as d:
        for path in sorted(glob.glob(os.path.join(ROOT, "examples", "brdfs", "*.brdf"))):
            k = lobe.compile(path)
            cols = {i: rng.uniform(0, 1, a.points) for i in k.inputs}
            csv = os.path.join(d, "p.csv")
            names = list(cols)
            np.savetxt(csv, np.column_stack([cols[n] for n in names]), delimiter=",", header=",".join(names), comments="", fmt="%.17g")
            k(**cols)
            clock = time.process_time if a.cpu else time.perf_counter
            best = min(_timed(lambda: k(**cols), clock) for _ in range(a.rounds))
            buf = np.empty(a.points)
            k(**cols, out=buf)
            best_out = min(_timed(lambda: k(**cols, out=buf), clock) for _ in range(a.rounds))
            r = subprocess.run([a.lobe, "eval", path, "--points", csv, "--json"], capture_output=True, text=True, check=True)
            cli = json.loads(r.stdout)["eval_cpu_ns_per_point" if a.cpu else "eval_ns_per_point"]
            py, po = best / a.points * 1e9, best_out / a.points * 1e9
            print(f"{os.path.basename(path):<26} {py:>13.2f} {po:>11.2f} {cli:>10.2f} {py / cli:>6.2f} {po / cli:>10.2f}")


def _timed(f, clock):
    t = clock()
    f()
    return clock() - t


if __name__ == "__main__":
    main()
