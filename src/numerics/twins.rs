//! Hand-written Rust twins of the catalogue formulas (`examples/brdfs`, as the papers publish them), as
//! evaluators: the one place they are written (unit tests, integration tests, `lobe bench` and the benches all
//! take them from here).
//!
//! Each twin computes the same function as its catalogue file `examples/brdfs/<stem>.brdf` compiled by lobe
//! (`tests/it/differential.rs` checks JIT = interpreter = twin): the lowering's domain policy — inputs
//! clamped to [0, 1], result `max(raw, 0)`, NaN-propagating — and every `max(…, 0)` the file writes (F_ST,
//! F_SCOS, F_SCOS2 clamp the base of their power at 0 so that the lobe stays zero beyond its zero). Inputs
//! arrive as [NL, NV, NH, VR, VH]; parameters in the file's declaration order (`n` first).

use crate::backend::{Evaluator, FnEvaluator};
use crate::builtins::fmax;
use crate::N_INPUTS;

const NH: usize = 2;
const VR: usize = 3;

fn c(x: &[f64; N_INPUTS], i: usize) -> f64 {
    crate::builtins::clamp(x[i], 0.0, 1.0)
}
fn out(v: f64) -> f64 {
    fmax(v, 0.0)
}

/// A twin as a plain function (what the benches call directly).
pub type TwinFn = fn(&[f64; N_INPUTS], &[f64]) -> f64;

/// A boxed evaluator with a name, parameter names and defaults (n first).
pub struct Twin {
    pub name: &'static str,
    pub params: &'static [&'static str],
    pub defaults: Vec<f64>,
    pub ev: Box<dyn Evaluator>,
}

/// One twin as data: the catalogue file it mirrors, its display name, its parameters and the function.
pub struct Def {
    /// `examples/brdfs/<stem>.brdf`.
    pub stem: &'static str,
    pub name: &'static str,
    /// Parameter names in the file's declaration order, and their defaults.
    pub params: &'static [&'static str],
    pub defaults: &'static [f64],
    pub f: TwinFn,
}

impl Def {
    /// The twin behind the `Evaluator` interface.
    pub(crate) fn twin(&self) -> Twin {
        Twin { name: self.name, params: self.params, defaults: self.defaults.to_vec(), ev: Box::new(FnEvaluator(self.f)) }
    }
}

/// A twin with the one parameter n (default 50, as the front end declares it).
const fn n_only(stem: &'static str, name: &'static str, f: TwinFn) -> Def {
    Def { stem, name, params: &["n"], defaults: &[50.0], f }
}

/// `lobe!(NH, |c, n| body)`: the twin function `out(body)` with c the clamped input and n the first parameter.
macro_rules! lobe {
    ($input:ident, |$c:ident, $n:ident| $body:expr) => {
        |x: &[f64; N_INPUTS], p: &[f64]| {
            let ($c, $n) = (c(x, $input), p[0]);
            out($body)
        }
    };
}

/// Phong (1.4): VR^n.
pub(crate) const PHONG: Def = n_only("phong", "Phong", lobe!(VR, |c, n| c.powf(n)));
/// Blinn (1.5): NH^n — the usual reference.
pub(crate) const BLINN: Def = n_only("blinn", "Blinn", lobe!(NH, |c, n| c.powf(n)));
/// Schlick (1.6): c / (n − n·c + c).
pub(crate) const SCHLICK: Def = n_only("schlick", "Schlick", lobe!(NH, |c, n| c / (n - n * c + c)));
/// Modified Schlick F_MSH (2.3): 2c / (1.25·(n − n·c + 1.25c)²).
pub(crate) const MODIFIED_SCHLICK: Def = n_only("modified_schlick", "Modified Schlick", lobe!(NH, |c, n| {
    let d = n - n * c + 1.25 * c;
    2.0 * c / (1.25 * d * d)
}));
/// F_dsh (2.26), as written in models.md:
/// c/(n − n c + c) + ( 2(c + 0.1)^8 / (1.25(1.25n − 1.25 n c + 1.25 c^8)² + 1.5) − 0.25 ).
pub(crate) const DSH: Def = n_only("dsh", "F_dsh", lobe!(NH, |c, n| {
    let d = 1.25 * n - 1.25 * n * c + 1.25 * c.powi(8);
    c / (n - n * c + c) + (2.0 * (c + 0.1).powi(8) / (1.25 * d * d + 1.5) - 0.25)
}));
/// F_SCOS (3.1): max(n/2·(c − 1) + 1, 0)², zero beyond acos((n−2)/n).
pub(crate) const SCOS: Def = n_only("scos", "F_SCOS", lobe!(NH, |c, n| fmax(n / 2.0 * (c - 1.0) + 1.0, 0.0).powi(2)));
/// F_SCOS2 (3.10): max((−1.1/(−n + n c − 2c))·n·(c − 1) + 1, 0)², zero beyond acos(n/(n+20)).
pub(crate) const SCOS2: Def =
    n_only("scos2", "F_SCOS2", lobe!(NH, |c, n| fmax((-1.1 / (-n + n * c - 2.0 * c)) * n * (c - 1.0) + 1.0, 0.0).powi(2)));
