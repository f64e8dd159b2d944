"""Sampling efficiency E[w]²/E[w²] of Mitsuba 3's own `roughconductor` sampling (visible normals, its default)
beside lobe's sampler (the exported plugin), for GGX and Beckmann at the roughness BENCHMARKS.md §18 uses (each
file's default: examples/explorer/ggx.brdf alpha = 0.2, examples/brdfs/beckmann.brdf m = 0.3; Mitsuba's Beckmann
alpha is the RMS slope m), at θi = 0°, 30°, 60°, 85°, 10⁵ samples each (llvm_ad_rgb).

Columns: `lobe` — the weights of the exported plugin's sample() (lobe's sampler: its f·cosθo/pdf);
`mitsuba on lobe's f` — directions and pdf from roughconductor.sample(), weight lobe's f·cosθo / that pdf (the
same target as lobe's column, so the two compare the samplers); `roughconductor` — the weights roughconductor
itself returns (its own BRDF, `material: none`: no Fresnel).

    python benches/mitsuba_efficiency.py [path/to/lobe]     (a Python with `pip install mitsuba`)
"""
import importlib.util
import math
import os
import subprocess
import sys
import tempfile

import drjit as dr
import mitsuba as mi

mi.set_variant('llvm_ad_rgb')
ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
LOBE = sys.argv[1] if len(sys.argv) > 1 else os.path.join(ROOT, 'target/release/lobe')
N = 100_000
CASES = [('explorer/ggx.brdf', 'ggx', 0.2), ('brdfs/beckmann.brdf', 'beckmann', 0.3)]


def efficiency(w):
    s, s2 = dr.sum(w)[0], dr.sum(w * w)[0]
    return s * s / (N * s2) if s2 > 0 else 0.0


def main():
    tmp = tempfile.mkdtemp()
    print('| file | distribution, alpha | θi | lobe | mitsuba on lobe\'s f | roughconductor |')
    print('|---|---|---|---|---|---|')
    for path, dist, alpha in CASES:
        out = os.path.join(tmp, dist + '.py')
        subprocess.run([LOBE, 'export', '--mitsuba', os.path.join(ROOT, 'examples', path), '-o', out], check=True)
        spec = importlib.util.spec_from_file_location('lobe_' + dist, out)
        m = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(m)
        ours = mi.load_dict({'type': m._NAME})
        theirs = mi.load_dict({'type': 'roughconductor', 'distribution': dist, 'alpha': alpha, 'material': 'none'})
        ctx = mi.BSDFContext()
        for deg in (0, 30, 60, 85):
            t = math.radians(deg)
            si = dr.zeros(mi.SurfaceInteraction3f, N)
            si.wi = mi.Vector3f(math.sin(t), 0.0, math.cos(t))
            rng = mi.PCG32(N, initseq=dr.arange(mi.UInt64, N) + 1000 * deg)
            s1, s2 = rng.next_float32(), mi.Point2f(rng.next_float32(), rng.next_float32())
            _, w_lobe = ours.sample(ctx, si, s1, s2)
            bs, w_mi = theirs.sample(ctx, si, s1, s2)
            f_cos = ours.eval(ctx, si, bs.wo)
            w_cross = dr.select(bs.pdf > 0, f_cos.x / bs.pdf, 0.0)
            print(f'| {path} | {dist}, {alpha} | {deg}° | {efficiency(w_lobe.x):.2f} | {efficiency(w_cross):.2f} '
                  f'| {efficiency(w_mi.x):.2f} |', flush=True)


main()
