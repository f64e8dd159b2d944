"""ns/element for lobe and its Python peers on the catalogue, at 2^20 points, in one run.

    python python/bench/peers.py [--points N] [--repeat R] [--formulas a.brdf b.brdf …]

Peers: numpy, numexpr and numba (each skipped, and said so, when not installed), evaluating the same
formula — lobe's own plain simplification (`Kernel.check()["simplified"]`), translated to each dialect — on
the same float64 arrays. The `cli` column is the command line's batched kernel on the same points: `lobe eval
FILE --points CSV --json` run as a subprocess, its `eval_ns_per_point` (evaluation only, one thread). lobe's
columns: `lobe` (all threads: large batches are split over rayon's threads) and `lobe 1t` (a child process
with RAYON_NUM_THREADS=1, the cli column's conditions); `1t/cli` is their ratio. Times are the median of
--repeat calls, after one warm-up call (numba's compile time is excluded and printed separately).
"""

import argparse
import ast
import copy
import glob
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, "..", "tests"))
from cli import ROOT, lobe_bin  # noqa: E402


def median_ns(f, n, repeat):
    f()
    ts = []
    for _ in range(repeat):
        t = time.perf_counter_ns()
        f()
        ts.append(time.perf_counter_ns() - t)
    return statistics.median(ts) / n


# -- lobe's program text → numpy / numexpr / numba --------------------------------------------------------
def program(text):
    """[(name, expr AST)] for the lets, then ("", root)."""
    lines = [l.strip() for l in text.replace("^", "**").splitlines() if l.strip()]
    out = []
    for l in lines[:-1]:
        assert l.startswith("let "), l
        name, e = l[4:].split("=", 1)
        out.append((name.strip(), ast.parse(e.strip(), mode="eval").body))
    out.append(("", ast.parse(lines[-1], mode="eval").body))
    return out


class Dialect(ast.NodeTransformer):
    """Rewrites calls and names: `calls` maps a lobe builtin to a function of the argument sources."""

    def __init__(self, calls, names):
        self.calls, self.names = calls, names

    def visit_Call(self, node):
        f = node.func.id
        args = [ast.unparse(self.visit(a)) for a in node.args]
        if f not in self.calls:
            raise NotImplementedError(f)
        return ast.parse(self.calls[f](*args), mode="eval").body

    def visit_Name(self, node):
        return ast.parse(self.names.get(node.id, node.id), mode="eval").body


NP_CALLS = {
    "clamp": lambda x, a, b: f"np.clip({x}, {a}, {b})",
    "min": lambda a, b: f"np.minimum({a}, {b})",
    "max": lambda a, b: f"np.maximum({a}, {b})",
    "pow": lambda a, b: f"np.power({a}, {b})",
    **{f: (lambda g: lambda *a: f"np.{g}({', '.join(a)})")(g) for f, g in [("exp", "exp"), ("sqrt", "sqrt"), ("acos", "arccos"), ("sin", "sin"), ("cos", "cos"), ("abs", "abs"), ("log", "log")]},
}
NE_CALLS = {
    "clamp": lambda x, a, b: f"where(({x}) < ({a}), {a}, where(({x}) > ({b}), {b}, {x}))",
    "min": lambda a, b: f"where(({a}) < ({b}), {a}, {b})",
    "max": lambda a, b: f"where(({a}) > ({b}), {a}, {b})",
    "pow": lambda a, b: f"({a}) ** ({b})",
    **{f: (lambda g: lambda *a: f"{g}({', '.join(a)})")(g) for f, g in [("exp", "exp"), ("sqrt", "sqrt"), ("acos", "arccos"), ("sin", "sin"), ("cos", "cos"), ("abs", "abs"), ("log", "log")]},
}
NB_CALLS = {
    "clamp": lambda x, a, b: f"min(max({x}, {a}), {b})",
    "min": lambda a, b: f"min({a}, {b})",
    "max": lambda a, b: f"max({a}, {b})",
    "pow": lambda a, b: f"math.pow({a}, {b})",
    **{f: (lambda g: lambda *a: f"math.{g}({', '.join(a)})")(g) for f, g in [("exp", "exp"), ("sqrt", "sqrt"), ("acos", "acos"), ("sin", "sin"), ("cos", "cos"), ("abs", "fabs"), ("log", "log")]},
}


def translate(prog, calls, names):
    d = Dialect(calls, names)
    return [(n, ast.unparse(d.visit(copy.deepcopy(e)))) for n, e in prog]


def numpy_fn(prog, args):
    body = "".join(f"    {n} = {e}\n" for n, e in translate(prog, NP_CALLS, {"pi": "np.pi"})[:-1])
    src = f"def f({', '.join(args)}):\n{body}    return {translate(prog, NP_CALLS, {'pi': 'np.pi'})[-1][1]}\n"
    ns = {"np": np}
    exec(src, ns)
    return ns["f"]


def numexpr_fn(prog, ne):
    steps = translate(prog, NE_CALLS, {"pi": "pi_"})

    def f(**env):
        env = dict(env, pi_=np.pi)
        for n, e in steps[:-1]:
            env[n] = ne.evaluate(e, local_dict=env)
        return ne.evaluate(steps[-1][1], local_dict=env)

    return f


