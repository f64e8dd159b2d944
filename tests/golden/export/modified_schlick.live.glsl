// Modified Schlick — exported by lobe VERSION as GLSL 4.50.
// Source: Master's thesis “Development of rendering methods and software for computer graphics systems”, VNTU, Vinnytsia, 2022, eq. (2.3)
// Formula (simplified):
//   let nh = clamp(NH, 0, 1)
//   let t1 = n * (1 - nh) + 1.25 * nh
//   2 * nh / (1.25 * (t1 * t1))
// Inputs are cosines (clamped to [0, 1] here, as lobe does); the result is clamped at 0.
// lobe evaluates in f64; this runs in f32. GPU min/max need not propagate NaN, and
// pow(x, y) is undefined on GPUs for x < 0 or x = 0, y <= 0.
float lobe_modified_schlick(float NH, float n) {
    float t0 = clamp(NH, 0.0, 1.0);
    float t1 = ((n * (1.0 - t0)) + (1.25 * t0));
    return ((2.0 * t0) / (1.25 * (t1 * t1)));
}
