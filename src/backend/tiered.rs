//! Automatic tiering (the `auto` tier, an LLVM build's default): a kernel compiled by Cranelift first, which LLVM
//! takes over from at the first batch of [`AUTO_LLVM_POINTS`] points or more, as JVMs and Julia promote hot code
//! to their optimising compiler. The decision is the batch's size, not a running count, so the tier a command
//! runs on does not depend on how often it was timed.
//!
//! Why batch size: the LLVM tier's kernels are 1.1–5× faster per element and cost 7–72 ms more to
//! compile than Cranelift's 0.5–9 ms (BENCHMARKS.md, the LLVM tier against Cranelift). One evaluation, or a few
//! hundred, is over before LLVM has compiled; a long batch, a fit, a sweep or a sampler's tables evaluate
//! millions. The two tiers give the same bits (the differential tests), so the switch changes no value, only the
//! time. Per-point calls ([`Evaluator::eval`], [`Evaluator::prepare`]) stay on the tier running at the time:
//! Cranelift until the switch, LLVM after it. If LLVM fails to compile the formula (a host it cannot target),
//! the kernel stays on Cranelift.

use super::{Backend, Columns, Evaluator, Prepared};
use crate::builtins::Mode;
use crate::ir::{Formula, N_INPUTS};
use std::sync::{Arc, OnceLock};

/// Batched evaluations after which a kernel moves to the LLVM tier.
pub const AUTO_LLVM_POINTS: usize = 4096;

/// A Cranelift kernel that LLVM takes over from (module docs).
pub(crate) struct Tiered {
    first: Arc<dyn Evaluator>,
    formula: Arc<Formula>,
    math: Mode,
    /// The LLVM kernel once compiled (`None` inside: LLVM could not compile it).
    second: OnceLock<Option<Arc<dyn Evaluator>>>,
}

impl Tiered {
    pub(crate) fn new(first: Arc<dyn Evaluator>, formula: Arc<Formula>, math: Mode) -> Tiered {
        Tiered { first, formula, math, second: OnceLock::new() }
    }

    /// The LLVM kernel if it has been compiled.
    fn promoted(&self) -> Option<&Arc<dyn Evaluator>> {
        self.second.get().and_then(Option::as_ref)
    }

    /// The evaluator for a batch of `n`: LLVM from the first batch of [`AUTO_LLVM_POINTS`] (compiled then, once).
    fn for_batch(&self, n: usize) -> &Arc<dyn Evaluator> {
        if let Some(s) = self.promoted() {
            return s;
        }
        if n >= AUTO_LLVM_POINTS {
            if let Some(s) = self.second.get_or_init(|| super::llvm::llvm_kernel(&self.formula, self.math).ok().map(|k| Arc::new(k) as Arc<dyn Evaluator>)) {
                return s;
            }
        }
        &self.first
    }

    /// The tier that evaluates now.
    fn current(&self) -> &Arc<dyn Evaluator> {
        self.promoted().unwrap_or(&self.first)
    }
}

impl Evaluator for Tiered {
    fn eval(&self, x: &[f64; N_INPUTS], params: &[f64]) -> f64 {
        self.current().eval(x, params)
    }

    fn prepare(&self, params: &[f64]) -> Prepared<'_> {
        self.current().prepare(params)
    }

    /// Warms the tier running now (a batch that promotes the kernel warms LLVM's as it compiles it).
    fn warm_up(&self) {
        self.current().warm_up()
    }

    fn eval_batch(&self, cols: &Columns, params: &[f64], out: &mut [f64]) {
        self.for_batch(out.len()).eval_batch(cols, params, out)
    }

    fn ran_on(&self) -> Option<Backend> {
        Some(if self.promoted().is_some() { Backend::Llvm } else { Backend::Jit })
    }
}
