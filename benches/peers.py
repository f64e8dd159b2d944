#!/usr/bin/env python3
"""lobe's JIT tiers against Dr.Jit, numba, numpy and numexpr on the catalogue: time ratios and bits of error.

    python3 -m venv .venv && .venv/bin/pip install drjit==1.5.0 numba numpy numexpr    # the peers (any subset)
    cargo build --release --features llvm                                              # lobe with both tiers
    .venv/bin/python benches/peers.py [--points 1048576] [--rounds 5] [--json] [--formulas a.brdf …]
    .venv/bin/python benches/peers.py --self-test       # the statistics, the verdicts and the translator
    HOME=$(mktemp -d) .venv/bin/python benches/peers.py --rounds 7 --json > peers.json  # BENCHMARKS.md §15's run
    .venv/bin/python benches/peers.py --table peers.json                                 # (cold Dr.Jit cache), its tables

The output starts with the date, the host, the versions and the machine's load (`uptime`) at the start and the end.

What runs. Every system evaluates the same formula on the same float64 points (the cosines uniform in [0, 1], one
seed), on one thread, at the formula's declared parameter values, baked as constants everywhere (with --live
they are run-time values: lobe's live parameters, Dr.Jit's opaque scalars, numba's and numpy's arguments).
- lobe, three modes of the command line's batched kernel, `lobe eval FILE --set P=V,… --points CSV --json`:
  `cranelift` (`--tier cranelift`, the default build's tier), `llvm` (`--tier llvm`, precise: the accuracy
  pass's kernel, what every command compiles) and `llvm-speed` (`--tier llvm --prefer speed`: the plain
  simplification, no accuracy-pass rewrite, lobe's precise math library).
- the peers, each on two texts of the formula, both in the tables:
  "as written" (`written`): the .brdf file's own `let` lines and final expression, as a researcher writes them
  (`^` as the dialect's power operator, parameters replaced by their values), plus lobe's domain policy where it
  changes a value: the result is clamped at 0 (`max(…, 0)`) on the rows whose written formula is negative at
  some benchmark point (the inputs are already in [0, 1], so the input clamps change nothing);
  "lobe's text" (`lobe`): lobe's plain simplification at the same values (`lobe check --set … --json`, its
  `simplified`: integer powers as multiplication chains, constants folded, domain clamps kept).
  Each text is translated to numpy (whole-array operations), numexpr, numba (an `@njit(error_model="numpy",
  fastmath=False)` loop into a preallocated output) and Dr.Jit (its LLVM backend, `drjit.set_thread_count(1)`:
  the kernel runs on the calling thread). A text the translator cannot write in a dialect is reported with the
  reason, never dropped silently.
- lobe's own Python module when it is installed (`pip install ./python`; its automatic tier: LLVM at this size
  when built with `--features llvm`, else Cranelift), `RAYON_NUM_THREADS=1`: shown, not in the verdicts.
A peer that is not installed is skipped and named.

The timing rule, the same for every system: KERNEL TIME, the steady-state time to evaluate the formula over
arrays already in the system's own format into its output, without per-call work a system does again on every
call only because it is called from Python. lobe: `eval_cpu_ns_per_point`, the command's steady state of the
batched kernel (no CSV, no process); Dr.Jit: `dr.eval(y); dr.sync_thread()` after tracing `y` untimed (the
kernel is found in Dr.Jit's cache and run: a hash look-up and a launch, as lobe's call is a dispatch); numba:
the whole call (its dispatch is ~µs against ms of loop); numpy and numexpr: the whole call (there is no kernel
apart from the call). Dr.Jit's whole call (tracing included) is measured in the same passes and shown beside it;
Dr.Jit's own `kernel_history()` execution time of one call is in the JSON as a cross-check. When lobe's Python
module is installed, the other rule is shown too: the whole call from Python, the module's `k(out=…, **inputs)`
(its automatic tier) against Dr.Jit's whole call.
Clock: this thread's CPU time (the machine may be shared); the whole-call comparison with lobe's module uses the
process's CPU time, as the module's kernel runs on a worker thread. A sample is the median of passes repeated for ≥ 3
passes and ≥ 20 ms after a warm-up call (which compiles); lobe's command does the same inside.

Statistic: the systems take turns within every round, the order rotating (≥ 5 rounds). For a lobe mode M and a
peer P (one system on one text) the per-round ratio is M's time / P's time within the same round; a row shows the
MEDIAN of the per-round ratios and their spread, min–max.

Errors: bits (log2(ulps + 1)) against the truth, `lobe eval --truth` (the formula as written in ~104-bit
precision, domain policy included), over the points where the truth is finite (no conditioning filter): the max
and the mean, and the count of NaN/±inf values there.

Verdict per row and peer (Pareto): "lobe wins" when some lobe mode is at least as accurate (max bits ≤ the
peer's and non-finite count ≤ the peer's) and its median per-round ratio is ≤ 1.0 without its spread
straddling 1.0; "tie" when, for such a mode, the spread straddles 1.0 (min < 1 < max); "peer wins" otherwise
(no lobe mode as accurate, or every accurate mode slower in every round). Summary counts of the verdicts, of the
rows where llvm (precise) is ≤ 1.2× Dr.Jit and of the rows where cranelift is ≤ 2.5× Dr.Jit (median ratio).

Compile times are printed per system with what each measures (they are unlike quantities, not ratios): lobe's
`compile_us` (parse, passes, the tier's JIT), numba's first call less a warm one (type inference, LLVM), Dr.Jit's
code generation and LLVM time of its first call's kernel from `kernel_history()` (marked when its kernel disk
cache had the kernel from an earlier run), numexpr's first call less a warm one.
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
MODES = ("cranelift", "llvm", "llvm-speed")
TEXTS = {"written": "as written", "lobe": "lobe's text"}
PEERS = ("drjit", "numba", "numpy", "numexpr")


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


def load():
    """`uptime`'s load averages (the machine may be shared)."""
    try:
        return subprocess.run(["uptime"], capture_output=True, text=True).stdout.strip()
    except OSError:
        return " ".join(f"{x:.2f}" for x in os.getloadavg())


