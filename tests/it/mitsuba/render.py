"""docs/mitsuba.md's rendering example: a sphere with an exported lobe BSDF under a constant environment and a
point light, path traced in scalar_rgb and llvm_ad_rgb. Prints `mean V` (the image's mean) per variant."""
import importlib.util
import sys

import drjit as dr
import mitsuba as mi


def scene(plugin):
    return {
        'type': 'scene',
        'integrator': {'type': 'path', 'max_depth': 3},
        'sensor': {
            'type': 'perspective',
            'fov': 30,
            'to_world': mi.ScalarTransform4f().look_at(origin=[0, 0, 5], target=[0, 0, 0], up=[0, 1, 0]),
            'film': {'type': 'hdrfilm', 'width': 32, 'height': 32},
            'sampler': {'type': 'independent', 'sample_count': 16},
        },
        'sphere': {'type': 'sphere', 'bsdf': {'type': plugin}},
        'env': {'type': 'constant', 'radiance': {'type': 'rgb', 'value': 0.5}},
        'light': {'type': 'point', 'position': [3, 3, 4], 'intensity': {'type': 'rgb', 'value': 40.0}},
    }


for variant in ('scalar_rgb', 'llvm_ad_rgb'):
    mi.set_variant(variant)
    spec = importlib.util.spec_from_file_location('lobe_export', sys.argv[1])
    m = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(m)  # registers the plugin for this variant
    image = mi.render(mi.load_dict(scene(m._NAME)))
    mean = dr.mean(dr.ravel(mi.TensorXf(image)))
    print('mean', float(mean[0] if dr.is_array_v(mean) else mean))
    mi.util.write_bitmap(variant + '.png', image)
