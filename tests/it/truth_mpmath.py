"""The truth evaluator against mpmath (tests/it/truth_mpmath.rs): reads cases as JSON on stdin, each a program
of IR nodes (the formula's, or one builtin's on its arguments), the argument values, and lobe's truth as
(hi, lo, e); evaluates the program in mpmath at 2 300 bits with the builtins' documented semantics written here
independently; prints per case the relative difference (null where the reference is not a finite non-zero
number, with what each gave)."""
import json
import math
import sys

import mpmath
from mpmath import mp, mpf
from mpmath.libmp import libmpf

# Wide enough that any sum of two f64s is exact (their exponents span 2¹⁰²⁴ to 2⁻¹⁰⁷⁴): 1 − 2⁻¹⁰⁷⁰ is not 1.
mp.prec = 2300


def f64(text):
    """An f64 from the Rust side's shortest round-trip text (exact)."""
    return mpf(float(text))


def to_f64(x):
    """Round to the nearest double (the truth decides steps on f64s; mpf's own float() truncates)."""
    return libmpf.to_float(x._mpf_, rnd=libmpf.round_nearest)


def is_int(x):
    return mpmath.isfinite(x) and x == mpmath.floor(x)


def powr(x, y):
    if x == 0:
        return mpf(1) if y == 0 else (mpf(0) if y > 0 else mpf("inf"))
    if x < 0:
        if not is_int(y):
            return mpf("nan")
        r = mpmath.power(-x, y)
        return -r if int(y) % 2 else r
    return mpmath.power(x, y)


def call(name, a):
    if name == "pow" or name == "powlo":
        return powr(a[0], a[1]) if name == "pow" else mpf(0)
    if name in ("sin", "sinnear"):
        return mpmath.sin(a[0])
    if name == "cos":
        return mpmath.cos(a[0])
    if name == "tan":
        return mpmath.sin(a[0]) / mpmath.cos(a[0])
    if name == "acos":
        return mpmath.acos(a[0]) if -1 <= a[0] <= 1 else mpf("nan")
    if name == "acoslo":
        return mpf(0)
    if name == "asin":
        return mpmath.asin(a[0]) if -1 <= a[0] <= 1 else mpf("nan")
    if name == "atan":
        return mpmath.atan(a[0])
    if name == "exp":
        return mpmath.exp(a[0])
    if name == "ln":
        return mpmath.log(a[0]) if a[0] > 0 else (mpf("-inf") if a[0] == 0 else mpf("nan"))
    if name == "sqrt":
        return mpmath.sqrt(a[0]) if a[0] >= 0 else mpf("nan")
    if name == "abs":
        return abs(a[0])
    if name == "min":
        return min(a[0], a[1])
    if name == "max":
        return max(a[0], a[1])
    if name == "clamp":
        return min(max(a[0], a[1]), a[2])
    if name == "floor":
        return mpf(math.floor(to_f64(a[0])))
    if name in ("lt", "le", "eq", "ne"):
        x, y = to_f64(a[0]), to_f64(a[1])
        return mpf(1 if {"lt": x < y, "le": x <= y, "eq": x == y, "ne": x != y}[name] else 0)
    if name == "select":
        return a[1] if to_f64(a[0]) != 0 else a[2]
    if name == "fma":
        return a[0] * a[1] + a[2]
    if name == "expmuldiv":
        return mpmath.exp(a[0]) * a[1] / a[2]
    raise ValueError("no mpmath definition of builtin " + name)


def run(nodes, inputs, params):
    v = []
    for n in nodes:
        k = n[0]
        if k == "const":
            v.append(f64(n[1]))
        elif k == "input":
            v.append(f64(inputs[n[1]]))
        elif k == "param":
            v.append(f64(params[n[1]]))
        elif k == "neg":
            v.append(-v[n[1]])
        elif k == "bin":
            a, b = v[n[2]], v[n[3]]
            v.append({"add": lambda: a + b, "sub": lambda: a - b, "mul": lambda: a * b,
                      "div": lambda: a / b if b != 0 else (mpf("nan") if a == 0 else mpmath.sign(a) * mpf("inf"))}[n[1]]())
        elif k == "call":
            v.append(call(n[1], [v[i] for i in n[2]]))
        else:
            raise ValueError(k)
    return v[-1]


def main():
    cases = json.load(sys.stdin)
    out = []
    for c in cases:
        ref = run(c["nodes"], c["inputs"], c["params"])
        hi, lo, e = (float(c["truth"][0]), float(c["truth"][1]), c["truth"][2])
        truth_f64 = math.ldexp(hi, e) if not math.isfinite(hi) or hi == 0 else None
        if truth_f64 is None:
            truth_f64 = to_f64((mpf(hi) + mpf(lo)) * mpmath.ldexp(mpf(1), e))
        ref_f64 = to_f64(ref) if not mpmath.isnan(ref) else math.nan
        same_f64 = truth_f64 == ref_f64 or (math.isnan(truth_f64) and math.isnan(ref_f64))
        if not mpmath.isfinite(ref) or ref == 0:
            special = "0" if ref == 0 else ("nan" if mpmath.isnan(ref) else ("+inf" if ref > 0 else "-inf"))
            out.append({"rel": None, "ref": special, "same_f64": same_f64})
            continue
        truth = (mpf(hi) + mpf(lo)) * mpmath.ldexp(mpf(1), e) if math.isfinite(hi) else None
        # A non-finite truth where mpmath's value is finite: the largest difference JSON can carry.
        rel = float(abs(truth - ref) / abs(ref)) if truth is not None else math.inf
        rel = rel if math.isfinite(rel) else 1e308
        out.append({"rel": rel, "ref": mpmath.nstr(ref, 30), "same_f64": same_f64})
    json.dump(out, sys.stdout, allow_nan=False)


if __name__ == "__main__":
    main()