def steady(f, n, split=None):
    """{"cpu", "wall"} ns/element of `f` (which does `n` elements) in this thread's CPU time and wall time: a
    warm-up call, then the median of passes repeated for ≥ 3 passes and ≥ 20 ms (or 1 s), as `lobe eval
    --points --json` times its kernel. With `split` (Dr.Jit), `f()` is untimed preparation (the trace) and
    `split(f())` the timed part; "whole_cpu" times both, and "whole_proc" both in the process's CPU time (all its
    threads: lobe's Python module runs its kernel on a worker thread)."""
    split(f()) if split else f()
    start, ns, wall, whole, proc = time.perf_counter(), [], [], [], []
    while len(ns) < 3 or (time.perf_counter() - start < 0.02 and len(ns) < 1000):
        p0, t0 = time.process_time_ns(), time.thread_time_ns()
        if split:
            y = f()
            t, w = time.thread_time_ns(), time.perf_counter_ns()
            split(y)
        else:
            t, w = t0, time.perf_counter_ns()
            f()
        end = time.thread_time_ns()
        proc.append(time.process_time_ns() - p0)
        ns.append(end - t)
        wall.append(time.perf_counter_ns() - w)
        whole.append(end - t0)
        if time.perf_counter() - start > 1:
            break
    return {"cpu": statistics.median(ns) / n, "wall": statistics.median(wall) / n, "whole_cpu": statistics.median(whole) / n, "whole_proc": statistics.median(proc) / n}


# -- a formula's text → [(name, expr AST)] → each dialect -----------------------------------------------------
def written_text(source):
    """The formula of a .brdf file as written: its `let` lines, then its final expression, one statement a line
    (comments, `@` directives and `param` lines left out; a statement continued on the next line joined).
    Raises NotImplementedError for what the translator does not write (fn helpers, selects, vectors)."""
    stmts = []
    for raw in source.splitlines():
        line = raw.split("#", 1)[0].strip()
        if not line or line.startswith("@") or line.startswith("param "):
            continue
        if line.startswith("fn "):
            raise NotImplementedError(f"a `fn` helper ({line}): the translator inlines no functions")
        if line.startswith("let ") or not stmts or stmts[-1].count("(") == stmts[-1].count(")") and not stmts[-1].rstrip().endswith(("+", "-", "*", "/", "^", ",")):
            stmts.append(line)
        else:
            stmts[-1] += " " + line
    for s in stmts:
        for token, why in (("?", "a select `c ? a : b`"), ("if ", "a select `if c then a else b`"), ("&&", "a boolean `&&`"), ("||", "a boolean `||`"), ("dot(", "a vector function"), ("norm(", "a vector function"), ("vec", "a vector")):
            if token in s:
                raise NotImplementedError(f"{why} in `{s}`: the translator writes scalar arithmetic only")
    if not stmts or stmts[-1].startswith("let "):
        raise NotImplementedError("no final expression")
    return "\n".join(stmts)


def program(text):
    """[(name, expr AST)] for the `let` lines, then ("", root); `^` is Python's `**` (right-associative, binding
    tighter than unary minus, as in lobe's language)."""
    lines = [l.strip() for l in text.replace("^", "**").splitlines() if l.strip()]
    out = []
    for l in lines[:-1]:
        if not l.startswith("let "):
            raise NotImplementedError(l)
        name, e = l[4:].split("=", 1)
        out.append((name.strip(), ast.parse(e.strip(), mode="eval").body))
    out.append(("", ast.parse(lines[-1], mode="eval").body))
    return out


def clamped(prog):
    """The program with its result clamped at 0 (lobe's domain policy)."""
    return prog[:-1] + [("", ast.parse(f"max({ast.unparse(prog[-1][1])}, 0)", mode="eval").body)]


class Dialect(ast.NodeTransformer):
    """Rewrites calls and names: `calls` maps a lobe builtin to a function of the argument sources."""

    def __init__(self, calls, names):
        self.calls, self.names = calls, names

    def visit_Call(self, node):
        f = node.func.id
        args = [ast.unparse(self.visit(a)) for a in node.args]
        if f not in self.calls:
            raise NotImplementedError(f"the builtin `{f}` has no entry in this dialect")
        return ast.parse(self.calls[f](*args), mode="eval").body

    def visit_Name(self, node):
        return ast.parse(self.names.get(node.id, node.id), mode="eval").body


# sinnear is lobe's sin on an argument range analysis bounds (its simplifier's coding): the peers' sin.
FUNCS = ["exp", "sqrt", "sin", "sinnear", "cos", "tan", "abs", "log", "ln", "acos", "asin", "atan"]


def dialect(clamp, minimum, maximum, power, fma, prefix, **rename):
    """A dialect's calls: format strings of the forms that differ, then `prefix + name(x)` for the one-argument
    functions (`rename`: a lobe builtin's name in the dialect, where it differs)."""
    rename = {"sinnear": "sin", **rename}
    forms = {"clamp": clamp, "min": minimum, "max": maximum, "pow": power, "fma": fma}
    out = {f: (lambda t: lambda *a: t.format(*a))(t) for f, t in forms.items()}
    out.update({f: (lambda g: lambda x: f"{prefix}{g}({x})")(rename.get(f, f)) for f in FUNCS})
    return out


