// Cook-Torrance — exported by lobe VERSION as GLSL 4.50.
// Source: R. L. Cook, K. E. Torrance, A reflectance model for computer graphics, ACM TOG 1982; Master's thesis “Development of rendering methods and software for computer graphics systems”, VNTU, Vinnytsia, 2022, eq. (1.10)
// Formula (simplified):
//   let nh = clamp(NH, 0, 1)
//   let t1 = nh * nh
//   let t2 = m * m
//   let vh = clamp(VH, 0, 1)
//   let nl = clamp(NL, 0, 1)
//   let t3 = 2 * nh
//   let nv = clamp(NV, 0, 1)
//   let t4 = 1 - vh
//   let t5 = t4 * t4
//   (F0 + (1 - F0) * (t5 * t5 * t4)) * (1 / (t2 * (t1 * t1)) * exp((t1 - 1) / (t2 * t1))) * min(1, min(t3 * nv / vh, t3 * nl / vh)) / (pi * nl * nv)
// Baked or unused parameters (folded into constants): n
// Inputs are cosines (clamped to [0, 1] here, as lobe does); the result is clamped at 0.
// lobe evaluates in f64; this runs in f32. GPU min/max need not propagate NaN, and
// pow(x, y) is undefined on GPUs for x < 0 or x = 0, y <= 0.
float lobe_cook_torrance(float NL, float NV, float NH, float VH, float m, float F0) {
    float t0 = clamp(NH, 0.0, 1.0);
    float t1 = (t0 * t0);
    float t2 = (m * m);
    float t3 = exp(((t1 - 1.0) / (t2 * t1)));
    float t4 = clamp(VH, 0.0, 1.0);
    float t5 = clamp(NL, 0.0, 1.0);
    float t6 = (2.0 * t0);
    float t7 = clamp(NV, 0.0, 1.0);
    float t8 = min(((t6 * t7) / t4), ((t6 * t5) / t4));
    float t9 = min(1.0, t8);
    float t10 = (1.0 - t4);
    float t11 = (t10 * t10);
    return ((((F0 + ((1.0 - F0) * ((t11 * t11) * t10))) * ((1.0 / (t2 * (t1 * t1))) * t3)) * t9) / ((3.1415927 * t5) * t7));
}
