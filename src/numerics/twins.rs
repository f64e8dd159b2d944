//! Hand-written Rust twins of the catalogue formulas (../shared/models.md), as evaluators.
//!
//! They follow the lowering's domain policy — inputs clamped to [0, 1], result `max(raw, 0)` — so they agree
//! with a compiled .brdf of the same formula. Used by the unit tests (which pin the published numbers),
//! integration tests and benches; inputs arrive as [NL, NV, NH, VR, VH]. Where a paper's formula must be
//! clamped before a power to mean what the paper plots (F_ST, F_SCOS, F_SCOS2 beyond their zero), the twin
//! clamps the base at 0, and says so.

use crate::backend::{Evaluator, FnEvaluator};
use crate::N_INPUTS;

const NH: usize = 2;
const VR: usize = 3;

fn c(x: &[f64; N_INPUTS], i: usize) -> f64 {
    crate::builtins::clamp(x[i], 0.0, 1.0)
}
fn out(v: f64) -> f64 {
    crate::builtins::fmax(v, 0.0)
}

/// A boxed evaluator with a name, parameter names and defaults (n first).
pub struct Twin {
    pub name: &'static str,
    pub params: &'static [&'static str],
    pub defaults: Vec<f64>,
    pub ev: Box<dyn Evaluator>,
}

fn twin<F: Fn(&[f64; N_INPUTS], &[f64]) -> f64 + Send + Sync + 'static>(
    name: &'static str,
    params: &'static [&'static str],
    defaults: Vec<f64>,
    f: F,
) -> Twin {
    Twin { name, params, defaults, ev: Box::new(FnEvaluator(f)) }
}

/// Phong (1.4): VR^n.
pub fn phong() -> Twin {
    twin("Phong", &["n"], vec![50.0], |x, p| out(c(x, VR).powf(p[0])))
}
/// Blinn (1.5): NH^n — the usual reference.
pub fn blinn() -> Twin {
    twin("Blinn", &["n"], vec![50.0], |x, p| out(c(x, NH).powf(p[0])))
}
/// Schlick (1.6): c / (n − n·c + c).
pub fn schlick() -> Twin {
    twin("Schlick", &["n"], vec![50.0], |x, p| {
        let (c, n) = (c(x, NH), p[0]);
        out(c / (n - n * c + c))
    })
}
/// Modified Schlick F_MSH (2.3): 2c / (1.25·(n − n·c + 1.25c)²).
pub fn modified_schlick() -> Twin {
    twin("Modified Schlick", &["n"], vec![50.0], |x, p| {
        let (c, n) = (c(x, NH), p[0]);
        let d = n - n * c + 1.25 * c;
        out(2.0 * c / (1.25 * d * d))
    })
}
/// F_dsh (2.26), as written in models.md:
/// c/(n − n c + c) + ( 2(c + 0.1)^8 / (1.25(1.25n − 1.25 n c + 1.25 c^8)² + 1.5) − 0.25 ).
pub fn dsh() -> Twin {
    twin("F_dsh", &["n"], vec![50.0], |x, p| {
        let (c, n) = (c(x, NH), p[0]);
        let d = 1.25 * n - 1.25 * n * c + 1.25 * c.powi(8);
        out(c / (n - n * c + c) + (2.0 * (c + 0.1).powi(8) / (1.25 * d * d + 1.5) - 0.25))
    })
}
/// F_SCOS (3.1): (n/2·(c − 1) + 1)², zero beyond acos((n−2)/n) (the base is clamped at 0).
pub fn scos() -> Twin {
    twin("F_SCOS", &["n"], vec![50.0], |x, p| {
        let (c, n) = (c(x, NH), p[0]);
        let b = (n / 2.0 * (c - 1.0) + 1.0).max(0.0);
        out(b * b)
    })
}
/// F_SCOS2 (3.10): ((−1.1/(−n + n c − 2c))·n·(c − 1) + 1)², zero beyond acos(n/(n+20)) (base clamped at 0).
pub fn scos2() -> Twin {
    twin("F_SCOS2", &["n"], vec![50.0], |x, p| {
        let (c, n) = (c(x, NH), p[0]);
        let b = ((-1.1 / (-n + n * c - 2.0 * c)) * n * (c - 1.0) + 1.0).max(0.0);
        out(b * b)
    })
}
/// F_ST (3.15): max(n/a·(c − 1) + 1, 0)^a; parameters n, a.
pub fn f_st() -> Twin {
    twin("F_ST", &["n", "a"], vec![50.0, 16.0], |x, p| {
        let (c, n, a) = (c(x, NH), p[0], p[1]);
        out((n / a * (c - 1.0) + 1.0).max(0.0).powf(a))
    })
}
/// Quadratic (3.18): 0.786n·c² + (1 − 0.786n)·c.
pub fn quadratic() -> Twin {
    twin("Quadratic", &["n"], vec![50.0], |x, p| {
        let (c, n) = (c(x, NH), p[0]);
        out(0.786 * n * c * c + (1.0 - 0.786 * n) * c)
    })
}
/// F_kutlog (article): cos^k(acos(Q^(1/k)) / acos(Q^(1/n)) · x), x = acos(NH), zero where the argument
/// passes π/2; parameters n, k, Q.
pub fn kutlog() -> Twin {
    twin("F_kutlog", &["n", "k", "Q"], vec![50.0, 1.0, 0.5], |x, p| {
        let (c, n, k, q) = (c(x, NH), p[0], p[1], p[2]);
        let arg = (q.powf(1.0 / k)).acos() / (q.powf(1.0 / n)).acos() * c.acos();
        if arg >= std::f64::consts::FRAC_PI_2 {
            0.0
        } else {
            out(arg.cos().powf(k))
        }
    })
}

/// Every twin, for table-driven tests.
pub fn all() -> Vec<Twin> {
    vec![phong(), blinn(), schlick(), modified_schlick(), dsh(), scos(), scos2(), f_st(), quadratic(), kutlog()]
}

/// The twin of a catalogue file (`examples/brdfs/<stem>.brdf`), if there is one; its parameters are in the
/// file's declaration order, so a kernel's parameter vector can be passed to it unchanged.
pub fn by_stem(stem: &str) -> Option<Twin> {
    Some(match stem {
        "phong" => phong(),
        "blinn" => blinn(),
        "schlick" => schlick(),
        "modified_schlick" => modified_schlick(),
        "dsh" => dsh(),
        "scos" => scos(),
        "scos2" => scos2(),
        "fst" => f_st(),
        "quadratic" => quadratic(),
        "kutlog" => kutlog(),
        _ => return None,
    })
}