# fma: numpy, numexpr and numba have none on arrays/scalars here; written as a * b + c (two roundings), which
# only the as-written text could use (no catalogue formula does).
NP_CALLS = dialect("np.clip({0}, {1}, {2})", "np.minimum({0}, {1})", "np.maximum({0}, {1})", "np.power({0}, {1})", "(({0}) * ({1}) + ({2}))", "np.", ln="log", acos="arccos", asin="arcsin", atan="arctan")
NE_CALLS = dialect(
    "where(({0}) < ({1}), {1}, where(({0}) > ({2}), {2}, {0}))",
    "where(({0}) < ({1}), {0}, {1})",
    "where(({0}) > ({1}), {0}, {1})",
    "({0}) ** ({1})",
    "(({0}) * ({1}) + ({2}))",
    "",
    ln="log",
    acos="arccos",
    asin="arcsin",
    atan="arctan",
)
NB_CALLS = dialect("min(max({0}, {1}), {2})", "min({0}, {1})", "max({0}, {1})", "math.pow({0}, {1})", "(({0}) * ({1}) + ({2}))", "math.", ln="log", abs="fabs")
DR_CALLS = dialect("dr.clip({0}, {1}, {2})", "dr.minimum({0}, {1})", "dr.maximum({0}, {1})", "dr.power({0}, {1})", "dr.fma({0}, {1}, {2})", "dr.", ln="log")


def translate(prog, calls, names):
    d = Dialect(calls, names)
    return [(n, ast.unparse(d.visit(copy.deepcopy(e)))) for n, e in prog]


def function(prog, args, calls, names, ns):
    """`def f(*args)`: the lets, then `return root`, in the dialect."""
    steps = translate(prog, calls, names)
    body = "".join(f"    {n} = {e}\n" for n, e in steps[:-1])
    exec(f"def f({', '.join(args)}):\n{body}    return {steps[-1][1]}\n", ns)
    return ns["f"]


def numba_loop(prog, inputs, params, numba, names):
    """An `@njit` loop over the points into `out` (one thread, no fastmath, numpy's error model: no zero test per
    division)."""
    import math

    steps = translate(prog, NB_CALLS, dict(names, pi="math.pi"))
    load_ = "".join(f"        {c} = {c}_[i]\n" for c in inputs)
    body = "".join(f"        {n} = {e}\n" for n, e in steps[:-1])
    src = f"def f({', '.join([c + '_' for c in inputs] + ['out'] + params)}):\n    for i in range(out.shape[0]):\n{load_}{body}        out[i] = {steps[-1][1]}\n"
    ns = {"math": math}
    exec(src, ns)
    return numba.njit(ns["f"], fastmath=False, parallel=False, nogil=True, error_model="numpy")


def numexpr_fn(prog, ne, env, names):
    steps = translate(prog, NE_CALLS, dict(names, pi="pi_"))

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


# -- the statistics and the verdicts --------------------------------------------------------------------------
def ratios(mine, theirs):
    """Per-round ratios mine[r] / theirs[r] (the same rounds), and their median, min and max."""
    if len(mine) != len(theirs) or not mine:
        raise ValueError(f"{len(mine)} rounds against {len(theirs)}")
    r = [a / b for a, b in zip(mine, theirs)]
    return {"ratios": r, "median": statistics.median(r), "min": min(r), "max": max(r)}


def straddles(stat):
    return stat["min"] < 1.0 < stat["max"]


def as_accurate(mode, peer):
    """A lobe mode's errors at least as good as a peer's: max bits and non-finite count."""
    return mode["max_bits"] <= peer["max_bits"] and mode["nonfinite"] <= peer["nonfinite"]


def verdict(modes, peer):
    """The Pareto verdict of lobe against one peer on one row: `modes` {name: (errors, ratio stat)}, `peer` its
    errors. Returns (verdict, the mode that decides it or None, why)."""
    accurate = {m: s for m, (e, s) in modes.items() if as_accurate(e, peer)}
    if not accurate:
        return "peer wins", None, "no lobe mode as accurate"
    wins = {m: s for m, s in accurate.items() if s["median"] <= 1.0 and not straddles(s)}
    if wins:
        m = min(wins, key=lambda k: wins[k]["median"])
        return "lobe wins", m, f"{m} {fmt_ratio(wins[m])}"
    ties = {m: s for m, s in accurate.items() if straddles(s)}
    if ties:
        m = min(ties, key=lambda k: ties[k]["median"])
        return "tie", m, f"{m} {fmt_ratio(ties[m])}"
    m = min(accurate, key=lambda k: accurate[k]["median"])
    return "peer wins", m, f"fastest as accurate: {m} {fmt_ratio(accurate[m])}"


def fmt_ratio(s):
    return f"{s['median']:.2f} [{s['min']:.2f}–{s['max']:.2f}]"


def within(stats, bound):
    """The rows (of {row: ratio stat}) whose median ratio is ≤ bound."""
    return [r for r, s in stats.items() if s["median"] <= bound]


def criterion(stats, bound):
    """{"rows": held, "of": n, "held": {row: "median [min–max]"}, "not": {…}} for a median ratio ≤ bound."""
    held = within(stats, bound)
    return {"rows": held, "of": len(stats), "held": {r: fmt_ratio(stats[r]) for r in held}, "not": {r: fmt_ratio(s) for r, s in stats.items() if r not in held}}


# -- the systems ----------------------------------------------------------------------------------------------
class Lobe:
    """One mode of the command line's batched kernel: a subprocess per sample (it reads the CSV each time)."""

    def __init__(self, binary, tier, name=None, extra=()):
        self.binary, self.tier, self.name, self.extra = binary, tier, name or tier, list(extra)
        self.key, self.text = self.name, None

    def prepare(self, f):
        args = [self.binary, "eval", f.path, *f.set, "--points", f.csv, "--json", "--tier", self.tier, *self.extra]
        r = run_json(args)
        meta = {"compile_ms": r["compile_us"] / 1e3, "lanes": r.get("lanes"), "backend": r.get("backend")}

        def sample():
            r = run_json(args)
            return {"cpu": r["eval_cpu_ns_per_point"], "wall": r["eval_ns_per_point"], "whole_cpu": r["eval_cpu_ns_per_point"], "whole_proc": r["eval_cpu_ns_per_point"]}

        return values(r), sample, meta


