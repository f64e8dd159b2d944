#!/usr/bin/env python3
"""lobe's two JIT tiers against Dr.Jit, numba and numpy on the catalogue: ns/element and bits of error, one run.

    python3 -m venv .venv && .venv/bin/pip install drjit==1.5.0 numba numpy     # the peers (any subset)
    cargo build --release --features llvm                                       # lobe with both tiers
    .venv/bin/python benches/peers.py [--points 1048576] [--rounds 5] [--json] [--formulas a.brdf …]

Every system evaluates the same formula on the same float64 points (the cosines uniform in [0, 1], one seed)
at the formula's declared parameter values, baked as constants everywhere (as `lobe bench` bakes n = 50; with
--live they are run-time values: lobe's live parameters, Dr.Jit's opaque scalars, numba's arguments), on one
thread:
- lobe: `lobe eval FILE --set P=V,… --points CSV --json --tier cranelift|llvm` (the accuracy pass's kernel, what
  every command compiles), its `eval_cpu_ns_per_point`: the steady state of the batched kernel into a written
  output; and `llvm-speed`, the same with `--prefer speed` (the plain simplification the peers run, with lobe's
  precise math library): what the accuracy pass costs, and what the arithmetic alone costs;
- the peers evaluate lobe's own plain simplification at the same values (`lobe check --set … --json`, its
  `simplified`), translated to each dialect: numpy (whole-array operations), numba (an `@njit` loop into a preallocated output), Dr.Jit (its LLVM
  backend, `drjit.set_thread_count(1)`: every kernel on the calling thread; each timed call traces the
  expression, finds its kernel in Dr.Jit's cache and runs it, `dr.eval` + `dr.sync_thread`), numexpr; lobe's
  own Python module (Cranelift) when it is installed (`pip install ./python`).
A peer that is not installed is skipped and named. Times are this thread's CPU time (the machine may be shared),
each sample the median of passes repeated for ≥ 3 passes and ≥ 20 ms after a warm-up call (which compiles); the
systems take turns within every round (the order rotates), and the table shows the minimum over rounds and the
spread (max/min − 1). Errors: bits (log2(ulps + 1)) against the truth, `lobe eval --truth` (the formula as
written in ~104-bit precision), max over the points where the truth is finite (no conditioning filter, unlike
`lobe check`'s "κ ≤ 16"), with the count of points beyond 4 bits and of non-finite values there. Compile times: lobe's `compile_us`, numba's first call, Dr.Jit's first call less a warm one.
"""

import argparse
import ast
import copy
import glob
import json
import os
import platform
import shutil
import statistics
import subprocess
import sys
import tempfile
import time

# One thread everywhere, before the libraries start their pools.
for _v in ("RAYON_NUM_THREADS", "NUMBA_NUM_THREADS", "OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMEXPR_MAX_THREADS", "NUMEXPR_NUM_THREADS"):
    os.environ[_v] = "1"

import numpy as np  # noqa: E402

ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), ".."))
COSINES = ("NL", "NV", "NH", "VR", "VH")


def lobe_bin():
    """$LOBE_BIN, else target/release/lobe, else `lobe` on PATH."""
    if os.environ.get("LOBE_BIN"):
        return os.environ["LOBE_BIN"]
    p = os.path.join(ROOT, "target", "release", "lobe")
    return p if os.access(p, os.X_OK) else shutil.which("lobe")


def run_json(args):
    r = subprocess.run(args, capture_output=True, text=True)
    if r.returncode != 0:
        raise RuntimeError(f"{' '.join(args)}: {r.stderr.strip()[-500:]}")
    return json.loads(r.stdout)


