//! Hand-written Rust twins of catalogue formulas: what a person would write instead of using lobe.
//!
//! They are the "native Rust" column of `lobe bench` and benches/eval.rs, and an independent check on the
//! catalogue files in tests. Each follows lobe's domain policy exactly as a careful hand-written shader would:
//! inputs clamped to [0, 1], result clamped at 0, integer powers as `powi` (which LLVM turns into
//! multiplications, as lobe's simplifier does). The exponent `n` is a runtime argument, as in a material
//! system: the JIT kernel it is compared with has `n` baked, which is lobe's advantage to show, not hide.

use crate::ir::N_INPUTS;

/// A twin: inputs in (NL, NV, NH, VR, VH) order, parameters in the .brdf file's declaration order.
pub type TwinFn = fn(&[f64; N_INPUTS], &[f64]) -> f64;

#[inline(always)]
fn c01(x: f64) -> f64 {
    x.clamp(0.0, 1.0)
}

#[inline(always)]
fn out(x: f64) -> f64 {
    // NaN stays NaN (as lobe's NaN-propagating max does).
    if x < 0.0 {
        0.0
    } else {
        x
    }
}

pub fn phong(x: &[f64; N_INPUTS], p: &[f64]) -> f64 {
    out(c01(x[3]).powf(p[0]))
}
pub fn blinn(x: &[f64; N_INPUTS], p: &[f64]) -> f64 {
    out(c01(x[2]).powf(p[0]))
}
pub fn schlick(x: &[f64; N_INPUTS], p: &[f64]) -> f64 {
    let (c, n) = (c01(x[2]), p[0]);
    out(c / (n - n * c + c))
}
pub fn modified_schlick(x: &[f64; N_INPUTS], p: &[f64]) -> f64 {
    let (c, n) = (c01(x[2]), p[0]);
    let d = n - n * c + 1.25 * c;
    out(2.0 * c / (1.25 * d * d))
}
pub fn gaussian(x: &[f64; N_INPUTS], p: &[f64]) -> f64 {
    let a = c01(x[2]).acos();
    out((-p[0] * a * a / 2.0).exp())
}
pub fn scos2(x: &[f64; N_INPUTS], p: &[f64]) -> f64 {
    let (c, n) = (c01(x[2]), p[0]);
    let b = ((-1.1 / (-n + n * c - 2.0 * c)) * n * (c - 1.0) + 1.0).max(0.0);
    out(b * b)
}
/// F_ST with parameters (n, a); `a` is rounded to an integer power, as the catalogue uses it.
pub fn fst(x: &[f64; N_INPUTS], p: &[f64]) -> f64 {
    let (c, n, a) = (c01(x[2]), p[0], p[1]);
    out((n / a * (c - 1.0) + 1.0).max(0.0).powi(a as i32))
}
pub fn quadratic(x: &[f64; N_INPUTS], p: &[f64]) -> f64 {
    let (c, n) = (c01(x[2]), p[0]);
    out(0.786 * n * c * c + (1.0 - 0.786 * n) * c)
}

/// The twin for a catalogue file stem, if lobe has one.
pub fn twin(stem: &str) -> Option<TwinFn> {
    Some(match stem {
        "phong" => phong,
        "blinn" => blinn,
        "schlick" => schlick,
        "modified_schlick" => modified_schlick,
        "gaussian" => gaussian,
        "scos2" => scos2,
        "fst" => fst,
        "quadratic" => quadratic,
        _ => return None,
    })
}

#[cfg(test)]
mod tests {
    #[test]
    fn twins_follow_the_domain_policy() {
        let x = [0.0, 0.0, 1.5, -0.5, 0.0];
        assert_eq!(super::blinn(&x, &[10.0]), 1.0);
        assert_eq!(super::phong(&x, &[10.0]), 0.0);
        assert_eq!(super::quadratic(&[0.0, 0.0, 0.1, 0.0, 0.0], &[100.0]), 0.0);
        assert!(super::twin("kutlog").is_none());
    }
}
