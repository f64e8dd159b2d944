"""The same scene rendered by lobe and by Mitsuba 3 (tests/it/envcompare.rs drives it; docs/mitsuba.md, "The same
scene in lobe and in Mitsuba").

Mitsuba renders: the OBJ sphere (the triangles and vertex normals lobe renders) with the BSDF plugin that
`lobe export --mitsuba` wrote, under the environment map, seen by a perspective camera with lobe's parameters
(vertical fov, position, target, up, square image, box pixel filter: lobe jitters uniformly over the pixel),
`direct` integrator (direct lighting only). The map goes to Mitsuba so that its radiance function is lobe's:
lobe looks maps up nearest-pixel with pixel (x, y) covering u in [x/W, (x+1)/W), v in [y/H, (y+1)/H); Mitsuba's
`envmap` interpolates bilinearly between samples at u = (x + 1/2)/W and v = y/(H - 1) (its half-texel shift and
its rows from pole to pole). Mitsuba gets the map repeated k times in u (column x' holds lobe's column x' // k)
and k·H + 1 rows at v = j/(k·H) (row j holds lobe's row j // k; a row on a boundary between two of lobe's rows
holds their mean): Mitsuba's function is then lobe's except in bands 1/k of a pixel wide about lobe's pixel
edges, where it ramps linearly and symmetrically from one value to the other (the same integral to first order).
`rotate` (degrees about +y, counter-clockwise seen from above, as lobe's scene key) is Mitsuba's emitter
`to_world` rotation about +y by the same angle: both conventions put u = 0 along -z and u = 1/4 along +x.

The Mitsuba image is the mean of `--passes` renders with different seeds, so its per-pixel standard error is
measured. A pixel counts as the sphere's when its four corners' rays all hit the sphere of radius `--inner`
(inside every facet). Prints a report, then one JSON line with the numbers (tests/it/envcompare.rs asserts).
"""
import argparse
import importlib.util
import json
import math
import time

import drjit as dr
import mitsuba as mi
import numpy as np

