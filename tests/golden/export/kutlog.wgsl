// F_kutlog — exported by lobe VERSION as WGSL.
// Source: Article “Energy-correct reflectance model based on the angle between vectors”, 2023
// Formula (simplified): max(pow(sin(max(1.5707963267948966 - acos(pow(Q, 1 / k)) / acos(pow(Q, 0.01)) * acos(clamp(NH, 0, 1)), 0)), k), 0)
// Baked or unused parameters (folded into constants): n
// Inputs are cosines (clamped to [0, 1] here, as lobe does); the result is clamped at 0.
// lobe evaluates in f64; this runs in f32. GPU min/max need not propagate NaN, and
// pow(x, y) is undefined on GPUs for x < 0 or x = 0, y <= 0.
fn lobe_kutlog(NH: f32, k: f32, Q: f32) -> f32 {
    let t0: f32 = clamp(NH, 0.0, 1.0);
    let t1: f32 = acos(clamp(t0, -1.0, 1.0));
    let t2: f32 = pow(Q, 0.01);
    let t3: f32 = acos(clamp(t2, -1.0, 1.0));
    let t4: f32 = pow(Q, (1.0 / k));
    let t5: f32 = acos(clamp(t4, -1.0, 1.0));
    let t6: f32 = max((1.5707964 - ((t5 / t3) * t1)), 0.0);
    let t7: f32 = sin(t6);
    let t8: f32 = pow(t7, k);
    return max(t8, 0.0);
}
