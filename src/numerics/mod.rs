//! Numerical checks of a BRDF kernel: energy (normalisation and albedo), accuracy against a reference lobe,
//! a stability sweep over the whole domain, and a parameter fit; the ground truth ([`truth`]: any formula in
//! ~104-bit precision with an unbounded exponent, settled at more bits where its own error bound asks) and the accuracy pass's measurement and choice ([`robust`]);
//! a formula's value and gradient as one compiled multi-output kernel ([`grad`]).
//!
//! Design: every check takes a `&dyn Evaluator` plus a parameter slice (and, where needed, the formula's
//! parameter declarations or used-input set) — never source text — so the same code runs on the JIT, the
//! interpreter, or a hand-written Rust closure ([`twins`], used by the tests to pin the published numbers).
//!
//! # The lobe convention (shared by the lobe-mode energy check, accuracy and fit)
//! The papers treat a lobe as a function of one angle θ, `c = cos θ`, with the light at the normal. lobe maps
//! `c` to the five inputs as [`lobe_inputs`] does: **NL = 1** (light at the normal), **NV = c** (the
//! outgoing direction whose cosine weights the integral), **NH = VR = c** (whichever lobe variable the formula
//! reads sees the lobe angle; with L = N, VR = NV exactly, and NH = c is the papers' abstraction), and
//! **VH = cos(θ/2) = √((1+c)/2)** (L = N, V at θ). Because NH and VR are both set to `c`, the result does
//! not depend on which of the two a formula reads; [`choose_lobe_input`] still names it for reports.
//! The physically consistent alternative (NH = cos(θ/2) for a light at the normal) is what
//! the full-mode energy check measures at θᵢ = 0.
//!
//! # JSON keys (one object per check; stable)
//! Numbers follow [`crate::base::json`]: finite values are numbers, NaN and ±inf the strings `"NaN"`, `"inf"`,
//! `"-inf"`.
//! - `energy`: `mode` (`lobe` or `full`), `params`; lobe mode: `coef` (1/(2π·Int)), `integral`, `evals`,
//!   `lobe_input`; over a range of n: `range` = list of {`n`, `coef`} instead of `coef`/`integral`/`evals`; against
//!   a fitted coefficient: `against_max_abs` (max |coef_fit·2π·Int − 1|), `against_worst_n`, `against_mean_abs`; full
//!   mode: `coef` (= 1/`albedo_max`), `albedo_max`, `theta_i_at_max_deg`, `albedo` (list of {`theta_i_deg`,
//!   `rho`}), `reciprocity_max_rel`, `reciprocity_worst` ({`theta_l_deg`, `theta_v_deg`, `phi_v_deg`}).
//! - `accuracy`: `mean_abs_grid`, `epicenter_max_rel_pct` (+ `epicenter_worst_n`), `inflection_max_rel_pct`
//!   (+ `inflection_worst_n`), `max_abs` (+ `max_abs_n`, `max_abs_angle_deg`), `cutoff_max_rel_pct`
//!   (+ `cutoff_worst_n`, `cutoff_worst_angle_deg`), `lobe_ratio_min`, `lobe_ratio_max` (+ `_n`), `nan_points`,
//!   `q`, `seconds`.
//! - `fit`: `best` = list of {`params` (object name → value), `score`, `refined`}, best first; `metric`,
//!   `evaluated`, `refinement` (`levenberg-marquardt` or `derivative-free`), `lm` ({`starts`, `iterations`,
//!   `evaluations`}), `seconds`.
//! - `check` (accuracy report, [`robust`]): `bits_error_avg`, `bits_error_max`, `bits_error_worst` ({`inputs`,
//!   `params`, `value`, `truth`, `bits`}), `bits_error_max_well_conditioned`, `nonfinite_where_finite`,
//!   `ill_conditioned`, `undefined`, `limit_points` (points whose truth is a limit along an edge input), `before` (the same keys for the plain simplification), `accuracy_rewrites`
//!   (list of {`rule`, `kept`, `reason`, `cost_ratio`, `bits_error_avg`, `bits_error_max`,
//!   `nonfinite_where_finite`}), `compiled`, `cost_ratio`, `points`. `energy` lobe mode also gives
//!   `skipped_nan_up_to` and `skipped_bound` (null when nothing was skipped).
//! - `sweep`: `nan`, `inf`, `negative`, `over_bound` counts, `evaluated`, `exhaustive`, `bound`, `regions` =
//!   list of {`region`, `evaluated`, `nan`, `inf`, `negative`, `over_bound`, `first`} where `first` maps each
//!   kind to its first example ({`inputs`, `params`, `value`}) or `null`.
//!
//! # Cost
//! Every check is a count of formula evaluations, so the evaluator's time per evaluation sets its time (on
//! arithmetic formulas the JIT is roughly 10× faster than the interpreter per scalar call and 30–45× per
//! batched element):
//! - one exact coefficient ([`energy::normalization_coef`]): a few hundred to ~2 000 evaluations (adaptive
//!   GK15 over a ladder of breakpoints; 520–620 in the cases of `benches/energy.rs`);
//! - a whole accuracy report: the papers' grid (91 × 1000; the reference's rows once) and the fine grid
//!   (1 801 × 1000) for both formulas, plus ~100 scalar evaluations per n for the cut-offs — about 4 M;
//! - full-mode energy: 91 incidence angles, each a nested adaptive GK15 over the hemisphere, plus 8 664
//!   reciprocity pairs (two evaluations each);
//! - a fit: one mean-|Δ| score is 91 000 evaluations of the formula (the reference is evaluated once), times
//!   the number of grid candidates (141 for a ∈ 200..340, 1000 for a ∈ 1..1000), plus ~60 scores to refine.
//!
//! Measured times, on the JIT, the interpreter and the twins: BENCHMARKS.md.

