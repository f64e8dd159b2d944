"""Fitting a measured table: lobe's Levenberg–Marquardt with exact derivatives against Dr.Jit's Adam on the same
loss (BENCHMARKS.md §14).

For each model, `lobe tabulate` writes a synthetic MERL table at known parameters; `lobe fit --measured` recovers
them (its grid, then Levenberg–Marquardt with the exact Jacobian, docs/derivatives.md); Dr.Jit minimises the same
loss with its Adam optimiser (`drjit.opt.Adam`, automatic differentiation of the same formula written in Dr.Jit
operations, in double precision as lobe). The loss is lobe's default metric over every entry of the table (docs/measured.md, "Fitting: metrics
and colour scale"): the cosine-weighted log error with its closed-form colour scale per channel,

    E = √( Σ (ln(1 + s_c·f·cos θ_i) − ln(1 + m·cos θ_i))² / (3N) ),  s_c = Σ w·a·y / Σ w·a²,
    a = f·cos θ_i, y = m·cos θ_i, w = 1/(1 + y)²,

over the entries measured in all three channels with L and V above the surface, at the entries' own angles
(θ_h = (i/90)²·π/2, θ_d = j/90·π/2, φ_d = k/180·π; docs/measured.md, "The lookup"). The script checks that its
entries and its Dr.Jit formula are lobe's: the loss at the tabulated parameters must be ≤ 1e-12 and N must be the
count lobe reports.

Adam starts from the file's default parameters (a user's natural start; lobe starts from its own grid), one
learning rate per model tried from a small set (the best is kept, and each try's time counts only for itself),
parameters clamped to their declared ranges after each step. Reported: lobe's wall time and final E (from its
`--json`), and the wall time each needs to reach E ≤ 10⁻³, 10⁻⁴ and 10⁻⁶ (Adam's first iteration includes
tracing and compiling its kernels). Both on 2 threads.

    python benches/fit_peers.py [path/to/lobe]    (a Python with `pip install mitsuba numpy`: drjit ≥ 1.0)
"""
import json
import math
import os
import subprocess
import sys
import tempfile
import time

import numpy as np
import drjit as dr
import drjit.opt
from drjit.llvm.ad import Float64 as Float

TARGETS = (1e-3, 1e-4, 1e-6)
PI = math.pi


def cosines(L, V):
    """N·L, N·V, N·H and V·H in the local frame (N = +z), H = normalize(L + V), as the files write them."""
    h = [L[i] + V[i] for i in range(3)]
    hl = dr.sqrt(h[0] * h[0] + h[1] * h[1] + h[2] * h[2])
    h = [c / hl for c in h]
    return L[2], V[2], h[2], V[0] * h[0] + V[1] * h[1] + V[2] * h[2]


def ggx(p, L, V):
    """examples/explorer/ggx.brdf as written (GGX D, separable Smith G1, Schlick's Fresnel)."""
    alpha, f0 = p['alpha'], p['f0']
    nl, nv, nh, vh = cosines(L, V)
    a2 = alpha * alpha

    def d(c):
        t = c * c * (a2 - 1.0) + 1.0
        return a2 / (PI * t * t)

    def g1(c):
        tan2 = (1.0 - c * c) / (c * c)
        return 2.0 / (1.0 + dr.sqrt(1.0 + a2 * tan2))

    f = f0 + (1.0 - f0) * dr.power(1.0 - vh, 5.0)
    return d(nh) * g1(nl) * g1(nv) * f / (4.0 * nl * nv)


def cook_torrance(p, L, V):
    """examples/explorer/cook_torrance.brdf as written, both bools on (Beckmann D, V-groove G, dielectric F)."""
    m, eta = p['m'], p['ior']
    nl, nv, nh, vh = cosines(L, V)
    c2, m2 = nh * nh, m * m
    d = dr.exp((c2 - 1.0) / (m2 * c2)) / (PI * m2 * c2 * c2)
    gv = dr.select(2.0 * nh * nv < vh, 2.0 * nh * nv / vh, 1.0)
    gl = dr.select(2.0 * nh * nl < vh, 2.0 * nh * nl / vh, 1.0)
    g = dr.select(nv < nl, gv, gl)
    gg = dr.sqrt(eta * eta - 1.0 + vh * vh)
    a = (gg - vh) / (gg + vh)
    b = (vh * (gg + vh) - 1.0) / (vh * (gg - vh) + 1.0)
    fr = 0.5 * a * a * (1.0 + b * b)
    return d * g * fr / (4.0 * nl * nv)


# file, the Dr.Jit formula, the tabulated values, each parameter's declared range and default, learning rates.
MODELS = [
    ('examples/explorer/ggx.brdf', ggx, {'alpha': 0.35, 'f0': 0.6},
     {'alpha': (0.001, 1.0, 0.2), 'f0': (0.0, 1.0, 0.04)}, (0.003, 0.01, 0.03)),
    ('examples/explorer/cook_torrance.brdf', cook_torrance, {'m': 0.3, 'ior': 1.8},
     {'m': (0.01, 1.0, 0.25), 'ior': (1.0, 3.0, 1.5)}, (0.003, 0.01, 0.03)),
]

SCALES = (1.0 / 1500, 1.15 / 1500, 1.66 / 1500)


