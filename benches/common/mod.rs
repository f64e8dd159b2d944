//! The benched catalogue: the formulas of `formulas.rs`, each compiled from its catalogue file
//! (`examples/brdfs/<stem>.brdf`) exactly as shipped, with its hand-written Rust twin from
//! `lobe::numerics::twins` (the same function: input clamps, `max(…, 0)`, NaN propagation).
#![allow(dead_code)]

pub mod formulas;

pub use formulas::{Benched, BENCHED};
use lobe::numerics::twins::{self, TwinFn};
use lobe::{Backend, Kernel};
use std::sync::Arc;

impl Benched {
    /// The Rust twin as a plain function.
    pub fn twin(&self) -> TwinFn {
        twins::def(self.stem).unwrap_or_else(|| panic!("{}: no Rust twin in lobe::numerics::twins", self.stem)).f
    }

    /// The Rust twin behind the same `Evaluator` interface as the JIT (same dispatch cost).
    pub fn twin_kernel(&self, like: &Kernel) -> Kernel {
        let ev = Arc::new(lobe::backend::FnEvaluator(self.twin()));
        Kernel::new(like.formula.clone(), Backend::Interp, lobe::Mode::Precise, ev, Default::default())
    }
}
