"""lobe's ray tracer against Mitsuba 3 under an environment map: camera samples per second on 2 threads, and the
time each needs to reach the same RMSE against its own high-spp reference (BENCHMARKS.md §19).

The scene is the papers' sphere (examples/scenes/paper_sphere.toml: a unit sphere of 20 stacks × 40 slices, camera
at (0, 0, 6), 45° vertical fov, the modified Schlick VR formula with n = 50) under blender-data's forest.exr, made
the same in both renderers as tests/it/envcompare.rs makes its scene (docs/mitsuba.md, "The same scene in lobe
and in Mitsuba"): one OBJ for both, lobe's material kd = 0, ks = 1, times_nl against the plugin `lobe export
--mitsuba` writes, Mitsuba's `direct` integrator, its map from tests/it/mitsuba/envcompare.py's mitsuba_map.
The point light, ambient and diffuse terms of the papers' scene are left out (they are not part of the BSDF).

One reference, Mitsuba's at REF spp: lobe's renders cannot be compared with a lobe reference, since lobe's samples
are a fixed sequence per pixel (a 64-spp render is the first 64 samples of a 16384-spp one); against Mitsuba's,
lobe's RMSE also holds the two renderers' systematic difference (≤ 0.2 % of the sphere's mean,
tests/it/envcompare.rs). Then RUNS renders at each of TRIAL_SPP (lobe's runs are the same image; only the time
varies). RMSE is over the pixels wholly inside the sphere (all four corners' rays hit its inscribed radius), so the
noise of a silhouette pixel's background does not count; linear RGB. RMSE²·time is constant for an unbiased
estimator, so the time to reach a target RMSE is RMSE²·t / target²; the target is 1 % of the sphere's mean. Time is the render's
wall time: lobe's `--stats` wall time of the tracer, Mitsuba's `mi.render` with `dr.set_thread_count(2)`, after
one warm-up render (its kernel compiles once).

    python benches/env_speed.py [path/to/lobe]     (a Python with `pip install mitsuba numpy`; blender-data)
"""
import importlib.util
import math
import os
import re
import statistics
import subprocess
import sys
import tempfile
import time

import drjit as dr
import mitsuba as mi
import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
LOBE = sys.argv[1] if len(sys.argv) > 1 else os.path.join(ROOT, 'target/release/lobe')
MAP = '/usr/share/blender/datafiles/studiolights/world/forest.exr'
FORMULA = os.path.join(ROOT, 'examples/brdfs/modified_schlick_vr.brdf')
SIZE = 128
REF = 16384
TRIAL_SPP = [64, 256]
RUNS = 3
STACKS = 20

mi.set_variant('llvm_ad_rgb')
dr.set_thread_count(2)


def load(path, name):
    spec = importlib.util.spec_from_file_location(name, path)
    m = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(m)
    return m


def sphere_obj(path):
    """The papers' sphere: STACKS stacks, 2·STACKS slices, vertex normals and texture coordinates."""
    s, p = STACKS, 2 * STACKS
    out = []
    for i in range(s + 1):
        t = math.pi * i / s
        for j in range(p + 1):
            f = 2 * math.pi * j / p
            x, y, z = math.sin(t) * math.sin(f), math.cos(t), math.sin(t) * math.cos(f)
            out.append(f'v {x!r} {y!r} {z!r}\nvn {x!r} {y!r} {z!r}\nvt {j / p!r} {1 - i / s!r}')
    for i in range(s):
        for j in range(p):
            a = i * (p + 1) + j + 1
            b, c = a + 1, a + p + 1
            if i > 0:
                out.append(f'f {a}/{a}/{a} {c}/{c}/{c} {b}/{b}/{b}')
            if i + 1 < s:
                out.append(f'f {b}/{b}/{b} {c}/{c}/{c} {c + 1}/{c + 1}/{c + 1}')
    with open(path, 'w') as f:
        f.write('\n'.join(out) + '\n')


def lobe_render(tmp, spp):
    """(image, seconds) from lobe at `spp`."""
    out = os.path.join(tmp, f'lobe_{spp}.exr')
    r = subprocess.run([LOBE, 'render', os.path.join(tmp, 'scene.toml'), '-o', out, '--threads', '2', '--spp', str(spp),
                        '--stats', '--force'], capture_output=True, text=True, check=True)
    wall = float(re.search(r'time: ([0-9.]+) ms wall', r.stdout + r.stderr).group(1)) / 1e3
    return np.array(mi.Bitmap(out), dtype=np.float64)[:, :, :3], wall


