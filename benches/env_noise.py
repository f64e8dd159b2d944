"""Noise against time for lobe's environment-light strategies (`lobe render --strategy bsdf|env|mis`): RMSE against
a 16 384-spp Mitsuba 3 reference of the same scene, against the tracer's CPU time, for a shiny and a rough GGX
sphere under blender-data's forest.exr; writes docs/env_noise.svg and prints the table (BENCHMARKS.md §19).

The scene is tests/it/envcompare.rs's (docs/mitsuba.md, "The same scene in lobe and in Mitsuba"): a 48-stack OBJ
sphere, camera at (0, 0, 4), fov 30°, 64×64, examples/explorer/ggx.brdf with f0 = 0.5 and alpha 0.05 (shiny) or
0.5 (rough), kd = 0, ks = 1, `times_nl`. The reference is Mitsuba's (`direct`, the exported plugin): lobe's samples
are a fixed sequence per pixel, so a lobe reference would share its first samples with every trial. RMSE is over the
pixels wholly inside the sphere, linear RGB. Time is the tracer's CPU time (`--stats`: "shading … ms cpu"), which a
loaded machine inflates less than wall time.

    python benches/env_noise.py [path/to/lobe]     (a Python with `pip install mitsuba numpy`; blender-data)
"""
import importlib.util
import math
import os
import re
import subprocess
import sys
import tempfile

import mitsuba as mi
import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
LOBE = sys.argv[1] if len(sys.argv) > 1 else os.path.join(ROOT, 'target/release/lobe')
MAP = '/usr/share/blender/datafiles/studiolights/world/forest.exr'
GGX = os.path.join(ROOT, 'examples/explorer/ggx.brdf')
SIZE, FOV, DIST, STACKS = 64, 30, 4, 48
REF = 16384
SPPS = [16, 64, 256]
STRATEGIES = ['bsdf', 'env', 'mis']
MATERIALS = [('shiny', 0.05), ('rough', 0.5)]
OUT = os.path.join(ROOT, 'docs/env_noise.svg')

mi.set_variant('llvm_ad_rgb')


def load(path, name):
    spec = importlib.util.spec_from_file_location(name, path)
    m = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(m)
    return m


def inside():
    """Pixels whose four corners' rays hit the sphere's inscribed radius cos(π/STACKS)."""
    t = math.tan(math.radians(FOV) / 2)

    def hits(px, py):
        d = np.array([(2 * px / SIZE - 1) * t, (1 - 2 * py / SIZE) * t, -1.0])
        d /= np.linalg.norm(d)
        return (DIST * d[2]) ** 2 - (DIST * DIST - math.cos(math.pi / STACKS) ** 2) > 0

    return np.array([[all(hits(x + dx, y + dy) for dx in (0, 1) for dy in (0, 1)) for x in range(SIZE)]
                     for y in range(SIZE)])