def entries(table):
    """The table's entries as lobe fits them: directions L, V (numpy, 3 × N), cos θ_i and m per channel."""
    raw = np.fromfile(table, dtype='<i4', count=3)
    assert tuple(raw) == (90, 90, 180), raw
    vals = np.fromfile(table, dtype='<f8', offset=12).reshape(3, 90, 90, 180)
    i, j, k = np.meshgrid(np.arange(90), np.arange(90), np.arange(180), indexing='ij')
    th = (i / 90.0) ** 2 * (PI / 2)
    td = j / 90.0 * (PI / 2)
    pd = k / 180.0 * PI
    d = np.stack([np.sin(td) * np.cos(pd), np.sin(td) * np.sin(pd), np.cos(td)])
    # L = D turned by θ_h about the bitangent (y); φ_h = 0.
    L = np.stack([d[0] * np.cos(th) + d[2] * np.sin(th), d[1], -d[0] * np.sin(th) + d[2] * np.cos(th)])
    H = np.stack([np.sin(th), np.zeros_like(th), np.cos(th)])
    V = 2 * (L * H).sum(axis=0) * H - L
    measured = (vals >= 0).all(axis=0)
    keep = measured & (L[2] > 0) & (V[2] > 0)
    m = np.stack([vals[c][keep] * SCALES[c] for c in range(3)])
    return L[:, keep], V[:, keep], L[2][keep], m


def loss_fn(model, L, V, cos, m):
    """E(params) in Dr.Jit, differentiable."""
    Lj = [Float(L[c]) for c in range(3)]
    Vj = [Float(V[c]) for c in range(3)]
    cj = Float(cos)
    y = [Float(m[c]) * cj for c in range(3)]
    w = [1.0 / ((1.0 + yc) * (1.0 + yc)) for yc in y]
    logm = [dr.log(1.0 + yc) for yc in y]
    n = 3 * len(cos)

    def loss(p):
        a = model(p, Lj, Vj) * cj
        total = Float(0.0)
        for c in range(3):
            s = dr.sum(w[c] * a * y[c]) / dr.sum(w[c] * a * a)
            r = dr.log(1.0 + s * a) - logm[c]
            total += dr.sum(r * r)
        return dr.sqrt(total / n)

    return loss


def lobe_fit(lobe, file, table, ranges):
    args = [lobe, 'fit', file, '--measured', table, '--json']
    for name, (lo, hi, _) in ranges.items():
        args += ['--param', f'{name}={lo}..{hi}']
    t = time.perf_counter()
    out = subprocess.run(args, capture_output=True, text=True, check=True)
    wall = time.perf_counter() - t
    j = json.loads(out.stdout)
    return j, wall


def adam(loss, ranges, lr, cap_iters=3000, cap_seconds=120.0):
    """Adam from the defaults; (seconds to reach each target or None, final E, iterations, parameters)."""
    opt = dr.opt.Adam(lr=lr)
    for name, (_, _, default) in ranges.items():
        opt[name] = Float(default)
    reached = {t: None for t in TARGETS}
    t0 = time.perf_counter()
    e = float('nan')
    it = 0
    for it in range(1, cap_iters + 1):
        p = {name: opt[name] for name in ranges}
        e_ad = loss(p)
        dr.backward(e_ad)
        e = float(e_ad[0])
        now = time.perf_counter() - t0
        for t in TARGETS:
            if reached[t] is None and e <= t:
                reached[t] = now
        if all(v is not None for v in reached.values()) or now > cap_seconds or not math.isfinite(e):
            break
        opt.step()
        for name, (lo, hi, _) in ranges.items():
            opt[name] = dr.clip(opt[name], lo, hi)
    return reached, e, it, {name: float(opt[name][0]) for name in ranges}


def main():
    lobe = os.path.abspath(sys.argv[1] if len(sys.argv) > 1 else 'target/release/lobe')
    dr.set_thread_count(2)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for file, model, truth, ranges, rates in MODELS:
            table = os.path.join(tmp, os.path.basename(file) + '.binary')
            sets = sum((['--set', f'{k}={v}'] for k, v in truth.items()), [])
            subprocess.run([lobe, 'tabulate', file, *sets, '-o', table], check=True, capture_output=True)
            L, V, cos, m = entries(table)
            j, wall = lobe_fit(lobe, file, table, ranges)
            if j['entries'] != len(cos):
                sys.exit(f'{file}: {len(cos)} entries here, lobe fitted {j["entries"]}')
            loss = loss_fn(model, L, V, cos, m)
            at_truth = float(loss({k: Float(v) for k, v in truth.items()})[0])
            if not at_truth <= 1e-12:
                sys.exit(f'{file}: the Dr.Jit loss at the tabulated parameters is {at_truth:.3e}, not lobe\'s formula')
            best = None
            for lr in rates:
                r = adam(loss, ranges, lr)
                key = (sum(1 for v in r[0].values() if v is not None), -r[1])
                if best is None or key > best[0]:
                    best = (key, lr, r)
            _, lr, (reached, e, iters, params) = best
            rows.append((file, truth, j, wall, lr, reached, e, iters, params))
    print('| model (tabulated at) | lobe fit: wall, final E, parameters | Dr.Jit Adam: lr, iterations, final E, parameters |'
          + ''.join(f' to E ≤ {t:g}: lobe / Adam |' for t in TARGETS))
    print('|---|---|---|' + '---|' * len(TARGETS))
    for file, truth, j, wall, lr, reached, e, iters, params in rows:
        lp = ', '.join(f'{k} = {v:.6g}' for k, v in j['params'].items())
        ap = ', '.join(f'{k} = {v:.6g}' for k, v in params.items())
        tv = ', '.join(f'{k} = {v}' for k, v in truth.items())
        cells = ''.join(f" {wall:.2f} s / {'—' if reached[t] is None else f'{reached[t]:.2f} s'} |" for t in TARGETS)
        print(f'| {os.path.basename(file)} ({tv}) | {wall:.2f} s, {j["error"]:.2e}, {lp} | {lr:g}, {iters}, {e:.2e}, {ap} |{cells}')
    print('(lobe\'s wall time is to its final E, below every target; "—": Adam did not reach it within 3000 '
          'iterations or 120 s)')


if __name__ == '__main__':
    main()