pub mod accuracy;
pub mod check;
pub mod energy;
pub mod grad;
pub mod lm;
pub mod fit;
pub mod measured;
pub mod normalize;
pub mod points;
pub mod quad;
pub mod pass_cache;
pub mod robust;
pub mod sweep;
pub mod truth;
pub mod twins;

use crate::base::diag::Diagnostic;
use crate::ir::{Input, InputSet};

/// What to change after a numerical check fails, worded by each front end ([`crate::base::diag::Advice`]).
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum NumericsAdvice {
    /// Normalising needs every parameter given a fixed value.
    BakeEveryParam,
    /// A fit needs at least one parameter to vary, with its range.
    FitSomeParam,
    /// A range of n was asked with a step that is not a positive number.
    PositiveStep,
    /// The formula is NaN somewhere: the stability sweep ([`sweep`]) shows where.
    SweepForUndefined,
    /// The formula as written is NaN on a piece that matters: the accuracy pass ([`robust`]) may remove it.
    RunAccuracyPass,
}

impl crate::base::diag::Advice for NumericsAdvice {
    fn plain(&self) -> String {
        match self {
            NumericsAdvice::BakeEveryParam => "give every parameter a value before normalising",
            NumericsAdvice::FitSomeParam => "name at least one parameter to fit, with its range (e.g. a in 1..1000)",
            NumericsAdvice::PositiveStep => "give the range a positive step, e.g. 1",
            NumericsAdvice::SweepForUndefined => "sweep the formula over its domain to see where it is undefined",
            NumericsAdvice::RunAccuracyPass => "check the formula's accuracy: the accuracy pass may remove the NaN",
        }
        .into()
    }
}

/// The lobe variable of a formula reading `used`: NH or VR, whichever it reads. If it reads both or neither,
/// NH, with a note saying so (the value is the same under the lobe convention).
/// The lobe cosine of a formula that reads exactly one of NH and VR and nothing else (the papers' one-cosine
/// lobes): what lobe mode integrates, and what the sampler's exact path inverts.
pub fn one_lobe_cosine(used: InputSet) -> Option<Input> {
    [Input::NH, Input::VR].into_iter().find(|&c| used.len() == 1 && used.contains(c))
}

pub fn choose_lobe_input(used: InputSet) -> (Input, Option<String>) {
    match (used.contains(Input::NH), used.contains(Input::VR)) {
        (true, false) => (Input::NH, None),
        (false, true) => (Input::VR, None),
        (true, true) => (Input::NH, Some("the formula reads both NH and VR; both are set to cos θ (lobe variable: NH)".into())),
        (false, false) => (
            Input::NH,
            Some(format!(
                "the formula reads neither NH nor VR (it reads: {}); using NH = cos θ with NL = 1, NV = cos θ",
                if used.is_empty() { "nothing".to_string() } else { used.to_string() }
            )),
        ),
    }
}

pub use crate::frame::{inputs_from_dirs, V3};
pub(crate) use crate::frame::lobe_inputs;

pub(crate) fn dot(a: V3, b: V3) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// A unit direction from polar angle θ (from the normal, +z) and azimuth φ, both in radians.
pub fn dir(theta: f64, phi: f64) -> V3 {
    [theta.sin() * phi.cos(), theta.sin() * phi.sin(), theta.cos()]
}

/// A unit direction whose cosine with the normal is exactly `c` (so denormal and 1 − ulp cosines are reachable,
/// which polar angles are not) at azimuth `phi`.
pub(crate) fn dir_from_cos(c: f64, phi: f64) -> V3 {
    let s = (1.0 - c * c).max(0.0).sqrt();
    [s * phi.cos(), s * phi.sin(), c]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn geometry_matches_the_lobe_convention_at_the_normal() {
        // Light at the normal, V at θ: VR = NV = cos θ, NH = VH = cos(θ/2).
        let t: f64 = 0.7;
        let x = inputs_from_dirs([0.0, 0.0, 1.0], dir(t, 0.3));
        assert!((x[0] - 1.0).abs() < 1e-15);
        assert!((x[1] - t.cos()).abs() < 1e-15 && (x[3] - t.cos()).abs() < 1e-15);
        assert!((x[2] - (t / 2.0).cos()).abs() < 1e-15 && (x[4] - (t / 2.0).cos()).abs() < 1e-15);
        let y = lobe_inputs(t.cos(), Input::NH);
        assert_eq!((y[0], y[1], y[3]), (1.0, t.cos(), t.cos()));
        assert!((y[4] - x[4]).abs() < 1e-15);
    }

    #[test]
    fn vr_is_symmetric_in_l_and_v() {
        let l = dir(0.4, 0.0);
        let v = dir(1.1, 2.0);
        let a = inputs_from_dirs(l, v);
        let b = inputs_from_dirs(v, l);
        assert!((a[3] - b[3]).abs() < 1e-15 && (a[2] - b[2]).abs() < 1e-15 && (a[4] - b[4]).abs() < 1e-15);
    }
}