def steady(f, n):
    """ns/element of `f` (which does `n` elements) in this thread's CPU time: a warm-up call, then the median of
    passes repeated for ≥ 3 passes and ≥ 20 ms (or 1 s), as `lobe eval --points --json` times its kernel."""
    f()
    start, ns, wall = time.perf_counter(), [], []
    while len(ns) < 3 or (time.perf_counter() - start < 0.02 and len(ns) < 1000):
        t, w = time.thread_time_ns(), time.perf_counter_ns()
        f()
        ns.append(time.thread_time_ns() - t)
        wall.append(time.perf_counter_ns() - w)
        if time.perf_counter() - start > 1:
            break
    return statistics.median(ns) / n, statistics.median(wall) / n


# -- lobe's program text → each dialect ---------------------------------------------------------------------
def program(text):
    """[(name, expr AST)] for the `let` lines, then ("", root)."""
    lines = [l.strip() for l in text.replace("^", "**").splitlines() if l.strip()]
    out = []
    for l in lines[:-1]:
        if not l.startswith("let "):
            raise NotImplementedError(l)
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


# sinnear is lobe's sin on an argument range analysis bounds (its simplifier's coding): the peers' sin.
FUNCS = ["exp", "sqrt", "sin", "sinnear", "cos", "abs", "log", "ln", "acos"]


def dialect(clamp, minimum, maximum, power, prefix, **rename):
    """A dialect's calls: format strings of the four forms that differ, then `prefix + name(x)` for the
    one-argument functions (`rename`: a lobe builtin's name in the dialect, where it differs)."""
    rename = {"sinnear": "sin", **rename}
    forms = {"clamp": clamp, "min": minimum, "max": maximum, "pow": power}
    out = {f: (lambda t: lambda *a: t.format(*a))(t) for f, t in forms.items()}
    out.update({f: (lambda g: lambda x: f"{prefix}{g}({x})")(rename.get(f, f)) for f in FUNCS})
    return out


NP_CALLS = dialect("np.clip({0}, {1}, {2})", "np.minimum({0}, {1})", "np.maximum({0}, {1})", "np.power({0}, {1})", "np.", ln="log", acos="arccos")
NE_CALLS = dialect(
    "where(({0}) < ({1}), {1}, where(({0}) > ({2}), {2}, {0}))", "where(({0}) < ({1}), {0}, {1})", "where(({0}) > ({1}), {0}, {1})", "({0}) ** ({1})", "", ln="log", acos="arccos"
)
NB_CALLS = dialect("min(max({0}, {1}), {2})", "min({0}, {1})", "max({0}, {1})", "math.pow({0}, {1})", "math.", ln="log", abs="fabs")
DR_CALLS = dialect("dr.clip({0}, {1}, {2})", "dr.minimum({0}, {1})", "dr.maximum({0}, {1})", "dr.power({0}, {1})", "dr.", ln="log")


def translate(prog, calls, names):
    d = Dialect(calls, names)
    return [(n, ast.unparse(d.visit(copy.deepcopy(e)))) for n, e in prog]


def function(prog, args, calls, names, ns):
    """`def f(*args)`: the lets, then `return root`, in the dialect."""
    steps = translate(prog, calls, names)
    body = "".join(f"    {n} = {e}\n" for n, e in steps[:-1])
    exec(f"def f({', '.join(args)}):\n{body}    return {steps[-1][1]}\n", ns)
    return ns["f"]


def numba_loop(prog, inputs, params, numba):
    """An `@njit` loop over the points into `out` (one thread, no fastmath)."""
    import math

    steps = translate(prog, NB_CALLS, {"pi": "math.pi"})
    load = "".join(f"        {c} = {c}_[i]\n" for c in inputs)
    body = "".join(f"        {n} = {e}\n" for n, e in steps[:-1])
    src = f"def f({', '.join([c + '_' for c in inputs] + ['out'] + params)}):\n    for i in range(out.shape[0]):\n{load}{body}        out[i] = {steps[-1][1]}\n"
    ns = {"math": math}
    exec(src, ns)
    return numba.njit(ns["f"], fastmath=False, parallel=False, nogil=True)