class Peer:
    """A Python system on one text: `build(module, f, prog, names)` returns (call, result → float64 array,
    split or None)."""

    def __init__(self, name, module, build, text):
        self.name, self.module, self.build, self.text = name, module, build, text
        self.key = f"{name}/{text}" if text else name

    def prepare(self, f):
        prog, names = f.progs[self.text] if self.text else (None, None)
        if prog is None and self.text:
            raise NotImplementedError(f.untranslated[self.text])
        dr = self.module if self.name == "drjit" else None
        if dr:
            dr.set_flag(dr.JitFlag.KernelHistory, True)
            dr.kernel_history()
        t = time.perf_counter()
        call, result, split = self.build(self.module, f, prog, names)
        one = (lambda: split(call())) if split else call
        first = result(one())
        compile_s = time.perf_counter() - t
        meta = {}
        if dr:
            # Dr.Jit's own account of its first call: code generation and LLVM, and whether its disk cache had it.
            h = [k for k in dr.kernel_history() if k.get("type") == dr.KernelType.JIT]
            dr.set_flag(dr.JitFlag.KernelHistory, False)
            meta["jit_ms"] = sum(k["codegen_time"] + k["backend_time"] for k in h)
            meta["disk_cache_hit"] = any(k["cache_disk"] for k in h)
        t = time.perf_counter()
        one()
        meta["compile_ms"] = (compile_s - (time.perf_counter() - t)) * 1e3
        if dr:
            meta.update(drjit_history(dr, call, split, f.n))
        if self.name == "python":
            # The module's kernel runs on a worker thread: the process's CPU time is its time.
            return first, (lambda: (lambda r: dict(r, cpu=r["whole_proc"]))(steady(call, f.n))), meta
        return first, (lambda: steady(call, f.n, split)), meta


def args_of(f):
    return f.inputs + f.param_names


def build_numpy(np_, f, prog, names):
    g = function(prog, args_of(f), NP_CALLS, dict(names, pi="np.pi"), {"np": np_})
    args = [f.cols[c] for c in f.inputs] + f.param_values

    def call():
        with np_.errstate(all="ignore"):
            return g(*args)

    return call, (lambda r: np.broadcast_to(np.asarray(r, dtype=np.float64), (f.n,)).copy()), None


def build_numba(numba, f, prog, names):
    g = numba_loop(prog, f.inputs, f.param_names, numba, names)
    out = np.empty(f.n)
    args = [f.cols[c] for c in f.inputs] + [out] + f.param_values
    return (lambda: g(*args)), (lambda _: out.copy()), None


def build_numexpr(ne, f, prog, names):
    call = numexpr_fn(prog, ne, dict({c: f.cols[c] for c in f.inputs}, **dict(zip(f.param_names, f.param_values))), names)
    return call, (lambda r: np.broadcast_to(np.asarray(r, dtype=np.float64), (f.n,)).copy()), None


def build_drjit(dr, f, prog, names):
    g = function(prog, args_of(f), DR_CALLS, dict(names, pi="dr.pi"), {"dr": dr})
    from drjit.llvm import Float64

    cols = drjit_columns(dr, f)
    # A live parameter is an opaque scalar: a run-time value of the kernel, not a literal Dr.Jit folds.
    args = [cols[c] for c in f.inputs] + [dr.opaque(Float64, v) for v in f.param_values]

    def trace():
        y = g(*args)
        return y if isinstance(y, Float64) else Float64(y) + dr.zeros(Float64, f.n)

    def run(y):
        dr.eval(y)
        dr.sync_thread()
        return y

    return trace, (lambda y: np.broadcast_to(np.asarray(y, dtype=np.float64), (f.n,)).copy()), run


def drjit_history(dr, trace, run, n):
    """Dr.Jit's own record of one warm call: its kernels' execution time (wall), ns/element."""
    try:
        dr.set_flag(dr.JitFlag.KernelHistory, True)
        dr.kernel_history()
        run(trace())
        h = [k for k in dr.kernel_history() if k.get("type") == dr.KernelType.JIT]
        dr.set_flag(dr.JitFlag.KernelHistory, False)
        return {"kernel_history_ns": sum(k["execution_time"] for k in h) * 1e6 / n, "kernels": len(h)}
    except Exception as e:  # noqa: BLE001 — a cross-check only
        return {"kernel_history_error": str(e)[:200]}


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


def build_module(lobe, f, _prog, _names):
    k = lobe.compile(f.path, **f.baked)
    inputs = {c: f.cols[c] for c in k.inputs}
    out = np.empty(f.n)
    return (lambda: k(out=out, **inputs)), (lambda _: out.copy()), None


def peers(texts):
    """(the peers found, one per text, {skipped: why})."""
    found, skipped = [], {}
    for name, module, build in [("drjit", "drjit", build_drjit), ("numba", "numba", build_numba), ("numpy", "numpy", build_numpy), ("numexpr", "numexpr", build_numexpr), ("python", "lobe", build_module)]:
        try:
            m = __import__(module)
        except ImportError as e:
            skipped[name] = f"not installed ({e.name or module}; pip install {'./python' if module == 'lobe' else module})"
            continue
        if name == "drjit":
            m.set_thread_count(1)
        found += [Peer(name, m, build, t) for t in texts] if name != "python" else [Peer(name, m, build, None)]
    return found, skipped


