//! Energy normalisation: F → coef·F with the papers' exact coefficient `1/(2π·Int)` (lobe convention, the
//! lobe variable chosen from the inputs the formula reads). [`coefficient`] is the one place it is computed:
//! scene materials keep it beside their kernel and multiply at shading time; evaluating a normalised formula bakes it into
//! the IR with [`bake_coefficient`]. Cost: one adaptive quadrature, a few hundred evaluations.

use super::{choose_lobe_input, energy, Diagnostic};
use crate::backend::interp::Interp;
use crate::backend::Evaluator;
use crate::ir::{BinOp, Formula, InputSet};

/// The exact normalisation coefficient of a kernel reading `used`, at `params`.
/// A lobe whose integral is so small that `1/(2π·Int)` overflows (e.g. `NH^n * 1e-310`) is refused rather
/// than normalised to infinity.
pub(crate) fn coefficient(ev: &dyn Evaluator, used: InputSet, params: &[f64]) -> Result<f64, Diagnostic> {
    let (lobe, _) = choose_lobe_input(used);
    let coef = energy::normalization_coef(ev, params, lobe)?;
    if !coef.is_finite() {
        return Err(Diagnostic::error(format!("the lobe integral is too small to normalise: 1/(2π·Int) overflows double precision ({coef})"))
            .hint("the formula is scaled by a tiny constant; drop the constant (normalisation removes any scale anyway)"));
    }
    Ok(coef)
}

/// `coef · f`, simplified, for a formula whose parameters are all baked (the coefficient depends on every
/// parameter, so a live one would make the baked constant wrong). Evaluated on the reference interpreter.
pub fn bake_coefficient(f: Formula) -> Result<Formula, Diagnostic> {
    let live: Vec<&str> = f.ir.used_params(f.root).iter().map(|&i| f.params[i as usize].name.as_str()).collect();
    if !live.is_empty() {
        return Err(Diagnostic::error(format!("cannot normalise {}: parameter(s) {} are not baked", f.display_name(), live.join(", ")))
            .hint(super::NumericsAdvice::BakeEveryParam));
    }
    let coef = coefficient(&Interp::new(&f), f.used_inputs(), &f.default_params())
        .map_err(|e| Diagnostic { message: format!("cannot normalise {}: {}", f.display_name(), e.message), ..e })?;
    let mut g = f;
    let span = g.ir.span(g.root);
    let c = g.ir.konst(coef, span);
    g.root = g.ir.bin(BinOp::Mul, c, g.root, span);
    Ok(crate::simplify::simplify(&g, &[]))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::backend::FnEvaluator;
    use crate::ir::Input;

    #[test]
    fn phong_coefficient_is_n_plus_2_over_2pi() {
        let ev = FnEvaluator(|x: &[f64; crate::N_INPUTS], p: &[f64]| x[3].clamp(0.0, 1.0).powf(p[0]));
        let mut vr = InputSet::default();
        vr.insert(Input::VR);
        for n in [1.0, 10.0, 100.0] {
            let c = coefficient(&ev, vr, &[n]).unwrap();
            let exact = (n + 2.0) / (2.0 * std::f64::consts::PI);
            assert!((c - exact).abs() / exact < 1e-6, "{n}: {c} vs {exact}");
        }
        assert!(coefficient(&FnEvaluator(|_: &[f64; crate::N_INPUTS], _: &[f64]| 0.0), vr, &[1.0]).is_err());
        let tiny = FnEvaluator(|x: &[f64; crate::N_INPUTS], p: &[f64]| x[3].clamp(0.0, 1.0).powf(p[0]) * 1e-300 * 1e-10);
        assert!(coefficient(&tiny, vr, &[50.0]).unwrap_err().message.contains("overflows"));
    }
}
