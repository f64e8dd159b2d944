//! The power family: integer powers above 8 as pow calls or as compensated multiplication chains, and the
//! baked pass's live choice (described in [`super`]).

#[cfg(doc)]
use super::chain::{compensated_powers, pow_call_policy};
use super::rule::{Example, Rule, Sites, Source};
use crate::ir::Formula;
use crate::simplify::rewrite::Analysis;

/// `pow-call` (module docs): the source simplified with [`pow_call_policy`].
pub(crate) struct PowCall;

impl Rule for PowCall {
    fn name(&self) -> &'static str {
        "pow-call"
    }
    fn doc(&self) -> &'static str {
        "integer powers above 8 as pow calls instead of multiplication chains"
    }
    fn sites(&self) -> Sites {
        Sites::Whole
    }
    fn apply(&self, src: &Source, a: &Analysis, _: Option<usize>) -> Option<Formula> {
        let p = src.pow_call();
        (super::rule::identity(p) != super::rule::identity(&a.f)).then(|| p.clone())
    }
    fn example(&self) -> Example {
        Example { before: "NH^n", bake: &[(0, 1000.0)], site: None, shows: "pow(" }
    }
    fn early(&self, _: &Analysis) -> bool {
        true
    }
}

/// `compensated-power` (module docs): [`compensated_powers`] of the source's pow calls.
pub(crate) struct CompensatedPower;

impl Rule for CompensatedPower {
    fn name(&self) -> &'static str {
        "compensated-power"
    }
    fn doc(&self) -> &'static str {
        "integer powers above 8 as compensated multiplication chains (fma error terms)"
    }
    fn sites(&self) -> Sites {
        Sites::Whole
    }
    fn apply(&self, src: &Source, _: &Analysis, _: Option<usize>) -> Option<Formula> {
        src.compensated().cloned()
    }
    fn example(&self) -> Example {
        Example { before: "NH^n", bake: &[(0, 1000.0)], site: None, shows: "fma(" }
    }
    fn early(&self, _: &Analysis) -> bool {
        true
    }
    fn replaces_pow_calls(&self) -> bool {
        true
    }
}

/// `live-choice` (module docs): the baked pass's first trial, the source (the live decision) with the values
/// baked, integer powers above 8 kept as pow calls under the accuracy preference (the live kernel calls pow),
/// as the simplifier chains them under the speed preference.
pub(crate) struct LiveChoice;

impl Rule for LiveChoice {
    fn name(&self) -> &'static str {
        "live-choice"
    }
    fn doc(&self) -> &'static str {
        "the rewrites chosen with every parameter live, the baked values folded into them: baked and live kernels agree"
    }
    fn sites(&self) -> Sites {
        Sites::Baked
    }
    fn apply(&self, src: &Source, _: &Analysis, _: Option<usize>) -> Option<Formula> {
        Some(if src.pow_calls() { src.pow_call().clone() } else { crate::simplify::simplify(src.src(), src.bake()) })
    }
    fn example(&self) -> Example {
        Example { before: "NH^n", bake: &[(0, 1000.0)], site: None, shows: "pow(" }
    }
}