def numexpr_fn(prog, ne, env):
    steps = translate(prog, NE_CALLS, {"pi": "pi_"})

    def f():
        e = dict(env, pi_=np.pi)
        for n, x in steps[:-1]:
            e[n] = ne.evaluate(x, local_dict=e)
        return ne.evaluate(steps[-1][1], local_dict=e)

    return f


# -- errors ---------------------------------------------------------------------------------------------------
def ordered(x):
    """f64 bits as int64 ordered like the values (lobe's `ulps`)."""
    b = np.ascontiguousarray(x, dtype=np.float64).view(np.int64)
    return np.where(b < 0, np.iinfo(np.int64).min - b, b)


def ulps(a, b):
    """|a − b| in ulps, as lobe's `ulps` counts them (exact within a sign; across signs, as float64)."""
    oa, ob = ordered(a), ordered(b)
    same = (oa < 0) == (ob < 0)
    with np.errstate(over="ignore"):
        d = np.where(same, np.abs(oa - ob).astype(np.float64), np.abs(oa.astype(np.float64)) + np.abs(ob.astype(np.float64)))
    return d


def error(got, truth):
    """Max and mean bits (log2(ulps + 1)) where the truth is finite, and the non-finite values there."""
    got = np.broadcast_to(np.asarray(got, dtype=np.float64), truth.shape)
    fin = np.isfinite(truth)
    g, t = got[fin], truth[fin]
    u = ulps(g, t)
    u[np.isnan(g)] = 2.0**64
    b = np.log2(u + 1)
    return {
        "max_bits": float(b.max()) if b.size else 0.0,
        "avg_bits": float(b.mean()) if b.size else 0.0,
        "over_4_bits": int((b > 4).sum()),
        "nonfinite": int((~np.isfinite(g)).sum()),
    }


def values(report):
    return np.asarray(report["values"], dtype=np.float64)


# -- the systems ----------------------------------------------------------------------------------------------
class Lobe:
    """One tier of the command line's batched kernel: a subprocess per sample (it reads the CSV each time)."""

    def __init__(self, binary, tier, name=None, extra=()):
        self.binary, self.tier, self.name, self.extra = binary, tier, name or tier, list(extra)

    def prepare(self, f):
        args = [self.binary, "eval", f.path, *f.set, "--points", f.csv, "--json", "--tier", self.tier, *self.extra]
        r = run_json(args)
        f.meta[self.name] = {"compile_ms": r["compile_us"] / 1e3, "lanes": r.get("lanes")}
        def sample():
            r = run_json(args)
            return r["eval_cpu_ns_per_point"], r["eval_ns_per_point"]

        return values(r), sample


class Peer:
    """A Python system: `build(f)` returns (call, result of a call → float64 array)."""

    def __init__(self, name, module, build):
        self.name, self.module, self.build = name, module, build

    def prepare(self, f):
        t = time.perf_counter()
        call, result = self.build(self.module, f)
        first = result(call())
        compile_s = time.perf_counter() - t
        t = time.perf_counter()
        call()
        f.meta[self.name] = {"compile_ms": (compile_s - (time.perf_counter() - t)) * 1e3}
        return first, lambda: steady(call, f.n)


def build_numpy(np_, f):
    g = function(f.prog, f.inputs + f.param_names, NP_CALLS, {"pi": "np.pi"}, {"np": np_})
    args = [f.cols[c] for c in f.inputs] + f.param_values

    def call():
        with np_.errstate(all="ignore"):
            return g(*args)

    return call, lambda r: r


def build_numba(numba, f):
    g = numba_loop(f.prog, f.inputs, f.param_names, numba)
    out = np.empty(f.n)
    args = [f.cols[c] for c in f.inputs] + [out] + f.param_values
    return (lambda: g(*args)), (lambda _: out.copy())


def build_numexpr(ne, f):
    return numexpr_fn(f.prog, ne, dict({c: f.cols[c] for c in f.inputs}, **dict(zip(f.param_names, f.param_values)))), (lambda r: r)