def main():
    tmp = tempfile.mkdtemp()
    obj = os.path.join(tmp, 'sphere.obj')
    sphere_obj(obj)
    module = os.path.join(tmp, 'msvr.py')
    subprocess.run([LOBE, 'export', '--mitsuba', FORMULA, '-o', module], check=True, capture_output=True)
    plugin = load(module, 'msvr')._NAME
    with open(os.path.join(tmp, 'scene.toml'), 'w') as f:
        f.write(f'width = {SIZE}\nheight = {SIZE}\n[environment]\npath = "{MAP}"\n[camera]\nposition = [0, 0, 6]\n'
                f'fov = 45\n[materials.m]\nbrdf = "{FORMULA}"\nparams = {{ n = 50 }}\nka = 0\nkd = 0\nks = 1\n'
                f'times_nl = true\n[[object]]\nshape = "mesh"\npath = "sphere.obj"\nmaterial = "m"\n')
    envcompare = load(os.path.join(ROOT, 'tests/it/mitsuba/envcompare.py'), 'envcompare')
    scene = mi.load_dict({
        'type': 'scene',
        'integrator': {'type': 'direct'},
        'sensor': {
            'type': 'perspective', 'fov': 45, 'fov_axis': 'y',
            'to_world': mi.ScalarTransform4f().look_at(origin=[0, 0, 6], target=[0, 0, 0], up=[0, 1, 0]),
            'film': {'type': 'hdrfilm', 'width': SIZE, 'height': SIZE, 'rfilter': {'type': 'box'},
                     'pixel_format': 'rgb'},
            'sampler': {'type': 'independent', 'sample_count': 16},
        },
        'sphere': {'type': 'obj', 'filename': obj, 'bsdf': {'type': plugin}},
        'env': {'type': 'envmap', 'bitmap': envcompare.mitsuba_map(MAP)},
    })
    seed = [0]

    def mitsuba_render(spp):
        seed[0] += 1
        t = time.perf_counter()
        img = np.array(mi.render(scene, spp=spp, seed=seed[0]), dtype=np.float64)
        return img, time.perf_counter() - t

    mitsuba_render(16)  # warm-up: the kernel compiles once
    renderers = {'lobe': lambda spp: lobe_render(tmp, spp), 'Mitsuba 3 llvm_ad_rgb': mitsuba_render}
    reference = mitsuba_render(REF)[0]
    t = math.tan(math.radians(45) / 2)

    def hits(px, py):
        d = np.array([(2 * px / SIZE - 1) * t, (1 - 2 * py / SIZE) * t, -1.0])
        d /= np.linalg.norm(d)
        return (6 * d[2]) ** 2 - (36 - math.cos(math.pi / STACKS) ** 2) > 0

    covered = np.array([[all(hits(x + dx, y + dy) for dx in (0, 1) for dy in (0, 1)) for x in range(SIZE)]
                        for y in range(SIZE)])
    target = 0.01 * reference[covered].mean()
    print(f'{SIZE}×{SIZE}, {int(covered.sum())} pixels inside the sphere, Mitsuba reference at {REF} spp, target RMSE '
          f'{target:.5f} (1 % of the sphere mean); {RUNS} runs per spp')
    print('| renderer | spp | RMSE | wall s (runs) | M camera samples/s | s to target RMSE (median, min–max) |')
    print('| --- | ---: | ---: | --- | ---: | --- |')
    to_target = {}
    for name, go in renderers.items():
        for spp in TRIAL_SPP:
            rows = []
            for _ in range(RUNS):
                img, secs = go(spp)
                rmse = math.sqrt(((img - reference) ** 2)[covered].mean())
                rows.append((rmse, secs))
            times = [r * r * s / target ** 2 for r, s in rows]
            to_target.setdefault(name, []).extend(times)
            secs = [s for _, s in rows]
            print(f'| {name} | {spp} | {statistics.median(r for r, _ in rows):.5f} | '
                  f'{", ".join(f"{s:.2f}" for s in secs)} | {SIZE * SIZE * spp / statistics.median(secs) / 1e6:.2f} | '
                  f'{statistics.median(times):.2f} ({min(times):.2f}–{max(times):.2f}) |')
    lo, mi_ = to_target['lobe'], to_target['Mitsuba 3 llvm_ad_rgb']
    ratios = sorted(m / l for l, m in zip(lo, mi_))
    print(f'time to target, Mitsuba / lobe per paired run: median {statistics.median(ratios):.2f}, '
          f'range {ratios[0]:.2f}–{ratios[-1]:.2f} over {len(ratios)} pairs')


if __name__ == '__main__':
    main()