class Formula:
    """One catalogue file: its two texts at the benchmark's parameter values, its points and their truth."""

    def __init__(self, binary, path, cols, n, tmp, csvs, live, truth=True):
        self.path, self.n = path, n
        c = run_json([binary, "check", path, "--json", "--points", "1000"])
        defaults = [(p["name"], float(p["default"])) for p in c["params"]]
        # `lobe eval`'s and `lobe check`'s --set: every parameter baked at its default (none with --live).
        self.baked = {} if live else dict(defaults)
        self.set = ["--set", ",".join(f"{k}={v!r}" for k, v in defaults)] if self.baked else []
        if self.set:
            c = run_json([binary, "check", path, *self.set, "--json", "--points", "1000"])
        self.name = c["name"]
        self.inputs = [i for i in COSINES if i in c["used_inputs"]]
        live_params = [(k, v) for k, v in defaults if live]
        self.param_names, self.param_values = [k for k, _ in live_params], [v for _, v in live_params]
        self.cols = {i: cols[i] for i in COSINES}
        self.progs, self.untranslated, self.clamped = {}, {}, False
        # lobe's text reads only `used_inputs`; the written one may read more (an input the simplifier dropped).
        try:
            self.progs["lobe"] = (program(c["simplified"]), {})
        except (NotImplementedError, SyntaxError) as e:
            self.progs["lobe"], self.untranslated["lobe"] = (None, None), f"lobe's text: {e}"
        try:
            wprog = program(written_text(open(path, encoding="utf-8").read()))
            names = {k: repr(v) for k, v in self.baked.items()}
            read = {x.id for _, e in wprog for x in ast.walk(e) if isinstance(x, ast.Name)}
            unknown = read - set(COSINES) - set(names) - set(self.param_names) - {n for n, _ in wprog} - {"pi"}
            if unknown - set(NP_CALLS):
                raise NotImplementedError(f"names the benchmark does not give: {sorted(unknown)}")
            self.written_inputs = [i for i in COSINES if i in read]
            self.progs["written"] = (wprog, names)
        except (NotImplementedError, SyntaxError) as e:
            self.progs["written"], self.untranslated["written"] = (None, None), f"as written: {e}"
        self.inputs = sorted(set(self.inputs) | set(getattr(self, "written_inputs", [])), key=COSINES.index)
        if self.progs["written"][0] is not None:
            # lobe's domain policy, where the written formula goes negative on these points.
            g = function(self.progs["written"][0], args_of(self), NP_CALLS, dict(self.progs["written"][1], pi="np.pi"), {"np": np})
            with np.errstate(all="ignore"):
                v = np.asarray(g(*[cols[i] for i in self.inputs], *self.param_values))
            if (v < 0).any():
                self.clamped = True
                self.progs["written"] = (clamped(self.progs["written"][0]), self.progs["written"][1])
        key = tuple(self.inputs)
        if key not in csvs:
            csvs[key] = os.path.join(tmp, "_".join(key) + ".csv")
            np.savetxt(csvs[key], np.column_stack([cols[i] for i in key]), fmt="%.17g", delimiter=",", header=",".join(key), comments="")
        self.csv = csvs[key]
        if truth:
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


def summarize(rows, lobe_modes, peer_keys):
    """Per row: the ratio statistics of every lobe mode against every peer, the verdicts; then the counts."""
    counts = {p: {"lobe wins": 0, "tie": 0, "peer wins": 0} for p in peer_keys}
    llvm12 = {t: {} for t in TEXTS}
    cl25 = {t: {} for t in TEXTS}
    for row in rows:
        sy = row["systems"]
        row["ratios"], row["verdicts"] = {}, {}
        for p in peer_keys:
            if "ns_rounds" not in sy.get(p, {}):
                continue
            modes = {}
            for m in lobe_modes:
                if "ns_rounds" in sy.get(m, {}):
                    s = ratios(sy[m]["ns_rounds"], sy[p]["ns_rounds"])
                    row["ratios"][f"{m} / {p}"] = s
                    modes[m] = (sy[m], s)
            if modes:
                v, m, why = verdict(modes, sy[p])
                row["verdicts"][p] = {"verdict": v, "mode": m, "why": why}
                counts[p][v] += 1
        row["whole_ratios"] = {}
        for t in TEXTS:
            if sy.get("python", {}).get("whole_proc_ns_rounds") and sy.get(f"drjit/{t}", {}).get("whole_proc_ns_rounds"):
                row["whole_ratios"][f"python / drjit/{t}"] = ratios(sy["python"]["whole_proc_ns_rounds"], sy[f"drjit/{t}"]["whole_proc_ns_rounds"])
            if f"llvm / drjit/{t}" in row["ratios"]:
                llvm12[t][row["name"]] = row["ratios"][f"llvm / drjit/{t}"]
            if f"cranelift / drjit/{t}" in row["ratios"]:
                cl25[t][row["name"]] = row["ratios"][f"cranelift / drjit/{t}"]
    return {
        "verdicts": counts,
        "llvm_within_1.2x_drjit": {t: criterion(s, 1.2) for t, s in llvm12.items() if s},
        "cranelift_within_2.5x_drjit": {t: criterion(s, 2.5) for t, s in cl25.items() if s},
    }


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--points", type=int, default=1 << 20)
    ap.add_argument("--rounds", type=int, default=5, help="interleaved rounds (≥ 5 for the verdicts)")
    ap.add_argument("--formulas", nargs="*", default=sorted(glob.glob(os.path.join(ROOT, "examples", "brdfs", "*.brdf"))))
    ap.add_argument("--texts", default="written,lobe", help="the peers' texts: written, lobe or both")
    ap.add_argument("--json", action="store_true", help="print one JSON object instead of the tables")
    ap.add_argument("--live", action="store_true", help="parameters as run-time values instead of baked constants")
    ap.add_argument("--table", metavar="JSON", help="print the tables of a saved --json output instead of measuring")
    ap.add_argument("--self-test", action="store_true", help="check the statistics, the verdicts and the translator; exit non-zero on failure")
    a = ap.parse_args()
    if a.self_test:
        sys.exit(self_test())
    if a.table:
        with open(a.table, encoding="utf-8") as fh:
            print(table(json.load(fh)))
        return
    binary = lobe_bin()
    if binary is None:
        sys.exit("error: no lobe binary: cargo build --release --features llvm (or set LOBE_BIN)")
    texts = [t for t in a.texts.split(",") if t]
    if set(texts) - set(TEXTS):
        sys.exit(f"error: --texts takes {', '.join(TEXTS)}")
    load_start = load()
    found, skipped = peers(texts)
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
    csvs, forms, notes = {}, [], []
    for path in a.formulas:
        try:
            forms.append(Formula(binary, path, cols, a.points, tmp, csvs, a.live))
        except (NotImplementedError, SyntaxError, RuntimeError) as e:
            notes.append(f"{os.path.basename(path)}: not run: {e}")
    # Prepare every system on every formula (compiles, first values, errors), then the timed rounds.
    rows, timers = {}, {}
    for f in forms:
        row = rows[f.path] = {"file": os.path.relpath(f.path, ROOT), "name": f.name, "clamped_written": f.clamped, "untranslated": f.untranslated, "systems": {}}
        for s in systems:
            try:
                got, timer, meta = s.prepare(f)
            except (NotImplementedError, SyntaxError, RuntimeError, TypeError, ValueError, NameError, AttributeError) as e:
                row["systems"][s.key] = {"error": f"{type(e).__name__}: {str(e)[-300:]}"}
                continue
            row["systems"][s.key] = dict(error(got, f.truth), **meta, ns_rounds=[], wall_ns_rounds=[], whole_ns_rounds=[], whole_proc_ns_rounds=[])
            timers[(f.path, s.key)] = timer
        print(f"prepared {row['name']}", file=sys.stderr)
    for r in range(a.rounds):
        order = systems[r % len(systems):] + systems[: r % len(systems)]
        for f in forms:
            for s in order:
                if (f.path, s.key) in timers:
                    t = timers[(f.path, s.key)]()
                    sy = rows[f.path]["systems"][s.key]
                    sy["ns_rounds"].append(t["cpu"])
                    sy["wall_ns_rounds"].append(t["wall"])
                    sy["whole_ns_rounds"].append(t["whole_cpu"])
                    sy["whole_proc_ns_rounds"].append(t["whole_proc"])
        print(f"round {r + 1}/{a.rounds} done", file=sys.stderr)
    for row in rows.values():
        for s in row["systems"].values():
            if s.get("ns_rounds"):
                s["ns_median"], s["whole_ns_median"] = statistics.median(s["ns_rounds"]), statistics.median(s["whole_ns_rounds"])
    lobe_modes = [m for m in MODES if any(s.key == m for s in systems)]
    peer_keys = [s.key for s in found if s.name in PEERS]
    summary = summarize(list(rows.values()), lobe_modes, peer_keys)
    lanes = next((s.get("lanes") for row in rows.values() for n, s in row["systems"].items() if n == "llvm"), None)
    versions = {p.name: getattr(p.module, "__version__", "?") for p in found}
    out = {
        "date": time.strftime("%Y-%m-%d"),
        "command": " ".join(["benches/peers.py", *sys.argv[1:]]),
        "host": dict(host(binary), llvm_lanes=lanes, drjit_llvm=dr_llvm() if "drjit" in versions else None),
        "load": {"start": load_start, "end": load()},
        "points": a.points,
        "rounds": a.rounds,
        "clock": "thread CPU time",
        "timing_rule": "kernel time (Dr.Jit: dr.eval + sync after an untimed trace; numba, numpy, numexpr: the whole call; lobe: eval_cpu_ns_per_point)",
        "parameters": "live" if a.live else "baked",
        "versions": versions,
        "skipped": skipped,
        "notes": notes,
        "systems": [s.key for s in systems],
        "lobe_modes": lobe_modes,
        "peer_keys": peer_keys,
        "summary": summary,
        "rows": list(rows.values()),
    }
    if a.json:
        print(json.dumps(out, indent=1))
        return
    print(table(out))