def build_drjit(dr, f):
    g = function(f.prog, f.inputs + f.param_names, DR_CALLS, {"pi": "dr.pi"}, {"dr": dr})
    from drjit.llvm import Float64

    cols = drjit_columns(dr, f)
    # A live parameter is an opaque scalar: a run-time value of the kernel, not a literal Dr.Jit folds.
    args = [cols[c] for c in f.inputs] + [dr.opaque(Float64, v) for v in f.param_values]

    def call():
        y = g(*args)
        dr.eval(y)
        dr.sync_thread()
        return y

    return call, lambda y: np.broadcast_to(np.asarray(y, dtype=np.float64), (f.n,)).copy()


_DR_COLS = {}


def drjit_columns(dr, f):
    """The cosine columns as Dr.Jit LLVM arrays (made once: the copy is not timed)."""
    from drjit.llvm import Float64

    for c in f.inputs:
        if c not in _DR_COLS:
            _DR_COLS[c] = Float64(f.cols[c])
            dr.eval(_DR_COLS[c])
    dr.sync_thread()
    return _DR_COLS


def build_module(lobe, f):
    k = lobe.compile(f.path, **f.baked)
    inputs = {c: f.cols[c] for c in k.inputs}
    return (lambda: k(**inputs)), (lambda r: r)


def peers():
    """(the peers found, {skipped: why})."""
    found, skipped = [], {}
    for name, module, build in [("drjit", "drjit", build_drjit), ("numba", "numba", build_numba), ("numpy", "numpy", build_numpy), ("numexpr", "numexpr", build_numexpr), ("python", "lobe", build_module)]:
        try:
            m = __import__(module)
        except ImportError as e:
            skipped[name] = f"not installed ({e.name or module}; pip install {'./python' if module == 'lobe' else module})"
            continue
        if name == "drjit":
            m.set_thread_count(1)
        found.append(Peer(name, m, build))
    return found, skipped


class Formula:
    """One catalogue file: its simplification at the benchmark's parameter values, its points and their truth."""

    def __init__(self, binary, path, cols, n, tmp, csvs, live):
        self.path, self.n, self.meta = path, n, {}
        c = run_json([binary, "check", path, "--json", "--points", "1000"])
        defaults = [(p["name"], float(p["default"])) for p in c["params"]]
        # `lobe eval`'s and `lobe check`'s --set: every parameter baked at its default (none with --live).
        self.baked = {} if live else dict(defaults)
        self.set = ["--set", ",".join(f"{k}={v!r}" for k, v in defaults)] if self.baked else []
        if self.set:
            c = run_json([binary, "check", path, *self.set, "--json", "--points", "1000"])
        self.name = c["name"]
        self.inputs = [i for i in COSINES if i in c["used_inputs"]]
        if len(self.inputs) != len(c["used_inputs"]):
            raise NotImplementedError(f"inputs {c['used_inputs']} (the benchmark gives cosines only)")
        live_params = [(k, v) for k, v in defaults if live]
        self.param_names, self.param_values = [k for k, _ in live_params], [v for _, v in live_params]
        self.prog = program(c["simplified"])
        self.cols = {i: cols[i] for i in self.inputs}
        key = tuple(self.inputs)
        if key not in csvs:
            csvs[key] = os.path.join(tmp, "_".join(key) + ".csv")
            np.savetxt(csvs[key], np.column_stack([cols[i] for i in key]), fmt="%.17g", delimiter=",", header=",".join(key), comments="")
        self.csv = csvs[key]
        self.truth = values(run_json([binary, "eval", path, *self.set, "--points", self.csv, "--truth", "--json"]))


def host(binary):
    cpu = next((l.split(":", 1)[1].strip() for l in open("/proc/cpuinfo") if l.startswith("model name")), platform.processor()) if os.path.exists("/proc/cpuinfo") else platform.processor()
    flags = next((l.split(":", 1)[1].split() for l in open("/proc/cpuinfo") if l.startswith("flags")), []) if os.path.exists("/proc/cpuinfo") else []
    simd = "avx512f" if "avx512f" in flags else "avx2" if "avx2" in flags else "sse2"
    llvm = subprocess.run(["ldd", binary], capture_output=True, text=True).stdout if shutil.which("ldd") else ""
    llvm = next((l.split()[0] for l in llvm.splitlines() if "libLLVM" in l), None)
    return {"cpu": cpu, "simd": simd, "cores": os.cpu_count(), "lobe_llvm": llvm, "python": platform.python_version()}