def main():
    tmp = tempfile.mkdtemp()
    envcompare = load(os.path.join(ROOT, 'tests/it/mitsuba/envcompare.py'), 'envcompare')
    speed = load(os.path.join(ROOT, 'benches/env_speed.py'), 'env_speed')
    speed.STACKS = STACKS
    obj = os.path.join(tmp, 'sphere.obj')
    speed.sphere_obj(obj)
    env = envcompare.mitsuba_map(MAP)
    mask = inside()
    curves = {}
    print(f'{SIZE}×{SIZE}, {int(mask.sum())} pixels inside the sphere, Mitsuba reference at {REF} spp')
    print('| material | strategy | spp | RMSE | CPU s | RMSE·√(CPU s) |')
    print('| --- | --- | ---: | ---: | ---: | ---: |')
    for name, alpha in MATERIALS:
        module = os.path.join(tmp, f'ggx_{name}.py')
        subprocess.run([LOBE, 'export', '--mitsuba', GGX, '--set', f'alpha={alpha}', '--set', 'f0=0.5', '-o', module],
                       check=True, capture_output=True)
        plugin = load(module, f'ggx_{name}')._NAME
        scene = mi.load_dict({
            'type': 'scene',
            'integrator': {'type': 'direct'},
            'sensor': {
                'type': 'perspective', 'fov': FOV, 'fov_axis': 'y',
                'to_world': mi.ScalarTransform4f().look_at(origin=[0, 0, DIST], target=[0, 0, 0], up=[0, 1, 0]),
                'film': {'type': 'hdrfilm', 'width': SIZE, 'height': SIZE, 'rfilter': {'type': 'box'},
                         'pixel_format': 'rgb'},
                'sampler': {'type': 'independent', 'sample_count': 16},
            },
            'sphere': {'type': 'obj', 'filename': obj, 'bsdf': {'type': plugin}},
            'env': {'type': 'envmap', 'bitmap': env},
        })
        reference = np.mean([np.array(mi.render(scene, spp=REF // 4, seed=s), dtype=np.float64) for s in range(4)],
                            axis=0)
        toml = os.path.join(tmp, f'{name}.toml')
        with open(toml, 'w') as f:
            f.write(f'width = {SIZE}\nheight = {SIZE}\n[environment]\npath = "{MAP}"\n[camera]\n'
                    f'position = [0, 0, {DIST}]\nfov = {FOV}\n[materials.m]\nbrdf = "{GGX}"\n'
                    f'params = {{ alpha = {alpha}, f0 = 0.5 }}\nka = 0\nkd = 0\nks = 1\ntimes_nl = true\n'
                    f'[[object]]\nshape = "mesh"\npath = "sphere.obj"\nmaterial = "m"\n')
        for strategy in STRATEGIES:
            pts = []
            for spp in SPPS:
                out = os.path.join(tmp, f'{name}_{strategy}_{spp}.exr')
                r = subprocess.run([LOBE, 'render', toml, '-o', out, '--threads', '2', '--spp', str(spp), '--strategy',
                                    strategy, '--stats'], capture_output=True, text=True, check=True)
                cpu = float(re.search(r'shading ([0-9.]+) ms cpu', r.stdout + r.stderr).group(1)) / 1e3
                img = np.array(mi.Bitmap(out), dtype=np.float64)[:, :, :3]
                rmse = math.sqrt(((img - reference) ** 2)[mask].mean())
                pts.append((cpu, rmse))
                print(f'| {name} (α = {alpha}) | {strategy} | {spp} | {rmse:.5f} | {cpu:.3f} | {rmse * math.sqrt(cpu):.5f} |')
            curves[(name, strategy)] = pts
    svg(curves)
    print('wrote', os.path.relpath(OUT, ROOT))


def svg(curves):
    """Log–log RMSE against CPU seconds, one panel per material."""
    w, h, pad = 360, 280, 50
    colours = {'bsdf': '#d62728', 'env': '#1f77b4', 'mis': '#2ca02c'}
    xs = [c for pts in curves.values() for c, _ in pts]
    ys = [r for pts in curves.values() for _, r in pts]
    lx0, lx1 = math.floor(math.log10(min(xs))), math.ceil(math.log10(max(xs)))
    ly0, ly1 = math.floor(math.log10(min(ys))), math.ceil(math.log10(max(ys)))
    parts = [f'<svg xmlns="http://www.w3.org/2000/svg" width="{2 * w}" height="{h}" font-family="sans-serif" '
             f'font-size="11">']
    for i, (name, alpha) in enumerate(MATERIALS):
        ox = i * w

        def px(x, y):
            return (ox + pad + (math.log10(x) - lx0) / (lx1 - lx0) * (w - 1.5 * pad),
                    h - pad - (math.log10(y) - ly0) / (ly1 - ly0) * (h - 1.7 * pad))

        x0, y0 = px(10 ** lx0, 10 ** ly0)
        x1, y1 = px(10 ** lx1, 10 ** ly1)
        parts.append(f'<rect x="{x0}" y="{y1}" width="{x1 - x0}" height="{y0 - y1}" fill="none" stroke="#888"/>')
        for e in range(lx0, lx1 + 1):
            x, _ = px(10 ** e, 10 ** ly0)
            parts.append(f'<text x="{x}" y="{y0 + 14}" text-anchor="middle">1e{e}</text>')
        for e in range(ly0, ly1 + 1):
            _, y = px(10 ** lx0, 10 ** e)
            parts.append(f'<text x="{x0 - 4}" y="{y + 4}" text-anchor="end">1e{e}</text>')
        parts.append(f'<text x="{(x0 + x1) / 2}" y="{y1 - 8}" text-anchor="middle">{name} GGX (α = {alpha})</text>')
        parts.append(f'<text x="{(x0 + x1) / 2}" y="{h - 8}" text-anchor="middle">CPU seconds</text>')
        parts.append(f'<text x="{ox + 12}" y="{(y0 + y1) / 2}" transform="rotate(-90 {ox + 12} {(y0 + y1) / 2})" '
                     f'text-anchor="middle">RMSE</text>')
        for j, strategy in enumerate(STRATEGIES):
            pts = [px(c, r) for c, r in curves[(name, strategy)]]
            path = ' '.join(f'{x:.1f},{y:.1f}' for x, y in pts)
            parts.append(f'<polyline points="{path}" fill="none" stroke="{colours[strategy]}" stroke-width="2"/>')
            parts += [f'<circle cx="{x:.1f}" cy="{y:.1f}" r="3" fill="{colours[strategy]}"/>' for x, y in pts]
            parts.append(f'<text x="{x1 - 40}" y="{y1 + 16 + 14 * j}" fill="{colours[strategy]}">{strategy}</text>')
    parts.append('</svg>')
    with open(OUT, 'w') as f:
        f.write('\n'.join(parts) + '\n')


if __name__ == '__main__':
    main()