def label(key):
    if "/" in key:
        name, text = key.split("/")
        return f"{name} ({TEXTS[text]})"
    return key


def table(out):
    """The tables: ns/element; lobe against Dr.Jit; the verdicts; errors; compile times; the summary."""
    keys, lobe_modes, peer_keys = out["systems"], out["lobe_modes"], out["peer_keys"]
    h = out["host"]
    lines = [
        f"{out['date']}: `{out['command']}`: {out['points']} points, parameters {out['parameters']}, {out['rounds']} interleaved rounds, {out['clock']}, 1 thread; {h['cpu']} ({h['simd']}, {h['cores']} cores), lobe's LLVM tier {h['llvm_lanes']} lanes ({h['lobe_llvm']}), Dr.Jit's LLVM {h['drjit_llvm']}",
        f"load: at the start `{out['load']['start']}`; at the end `{out['load']['end']}`",
        "versions: " + ", ".join(f"{k} {v}" for k, v in out["versions"].items()),
        "skipped: " + ("; ".join(f"{k}: {v}" for k, v in out["skipped"].items()) or "none"),
        f"timing rule: {out['timing_rule']}",
    ]
    lines += [f"note: {n}" for n in out["notes"]]
    clamp = [row["name"] for row in out["rows"] if row["clamped_written"]]
    lines.append("as written, clamped at 0 (lobe's domain policy; the written formula is negative at some points): " + (", ".join(clamp) or "none"))
    untr = [f"{row['name']}: {w}" for row in out["rows"] for w in row["untranslated"].values()]
    lines.append("not translated: " + ("; ".join(untr) or "none (every row, both texts)"))
    lines += ["", "ns/element, median over rounds (kernel time)", ""]
    lines += ["| formula | " + " | ".join(label(k) for k in keys) + " |", "|---|" + "---:|" * len(keys)]
    for row in out["rows"]:
        cells = [f"{row['systems'].get(k, {})['ns_median']:.2f}" if "ns_median" in row["systems"].get(k, {}) else "—" for k in keys]
        lines.append(f"| {row['name']} | " + " | ".join(cells) + " |")
    dr = [k for k in peer_keys if k.startswith("drjit/")]
    if dr:
        lines += ["", "Dr.Jit's whole call from Python (tracing included) over its kernel time, median over rounds: " + "; ".join(
            f"{label(k)} " + ", ".join(f"{row['name']} {row['systems'][k]['whole_ns_median'] / row['systems'][k]['ns_median']:.2f}×" for row in out["rows"] if "ns_median" in row["systems"].get(k, {})) for k in dr
        )]
    whole = [f"python / drjit/{t}" for t in TEXTS if any(f"python / drjit/{t}" in row.get("whole_ratios", {}) for row in out["rows"])]
    if whole:
        lines += ["", "whole call from Python, the other rule: lobe's Python module (automatic tier) over Dr.Jit's whole call (tracing included), both in process CPU time, median of per-round ratios [min–max]", ""]
        lines += ["| formula | " + " | ".join(label(k.split(" / ")[1]).replace("drjit", "python / drjit") for k in whole) + " |", "|---|" + "---:|" * len(whole)]
        for row in out["rows"]:
            lines.append(f"| {row['name']} | " + " | ".join(fmt_ratio(row["whole_ratios"][k]) if k in row.get("whole_ratios", {}) else "—" for k in whole) + " |")
    against = [(m, p) for p in dr for m in lobe_modes]
    if against:
        lines += ["", "lobe / Dr.Jit: median of per-round ratios [min–max]", ""]
        lines += ["| formula | " + " | ".join(f"{m} / {label(p)}" for m, p in against) + " |", "|---|" + "---:|" * len(against)]
        for row in out["rows"]:
            cells = [fmt_ratio(row["ratios"][f"{m} / {p}"]) if f"{m} / {p}" in row["ratios"] else "—" for m, p in against]
            lines.append(f"| {row['name']} | " + " | ".join(cells) + " |")
    lines += ["", "Pareto verdict per peer (the deciding lobe mode, its median ratio [min–max])", ""]
    lines += ["| formula | " + " | ".join(label(p) for p in peer_keys) + " |", "|---|" + "---|" * len(peer_keys)]
    for row in out["rows"]:
        cells = []
        for p in peer_keys:
            v = row["verdicts"].get(p)
            cells.append(f"{v['verdict']}: {v['why']}" if v else "—")
        lines.append(f"| {row['name']} | " + " | ".join(cells) + " |")
    lines += ["", "bits of error against lobe's truth where the truth is finite: max / mean (+k: k NaN or ±inf values there)", ""]
    lines += ["| formula | " + " | ".join(label(k) for k in keys) + " |", "|---|" + "---:|" * len(keys)]
    for row in out["rows"]:
        cells = []
        for k in keys:
            s = row["systems"].get(k, {})
            cells.append((f"{s['max_bits']:.2f} / {s['avg_bits']:.2f}" + (f" +{s['nonfinite']}" if s["nonfinite"] else "")) if "max_bits" in s else "—")
        lines.append(f"| {row['name']} | " + " | ".join(cells) + " |")
    lines += [
        "",
        "compile ms, unlike quantities per column (not ratios): lobe's modes: `compile_us` (parse, passes, the tier's JIT); numba: first call less a warm one (type inference, LLVM); "
        "Dr.Jit: code generation + LLVM of its first call's kernel, from `kernel_history()` (\"disk\": a hit in Dr.Jit's kernel disk cache, from an earlier run; \"(cached)\": the same kernel as an earlier row's, a VR twin's); numexpr: first call less a warm one (parsing into its bytecode; ~0: no slower than a warm call); numpy compiles nothing; python (lobe's module): `lobe.compile` and a first call less a warm one (Cranelift, then LLVM at the first big array)",
        "",
    ]
    ckeys = [k for k in keys if not k.startswith("numpy")]
    lines += ["| formula | " + " | ".join(label(k) for k in ckeys) + " |", "|---|" + "---:|" * len(ckeys)]
    for row in out["rows"]:
        cells = []
        for k in ckeys:
            s = row["systems"].get(k, {})
            if "jit_ms" in s:
                cells.append(f"{s['jit_ms']:.1f}" + (" disk" if s.get("disk_cache_hit") else " (cached)" if s["jit_ms"] < 0.05 else ""))
            else:
                ms = s.get("compile_ms", float("nan"))
                cells.append("~0" if ms < 0.05 else f"{ms:.1f}")
        lines.append(f"| {row['name']} | " + " | ".join(cells) + " |")
    s = out["summary"]
    lines += ["", "summary"]
    for p, c in s["verdicts"].items():
        lines.append(f"- against {label(p)}: lobe wins {c['lobe wins']}, tie {c['tie']}, peer wins {c['peer wins']}")
    for crit, name in (("llvm_within_1.2x_drjit", "llvm (precise) ≤ 1.2× Dr.Jit"), ("cranelift_within_2.5x_drjit", "cranelift ≤ 2.5× Dr.Jit")):
        for t, v in s[crit].items():
            lines.append(f"- {name} ({TEXTS[t]}): {len(v['rows'])} of {v['of']} rows" + (f"; not on: " + ", ".join(f"{r} {x}" for r, x in v["not"].items()) if v["not"] else ""))
    errors = [f"{row['name']} / {label(n)}: {s['error']}" for row in out["rows"] for n, s in row["systems"].items() if "error" in s]
    if errors:
        lines += ["", "failed: " + "; ".join(errors)]
    return "\n".join(lines)