def dr_llvm():
    """The libLLVM Dr.Jit loaded (from this process's mappings), when it did."""
    try:
        return next((l.split()[-1] for l in open("/proc/self/maps") if "libLLVM" in l), None)
    except OSError:
        return None


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--points", type=int, default=1 << 20)
    ap.add_argument("--rounds", type=int, default=5, help="interleaved rounds (the table shows the minimum)")
    ap.add_argument("--formulas", nargs="*", default=sorted(glob.glob(os.path.join(ROOT, "examples", "brdfs", "*.brdf"))))
    ap.add_argument("--json", action="store_true", help="print one JSON object instead of the tables")
    ap.add_argument("--live", action="store_true", help="parameters as run-time values instead of baked constants")
    a = ap.parse_args()
    binary = lobe_bin()
    if binary is None:
        sys.exit("error: no lobe binary: cargo build --release --features llvm (or set LOBE_BIN)")
    found, skipped = peers()
    systems = [Lobe(binary, "cranelift")]
    try:
        run_json([binary, "eval", "--expr", "NH", "--at", "NH=0.5", "--json", "--tier", "llvm"])
        systems.append(Lobe(binary, "llvm"))
        systems.append(Lobe(binary, "llvm", "llvm-speed", ["--prefer", "speed"]))
    except RuntimeError as e:
        skipped["llvm"] = f"this lobe has no LLVM tier (cargo build --release --features llvm): {str(e)[-200:]}"
    systems += found
    rng = np.random.default_rng(0x1095)
    cols = {c: rng.uniform(0.0, 1.0, a.points) for c in COSINES}
    tmp = tempfile.mkdtemp(prefix="lobe-peers-")
    csvs, forms = {}, []
    for path in a.formulas:
        try:
            forms.append(Formula(binary, path, cols, a.points, tmp, csvs, a.live))
        except (NotImplementedError, SyntaxError) as e:
            print(f"note: {os.path.basename(path)} skipped: no translation of `{e}`", file=sys.stderr)
    # Prepare every system on every formula (compiles, first values, errors), then the timed rounds.
    rows = {}
    timers = {}
    for f in forms:
        row = rows[f.path] = {"file": os.path.relpath(f.path, ROOT), "name": f.name, "systems": {}}
        for s in systems:
            try:
                got, timer = s.prepare(f)
            except (NotImplementedError, SyntaxError, RuntimeError, TypeError, ValueError) as e:
                row["systems"][s.name] = {"error": f"{type(e).__name__}: {str(e)[-300:]}"}
                continue
            row["systems"][s.name] = dict(error(got, f.truth), **f.meta.get(s.name, {}), ns_rounds=[], wall_ns_rounds=[])
            timers[(f.path, s.name)] = timer
    for r in range(a.rounds):
        order = systems[r % len(systems):] + systems[: r % len(systems)]
        for f in forms:
            for s in order:
                if (f.path, s.name) in timers:
                    cpu, wall = timers[(f.path, s.name)]()
                    rows[f.path]["systems"][s.name]["ns_rounds"].append(cpu)
                    rows[f.path]["systems"][s.name]["wall_ns_rounds"].append(wall)
        print(f"round {r + 1}/{a.rounds} done", file=sys.stderr)
    for row in rows.values():
        for s in row["systems"].values():
            ns = s.get("ns_rounds")
            if ns:
                s["ns_min"], s["ns_median"], s["spread"] = min(ns), statistics.median(ns), max(ns) / min(ns) - 1
                s["wall_ns_min"] = min(s["wall_ns_rounds"])
        sy = row["systems"]
        if "ns_min" in sy.get("llvm", {}) and "ns_min" in sy.get("drjit", {}):
            row["llvm_over_drjit"] = sy["llvm"]["ns_min"] / sy["drjit"]["ns_min"]
    lanes = next((s.get("lanes") for row in rows.values() for n, s in row["systems"].items() if n == "llvm"), None)
    versions = {p.name: getattr(p.module, "__version__", "?") for p in found}
    out = {
        "date": time.strftime("%Y-%m-%d"),
        "host": dict(host(binary), llvm_lanes=lanes, drjit_llvm=dr_llvm() if "drjit" in versions else None),
        "points": a.points,
        "rounds": a.rounds,
        "clock": "thread CPU time",
        "parameters": "live" if a.live else "baked",
        "versions": versions,
        "skipped": skipped,
        "rows": list(rows.values()),
    }
    if a.json:
        print(json.dumps(out, indent=1))
        return
    print(table(out, [s.name for s in systems]))