/// Quadratic (3.18): 0.786n·c² + (1 − 0.786n)·c.
pub(crate) const QUADRATIC: Def = n_only("quadratic", "Quadratic", lobe!(NH, |c, n| 0.786 * n * c * c + (1.0 - 0.786 * n) * c));
/// Gaussian (1.7): exp(−n·acos(c)²/2).
pub(crate) const GAUSSIAN: Def = n_only("gaussian", "Gaussian", lobe!(NH, |c, n| (-n * c.acos().powi(2) / 2.0).exp()));
/// F_ST (3.15): max(n/a·(c − 1) + 1, 0)^a; parameters n, a.
pub(crate) const F_ST: Def = Def {
    stem: "fst",
    name: "F_ST",
    params: &["n", "a"],
    defaults: &[50.0, 16.0],
    f: |x, p| {
        let (c, n, a) = (c(x, NH), p[0], p[1]);
        out(fmax(n / a * (c - 1.0) + 1.0, 0.0).powf(a))
    },
};
/// F_kutlog (article): cos^k(acos(Q^(1/k)) / acos(Q^(1/n)) · x), x = acos(NH), zero where the argument
/// passes π/2; parameters n, k, Q.
pub(crate) const KUTLOG: Def = Def {
    stem: "kutlog",
    name: "F_kutlog",
    params: &["n", "k", "Q"],
    defaults: &[50.0, 1.0, 0.5],
    f: |x, p| {
        let (c, n, k, q) = (c(x, NH), p[0], p[1], p[2]);
        let arg = (q.powf(1.0 / k)).acos() / (q.powf(1.0 / n)).acos() * c.acos();
        if arg >= std::f64::consts::FRAC_PI_2 {
            0.0
        } else {
            out(arg.cos().powf(k))
        }
    },
};

/// Every twin, in catalogue order.
pub const DEFS: &[Def] = &[PHONG, BLINN, SCHLICK, MODIFIED_SCHLICK, DSH, SCOS, SCOS2, F_ST, QUADRATIC, GAUSSIAN, KUTLOG];

/// `pub fn phong() -> Twin` from `phong = PHONG`: the constructors callers use (`fn() -> Twin` values).
macro_rules! constructors {
    ($($f:ident = $def:ident),* $(,)?) => {
        $(
            #[doc = concat!("The twin [`", stringify!($def), "`].")]
            pub fn $f() -> Twin {
                $def.twin()
            }
        )*
    };
}

constructors! {
    phong = PHONG, blinn = BLINN, schlick = SCHLICK, modified_schlick = MODIFIED_SCHLICK, dsh = DSH, scos = SCOS,
    scos2 = SCOS2, f_st = F_ST, quadratic = QUADRATIC, gaussian = GAUSSIAN, kutlog = KUTLOG,
}

/// The definition of a catalogue file's twin (`examples/brdfs/<stem>.brdf`), if there is one.
pub fn def(stem: &str) -> Option<&'static Def> {
    DEFS.iter().find(|d| d.stem == stem)
}

/// The twin of a catalogue file (`examples/brdfs/<stem>.brdf`), if there is one; its parameters are in the
/// file's declaration order, so a kernel's parameter vector can be passed to it unchanged.
pub fn by_stem(stem: &str) -> Option<Twin> {
    def(stem).map(Def::twin)
}