def numba_fn(prog, args, numba):
    steps = translate(prog, NB_CALLS, {"pi": "math.pi"})
    body = "".join(f"    {n} = {e}\n" for n, e in steps[:-1])
    src = f"def f({', '.join(args)}):\n{body}    return {steps[-1][1]}\n"
    import math

    ns = {"math": math}
    exec(src, ns)
    return numba.vectorize([f"float64({', '.join(['float64'] * len(args))})"], nopython=True)(ns["f"])


def write_csv(path, cols):
    names = list(cols)
    with open(path, "w") as f:
        f.write(",".join(names) + "\n")
        f.write("\n".join(",".join(r) for r in zip(*[map(repr, cols[c].tolist()) for c in names])))
        f.write("\n")


def lobe_times(files, points, repeat):
    """{file: ns/element} for lobe in this process."""
    import lobe

    rng = np.random.default_rng(0)
    cos = {c: rng.uniform(0, 1, points) for c in ("NL", "NV", "NH", "VR", "VH")}
    out = {}
    for path in files:
        k = lobe.compile(path)
        inputs = {c: cos[c] for c in k.inputs}
        out[path] = median_ns(lambda: k(**inputs), points, repeat)
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--points", type=int, default=1 << 20)
    ap.add_argument("--repeat", type=int, default=9)
    ap.add_argument("--formulas", nargs="*", default=sorted(glob.glob(os.path.join(ROOT, "examples", "brdfs", "*.brdf"))))
    ap.add_argument("--lobe-only", action="store_true", help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.lobe_only:
        print(json.dumps(lobe_times(a.formulas, a.points, a.repeat)))
        return
    import lobe

    peers = {}
    for name in ("numexpr", "numba"):
        try:
            peers[name] = __import__(name)
        except ImportError:
            print(f"note: {name} is not installed; its column is skipped (pip install {name})")
    threads = os.cpu_count()
    print(f"{a.points} points, median of {a.repeat}; numpy {np.__version__}" + "".join(f", {n} {m.__version__}" for n, m in peers.items()) + f"; {threads} cores")
    env = dict(os.environ, RAYON_NUM_THREADS="1")
    child = subprocess.run([sys.executable, __file__, "--lobe-only", "--points", str(a.points), "--repeat", str(a.repeat), "--formulas", *a.formulas], env=env, capture_output=True, text=True)
    one = json.loads(child.stdout) if child.returncode == 0 else {}
    if child.returncode != 0:
        print(f"note: the one-thread lobe run failed: {child.stderr.strip()[-300:]}")
    many = lobe_times(a.formulas, a.points, a.repeat)
    binary = lobe_bin()
    if binary is None:
        print("note: no lobe binary (cargo build --release, or set LOBE_BIN); the cli column is skipped")
    rng = np.random.default_rng(0)
    cos = {c: rng.uniform(0, 1, a.points) for c in ("NL", "NV", "NH", "VR", "VH")}
    cols = ["lobe", "lobe 1t", "cli", "1t/cli", "numpy"] + list(peers)
    print(f"{'formula':22s}" + "".join(f"{c:>10s}" for c in cols) + "   ns/element")
    tmp = tempfile.mkdtemp(prefix="lobe-bench-")
    csvs = {}
    for path in a.formulas:
        k = lobe.compile(path)
        used = [c for c in k.inputs]
        inputs = {c: cos[c] for c in used}
        params = k.params
        row = {"lobe": many[path], "lobe 1t": one.get(path)}
        if binary:
            key = tuple(used)
            if key not in csvs:
                csvs[key] = os.path.join(tmp, "_".join(key) + ".csv")
                write_csv(csvs[key], inputs)
            r = subprocess.run([binary, "eval", path, "--points", csvs[key], "--json"], capture_output=True, text=True)
            if r.returncode == 0:
                row["cli"] = json.loads(r.stdout)["eval_ns_per_point"]
        if row.get("cli") and row.get("lobe 1t"):
            row["1t/cli"] = row["lobe 1t"] / row["cli"]
        prog = program(k.check(points=100)["simplified"])
        args = used + [p for p in params]
        try:
            f = numpy_fn(prog, args)
            vals = [inputs[c] for c in used] + [params[p] for p in params]
            with np.errstate(all="ignore"):
                row["numpy"] = median_ns(lambda: f(*vals), a.points, a.repeat)
            if "numexpr" in peers:
                g = numexpr_fn(prog, peers["numexpr"])
                env_ = dict(inputs, **params)
                row["numexpr"] = median_ns(lambda: g(**env_), a.points, a.repeat)
            if "numba" in peers:
                t = time.perf_counter()
                h = numba_fn(prog, args, peers["numba"])
                h(*[v[:1] if isinstance(v, np.ndarray) else v for v in vals])
                row["numba compile ms"] = (time.perf_counter() - t) * 1e3
                row["numba"] = median_ns(lambda: h(*vals), a.points, a.repeat)
        except NotImplementedError as e:
            print(f"note: {os.path.basename(path)}: the peers have no translation of `{e}`")
        cells = "".join(f"{row[c]:10.2f}" if row.get(c) is not None else f"{'—':>10s}" for c in cols)
        extra = f"   numba compile {row['numba compile ms']:.0f} ms" if "numba compile ms" in row else ""
        print(f"{os.path.basename(path):22s}{cells}{extra}")


if __name__ == "__main__":
    main()