def table(out, names):
    """The two markdown tables: ns/element (and LLVM/Dr.Jit), then bits of error."""
    h = out["host"]
    lines = [
        f"{out['date']}: {out['points']} points, parameters {out['parameters']}, min of {out['rounds']} interleaved rounds ({out['clock']}, 1 thread); {h['cpu']} ({h['simd']}, {h['cores']} cores), lobe's LLVM tier {h['llvm_lanes']} lanes ({h['lobe_llvm']}), Dr.Jit's LLVM {h['drjit_llvm']}",
        "versions: " + ", ".join(f"{k} {v}" for k, v in out["versions"].items()),
        "skipped: " + ("; ".join(f"{k}: {v}" for k, v in out["skipped"].items()) or "none"),
        "",
        "ns/element, min over rounds (spread: max/min − 1)",
        "",
        "| formula | " + " | ".join(names) + (" | llvm/drjit |" if "llvm" in names and "drjit" in names else " |"),
        "|---|" + "---:|" * (len(names) + ("llvm" in names and "drjit" in names)),
    ]
    for row in out["rows"]:
        cells = []
        for n in names:
            s = row["systems"].get(n, {})
            cells.append(f"{s['ns_min']:.2f} ({100 * s['spread']:.0f} %)" if "ns_min" in s else "—")
        if "llvm" in names and "drjit" in names:
            cells.append(f"**{row['llvm_over_drjit']:.2f}**" if "llvm_over_drjit" in row else "—")
        lines.append(f"| {row['name']} | " + " | ".join(cells) + " |")
    lines += ["", "max bits of error against lobe's truth (log2(ulps + 1), where the truth is finite), (points beyond 4 bits), +k: k non-finite values there", ""]
    lines += ["| formula | " + " | ".join(names) + " |", "|---|" + "---:|" * len(names)]
    for row in out["rows"]:
        cells = []
        for n in names:
            s = row["systems"].get(n, {})
            cells.append((f"{s['max_bits']:.2f} ({s['over_4_bits']})" + (f" +{s['nonfinite']}" if s["nonfinite"] else "")) if "max_bits" in s else "—")
        lines.append(f"| {row['name']} | " + " | ".join(cells) + " |")
    lines += ["", "compile ms (lobe: compile_us; numba: first call; Dr.Jit: first call less a warm one)", ""]
    lines += ["| formula | " + " | ".join(names) + " |", "|---|" + "---:|" * len(names)]
    for row in out["rows"]:
        cells = [f"{row['systems'].get(n, {}).get('compile_ms', float('nan')):.1f}" for n in names]
        lines.append(f"| {row['name']} | " + " | ".join(cells) + " |")
    errors = [f"{row['name']} / {n}: {s['error']}" for row in out["rows"] for n, s in row["systems"].items() if "error" in s]
    if errors:
        lines += ["", "failed: " + "; ".join(errors)]
    return "\n".join(lines)


if __name__ == "__main__":
    main()