def mitsuba_map(path, k=4):
    """lobe's map at `path` as a bitmap for Mitsuba's `envmap` whose bilinear function is lobe's nearest-pixel one
    but for bands 1/k of a pixel wide (the module docstring)."""
    # As lobe reads it: lossy compression's ringing (negatives within 1e-3 of the maximum) is 0.
    src = np.array(mi.Bitmap(path), dtype=np.float32)[:, :, :3]
    src = np.where((src < 0) & (src >= -1e-3 * src.max()), np.float32(0), src)
    if (src < 0).any() or not np.isfinite(src).all():
        raise SystemExit(f'{path}: negative or non-finite pixels (lobe refuses this map)')
    h = src.shape[0]
    wide = np.repeat(src, k, axis=1)
    rows = np.empty((k * h + 1, wide.shape[1], 3), np.float32)
    for j in range(k * h + 1):
        if j % k:
            rows[j] = wide[j // k]
        else:
            rows[j] = 0.5 * (wide[max(j // k - 1, 0)] + wide[min(j // k, h - 1)])
    return mi.Bitmap(rows)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument('--module', required=True, help='the module `lobe export --mitsuba` wrote')
    ap.add_argument('--lobe-exr', required=True, help="lobe's render (linear RGB EXR)")
    ap.add_argument('--map', required=True, help='the latitude-longitude map lobe rendered with')
    ap.add_argument('--rotate', type=float, default=0.0, help="lobe's [environment] rotate, degrees")
    ap.add_argument('--obj', required=True, help='the sphere lobe rendered (vertex normals, texture coordinates)')
    ap.add_argument('--inner', type=float, required=True, help='a radius inside every facet of the sphere')
    ap.add_argument('--size', type=int, required=True)
    ap.add_argument('--fov', type=float, required=True, help='vertical, degrees')
    ap.add_argument('--position', type=float, nargs=3, required=True)
    ap.add_argument('--spp', type=int, required=True, help='samples per pixel in all (split over the passes)')
    ap.add_argument('--passes', type=int, default=8)
    ap.add_argument('--upsample', type=int, default=4, help='k above')
    ap.add_argument('--block', type=int, default=8, help='side of the square blocks of pixels compared')
    ap.add_argument('--variant', default='llvm_ad_rgb')
    a = ap.parse_args()
    if a.spp % a.passes or a.size % a.block:
        raise SystemExit('--spp must be a multiple of --passes and --size of --block')

    mi.set_variant(a.variant)
    spec = importlib.util.spec_from_file_location('lobe_export', a.module)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)  # registers the plugin for this variant


    p = a.position
    scene = mi.load_dict({
        'type': 'scene',
        'integrator': {'type': 'direct'},
        'sensor': {
            'type': 'perspective', 'fov': a.fov, 'fov_axis': 'y',
            'to_world': mi.ScalarTransform4f().look_at(origin=p, target=[0, 0, 0], up=[0, 1, 0]),
            'film': {'type': 'hdrfilm', 'width': a.size, 'height': a.size, 'rfilter': {'type': 'box'},
                     'pixel_format': 'rgb'},
            'sampler': {'type': 'independent', 'sample_count': a.spp // a.passes},
        },
        'sphere': {'type': 'obj', 'filename': a.obj, 'bsdf': {'type': module._NAME}},
        'env': {'type': 'envmap', 'bitmap': mitsuba_map(a.map, a.upsample),
                'to_world': mi.ScalarTransform4f().rotate(axis=[0, 1, 0], angle=a.rotate)},
    })
    t0 = time.time()
    passes = np.array([np.array(mi.render(scene, seed=s), dtype=np.float64) for s in range(a.passes)])
    seconds = time.time() - t0
    mit = passes.mean(axis=0)
    lobe = np.array(mi.Bitmap(a.lobe_exr), dtype=np.float64)[:, :, :3]
    if lobe.shape != mit.shape:
        raise SystemExit(f'lobe image {lobe.shape} vs Mitsuba {mit.shape}')

    # Pixels inside the sphere: lobe's camera (vertical fov, square image, row 0 at the top).
    n, t = a.size, math.tan(math.radians(a.fov) / 2)
    eye = np.array(p, dtype=np.float64)
    fwd = -eye / np.linalg.norm(eye)
    right = np.cross(fwd, [0.0, 1.0, 0.0])
    right /= np.linalg.norm(right)
    up = np.cross(right, fwd)


    def hits(px, py):
        d = fwd + (2 * px / n - 1) * t * right + (1 - 2 * py / n) * t * up
        d /= np.linalg.norm(d)
        b = eye @ d
        return b * b - (eye @ eye - a.inner ** 2) > 0 and b < 0


    mask = np.array([[all(hits(x + dx, y + dy) for dx in (0, 1) for dy in (0, 1)) for x in range(n)] for y in range(n)])
    if mask.sum() < n * n // 8:
        raise SystemExit(f'only {mask.sum()} pixels inside the sphere')

    out = {'pixels': int(mask.sum()), 'mitsuba_seconds': seconds}
    # 1. The sphere's mean per channel: lobe / Mitsuba, and the standard error of that ratio from Mitsuba's passes
    #    (lobe's own noise is of the same order: the σ of the comparison is about √2 times it).
    sums = passes[:, mask, :].sum(axis=1)  # passes × channels
    out['mean_ratio'] = [float(lobe[mask, c].sum() / mit[mask, c].sum()) for c in range(3)]
    out['mean_ratio_sigma'] = [float(sums[:, c].std(ddof=1) / math.sqrt(a.passes) / sums[:, c].mean()) for c in range(3)]
    # 2. Per pixel (channel mean): the mean absolute relative difference, and Mitsuba's relative standard error.
    # Standard errors from the spread of the passes (of the channels' mean, per pixel or per block).
    lum_passes = passes.mean(axis=3)
    lum_l, lum_m, se_m = lobe.mean(axis=2), mit.mean(axis=2), lum_passes.std(axis=0, ddof=1) / math.sqrt(a.passes)
    rel = np.abs(lum_l - lum_m)[mask] / lum_m[mask]
    out['pixel_mean_abs_rel'] = float(rel.mean())
    out['pixel_sigma_rel'] = float((se_m[mask] / lum_m[mask]).mean())
    # 3. The same over blocks of block × block pixels wholly inside the sphere (a block's value is its pixels' mean:
    #    block² times the samples of one pixel).
    b, nb = a.block, n // a.block


    def blocks(img):
        return img.reshape(img.shape[:-2] + (nb, b, nb, b)).mean(axis=(-3, -1))


    bmask = mask.reshape(nb, b, nb, b).all(axis=(1, 3))
    bl, bm = blocks(lum_l), blocks(lum_m)
    bse = blocks(lum_passes).std(axis=0, ddof=1) / math.sqrt(a.passes)
    brel = np.abs(bl - bm)[bmask] / bm[bmask]
    out['blocks'] = int(bmask.sum())
    out['block_mean_abs_rel'] = float(brel.mean())
    out['block_max_abs_rel'] = float(brel.max())
    out['block_sigma_rel'] = float((bse[bmask] / bm[bmask]).mean())

    print(f"{module._NAME}: {out['pixels']} sphere pixels, Mitsuba {a.spp} spp in {seconds:.1f} s ({a.variant})")
    print('  sphere mean lobe/Mitsuba per channel: ' + ', '.join(
        f'{r:.4f} ± {s:.4f}' for r, s in zip(out['mean_ratio'], out['mean_ratio_sigma'])))
    print(f"  per pixel: mean |rel. difference| {out['pixel_mean_abs_rel']:.4f} "
          f"(Mitsuba's relative standard error alone {out['pixel_sigma_rel']:.4f})")
    print(f"  {b}×{b} blocks ({out['blocks']}): mean |rel. difference| {out['block_mean_abs_rel']:.4f}, "
          f"max {out['block_max_abs_rel']:.4f} (Mitsuba's relative standard error alone {out['block_sigma_rel']:.4f})")
    print(json.dumps(out))


if __name__ == '__main__':
    main()