# -- the self-test ----------------------------------------------------------------------------------------------
def self_test():
    """The statistics, the verdicts and the translator on synthetic inputs; the translations of the catalogue's
    formulas against `lobe eval --points` on 1000 points. Returns the process exit code."""
    failures = []

    def check(cond, what):
        if not cond:
            failures.append(what)
        print(f"{'ok  ' if cond else 'FAIL'} {what}", file=sys.stderr)

    # Statistics: the median of per-round ratios, not min/min nor a ratio of medians.
    s = ratios([1.0, 3.0, 3.0, 3.0, 3.0], [3.0, 2.0, 2.0, 2.0, 2.0])
    check(abs(s["median"] - 1.5) < 1e-12 and abs(s["min"] - 1 / 3) < 1e-12 and s["max"] == 1.5, "per-round ratios: median 1.5, min 1/3 (min/min would be 0.5)")
    check(ratios([1, 2, 3, 4, 5], [2, 4, 6, 8, 10])["median"] == 0.5, "paired rounds: a constant ratio")
    try:
        ratios([1, 2], [1])
        check(False, "unequal rounds refused")
    except ValueError:
        check(True, "unequal rounds refused")
    # Verdicts.
    good, bad, nan = {"max_bits": 1.0, "nonfinite": 0}, {"max_bits": 9.0, "nonfinite": 0}, {"max_bits": 1.0, "nonfinite": 3}
    st = lambda r: ratios(r, [1.0] * len(r))  # noqa: E731
    check(verdict({"llvm": (good, st([0.9, 1.1, 1.0, 0.95, 1.05]))}, good)[0] == "tie", "a ratio list straddling 1 is a tie")
    check(verdict({"llvm": (good, st([0.8, 0.85, 0.9, 0.82, 0.88]))}, good)[0] == "lobe wins", "all rounds under 1 and as accurate: lobe wins")
    check(verdict({"llvm": (good, st([0.8, 0.85, 1.0, 0.82, 0.88]))}, good)[0] == "lobe wins", "max exactly 1.0 does not straddle: lobe wins")
    check(verdict({"llvm": (bad, st([0.5] * 5))}, good)[0] == "peer wins", "faster but less accurate (max bits): peer wins")
    check(verdict({"llvm": (nan, st([0.5] * 5))}, good)[0] == "peer wins", "faster but more non-finite values: peer wins")
    check(verdict({"llvm": (good, st([1.2, 1.3, 1.5, 1.25, 1.4]))}, good)[0] == "peer wins", "as accurate, slower in every round: peer wins")
    v = verdict({"llvm-speed": (bad, st([0.5] * 5)), "llvm": (good, st([1.3] * 5)), "cranelift": (good, st([0.7, 0.9, 0.8, 0.75, 0.85]))}, good)
    check(v[:2] == ("lobe wins", "cranelift"), "the verdict takes any as-accurate mode (cranelift), not the fastest inaccurate one")
    check(verdict({"llvm": (good, st([0.9, 1.2, 1.1, 1.3, 1.05]))}, bad)[0] == "tie", "median above 1 but straddling: tie")
    check(within({"a": st([1.1, 1.2, 1.3]), "b": st([1.3, 1.25, 1.21])}, 1.2) == ["a"], "≤ 1.2× counts the median (a: 1.2) only")
    # The translator on synthetic text.
    src = "# c\n@name \"x\"\nparam a = 2 in 1..3\nlet c = NH  # the cosine\nlet d = max(c,\n  0.5)\n2*c / (1.25 *\n (a - a*c + c)^2) + d^2\n"
    t = written_text(src)
    check(t == "let c = NH\nlet d = max(c, 0.5)\n2*c / (1.25 * (a - a*c + c)^2) + d^2", f"written_text joins continued lines and drops comments/directives: {t!r}")
    f = function(program(t), ["NH"], NP_CALLS, {"a": "2.0", "pi": "np.pi"}, {"np": np})
    x = 0.3
    check(abs(f(np.array([x]))[0] - (2 * x / (1.25 * (2 - 2 * x + x) ** 2) + max(x, 0.5) ** 2)) < 1e-15, "numpy translation of the synthetic text")
    check(abs(function(program("-x^2"), ["x"], NP_CALLS, {}, {"np": np})(3.0) + 9.0) == 0.0, "-x^2 = -(x^2), as in lobe")
    check(function(program("2^3^2"), [], NP_CALLS, {}, {"np": np})() == 512.0, "^ is right-associative")
    for bad_src, what in (("fn sqr(x) = x*x\nsqr(NH)", "fn"), ("NH > 0.5 ? 1 : 0", "select")):
        try:
            written_text(bad_src)
            check(False, f"{what} refused with a reason")
        except NotImplementedError as e:
            check(bool(str(e)), f"{what} refused with a reason: {e}")
    try:
        translate(program("erf(NH)"), NP_CALLS, {})
        check(False, "an unknown builtin is refused")
    except NotImplementedError as e:
        check("erf" in str(e), f"an unknown builtin is refused: {e}")
    # The catalogue: both texts of every formula, against `lobe eval --points` on 1000 points.
    binary = lobe_bin()
    if binary is None:
        check(False, "a lobe binary (cargo build --release, or LOBE_BIN)")
    else:
        rng = np.random.default_rng(7)
        cols = {c: rng.uniform(0.0, 1.0, 1000) for c in COSINES}
        tmp = tempfile.mkdtemp(prefix="lobe-peers-test-")
        csvs = {}
        optional = {}
        for mod in ("numba", "drjit", "numexpr"):
            try:
                optional[mod] = __import__(mod)
            except ImportError:
                pass
        if "drjit" in optional:
            optional["drjit"].set_thread_count(1)
        for path in sorted(glob.glob(os.path.join(ROOT, "examples", "brdfs", "*.brdf"))):
            name = os.path.basename(path)
            try:
                fm = Formula(binary, path, cols, 1000, tmp, csvs, live=False, truth=False)
            except Exception as e:  # noqa: BLE001
                check(False, f"{name}: {type(e).__name__}: {e}")
                continue
            ref = values(run_json([binary, "eval", path, *fm.set, "--points", fm.csv, "--json", "--tier", "cranelift"]))
            for text in TEXTS:
                prog, names = fm.progs[text]
                if prog is None:
                    check(False, f"{name} {TEXTS[text]}: {fm.untranslated[text]}")
                    continue
                tried = [("numpy", np, build_numpy)] + [(m, optional[m], b) for m, b in (("numexpr", build_numexpr), ("numba", build_numba), ("drjit", build_drjit)) if m in optional]
                for sysname, mod, build in tried:
                    call, result, split = build(mod, fm, prog, names)
                    got = result(split(call()) if split else call())
                    same_nan = np.array_equal(np.isnan(got), np.isnan(ref))
                    ok = np.isfinite(ref) & (np.abs(ref) > 1e-290)
                    rel = np.abs(got[ok] - ref[ok]) / np.abs(ref[ok])
                    tiny = ~ok & np.isfinite(ref)
                    worst = float(rel.max()) if rel.size else 0.0
                    check(same_nan and worst <= 1e-12 and np.all(np.abs(got[tiny]) <= 1e-290), f"{name} {TEXTS[text]} in {sysname}: max relative difference {worst:.1e} against `lobe eval --points` (1000 points)")
        _DR_COLS.clear()
    print(f"self-test: {len(failures)} failure(s)", file=sys.stderr)
    return 1 if failures else 0


if __name__ == "__main__":
    main()
