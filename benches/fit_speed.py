"""Fits with the exact Jacobian (Levenberg–Marquardt, `lobe fit --measured`) against the derivative-free search
(`--derivative-free`) on synthetic MERL tables (BENCHMARKS.md §14, "Exact Jacobian against derivative-free").

For each of four explorer models, SETS parameter sets drawn with a fixed seed from the middle 80 % of each declared
range (as tests/it/fit_grad.rs draws them); each set is tabulated with `lobe tabulate` and fitted both ways with the
test's flags (`--stride 3 --grid-stride 6 --json`, the declared ranges as `--param`), the two fits of a table run one
after the other, their order alternating from table to table so that a drift of the machine's load falls on both.
Per fit: the fit's own time (`seconds` in the JSON: the grid, the refinement and the reported residuals, without
reading the table or compiling the kernels), the process's wall and CPU time (user + system, all threads), and the
recovered parameters' largest relative error. Per model: the median and the range of the per-table ratios
derivative-free / Levenberg–Marquardt, for each of the three times.

    python3 benches/fit_speed.py [--lobe target/release/lobe] [--sets 5] [--seed 48] [--models ggx,ward] [--json out.json]

Python 3 standard library only.
"""
import argparse
import json
import os
import random
import resource
import statistics
import subprocess
import sys
import tempfile
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

# Each model: its file and the parameters to recover with their declared ranges (tests/it/fit_grad.rs).
MODELS = {
    'ggx': ('examples/explorer/ggx.brdf', [('alpha', 0.001, 1.0), ('f0', 0.0, 1.0)]),
    'cook_torrance': ('examples/explorer/cook_torrance.brdf', [('m', 0.01, 1.0), ('ior', 1.0, 3.0)]),
    'ward_anisotropic': ('examples/explorer/ward_anisotropic.brdf', [('alpha_x', 0.01, 1.0), ('alpha_y', 0.01, 1.0)]),
    'principled': ('examples/explorer/principled.brdf', [('roughness', 0.02, 1.0), ('metallic', 0.0, 1.0), ('specular', 0.0, 1.0)]),
}

FLAGS = ['--stride', '3', '--grid-stride', '6', '--json']


def run(cmd):
    """Runs `cmd` (checked); returns its stdout, wall seconds and CPU seconds (user + system of the child)."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    p = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if p.returncode != 0:
        sys.exit(f"{' '.join(cmd)} failed:\n{p.stderr}")
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return p.stdout, wall, cpu


def fit(lobe, file, table, params, extra):
    args = [lobe, 'fit', file, '--measured', table, *FLAGS]
    for name, lo, hi in params:
        args += ['--param', f'{name}={lo}..{hi}']
    out, wall, cpu = run(args + extra)
    v = json.loads(out)
    return {'seconds': v['seconds'], 'wall': wall, 'cpu': cpu, 'params': v['params'], 'error': v['error'],
            'refinement': v['refinement'], 'lm': v['lm']}


def spread(xs):
    return f'{statistics.median(xs):.1f}× ({min(xs):.1f}–{max(xs):.1f})'


def main():
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--lobe', default=os.path.join(ROOT, 'target/release/lobe'))
    ap.add_argument('--sets', type=int, default=5)
    ap.add_argument('--seed', type=int, default=48)
    ap.add_argument('--models', default=','.join(MODELS))
    ap.add_argument('--json', help='write every fit as JSON here')
    ap.add_argument('--lm-only', action='store_true', help='recovery only: no derivative-free fits, no ratios')
    a = ap.parse_args()
    lobe = os.path.abspath(a.lobe)
    rng = random.Random(a.seed)
    print(f'load average {os.getloadavg()[0]:.2f} {os.getloadavg()[1]:.2f} {os.getloadavg()[2]:.2f}, {os.cpu_count()} cores')
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for key in a.models.split(','):
            file, params = MODELS[key]
            for k in range(a.sets):
                truth = {n: lo + (hi - lo) * (0.1 + 0.8 * rng.random()) for n, lo, hi in params}
                table = os.path.join(tmp, f'{key}_{k}.binary')
                run([lobe, 'tabulate', file, '--set', ','.join(f'{n}={v!r}' for n, v in truth.items()), '-o', table])
                order = [('lm', []), ('df', ['--derivative-free'])]
                if k % 2:
                    order.reverse()
                if a.lm_only:
                    order = order[:1] if order[0][0] == 'lm' else order[1:]
                fits = {name: fit(lobe, file, table, params, extra) for name, extra in order}
                os.remove(table)
                for name, f in fits.items():
                    f['rel'] = max(abs(f['params'][n] - v) / abs(v) for n, v in truth.items())
                row = {'model': key, 'truth': truth, **fits}
                rows.append(row)
                lm = fits['lm']
                if a.lm_only:
                    print(f"{key:17} {k}  LM {lm['seconds']:.3f} s ({lm['lm']['starts']} starts, {lm['lm']['iterations']} it, "
                          f"rel {lm['rel']:.1e}) {truth}", flush=True)
                    continue
                df = fits['df']
                assert lm['refinement'] == 'levenberg-marquardt' and df['refinement'] == 'derivative-free', row
                print(f"{key:17} {k}  LM {lm['seconds']:.3f} s (wall {lm['wall']:.3f}, cpu {lm['cpu']:.3f}, "
                      f"{lm['lm']['starts']} starts, {lm['lm']['iterations']} it, rel {lm['rel']:.1e})  "
                      f"DF {df['seconds']:.3f} s (wall {df['wall']:.3f}, cpu {df['cpu']:.3f}, rel {df['rel']:.1e})  "
                      f"{df['seconds'] / lm['seconds']:.1f}×", flush=True)
    print(f'load average {os.getloadavg()[0]:.2f} {os.getloadavg()[1]:.2f} {os.getloadavg()[2]:.2f}')
    if a.lm_only:
        worst = max(rows, key=lambda r: r['lm']['rel'])
        print(f"largest relative error {worst['lm']['rel']:.1e} ({worst['model']} {worst['truth']})")
        return
    print()
    print('| model | LM fit s (median) | DF fit s (median) | DF/LM fit time | DF/LM process wall | DF/LM process CPU '
          '| LM largest rel. error | DF largest rel. error |')
    print('|---|---:|---:|---:|---:|---:|---:|---:|')
    for key in a.models.split(','):
        mine = [r for r in rows if r['model'] == key]
        ratio = {t: [r['df'][t] / r['lm'][t] for r in mine] for t in ('seconds', 'wall', 'cpu')}
        print(f"| {key} | {statistics.median(r['lm']['seconds'] for r in mine):.3f} "
              f"| {statistics.median(r['df']['seconds'] for r in mine):.3f} "
              f"| {spread(ratio['seconds'])} | {spread(ratio['wall'])} | {spread(ratio['cpu'])} "
              f"| {max(r['lm']['rel'] for r in mine):.1e} | {max(r['df']['rel'] for r in mine):.1e} |")
    if a.json:
        with open(a.json, 'w') as f:
            json.dump(rows, f, indent=1)


if __name__ == '__main__':
    main()
