//! What the renderer and the numerical checks call: a compiled formula behind one interface.
//!
//! A [`Kernel`] owns the simplified [`Formula`] and an [`Evaluator`] (the interpreter or JIT code). Inputs are
//! passed as `[f64; N_INPUTS]` in [`Input::ALL`] order (NL, NV, NH, VR, VH) and parameters as a slice in
//! declaration order (`n` first). Baked parameters are already constants in the IR; their slots in the slice
//! are ignored, so callers can always pass the full parameter vector.
//!
//! Loops over many points with one parameter set bind the parameters first ([`Evaluator::prepare`] →
//! [`Prepared`]): the per-call length check, the native code's block lookup and the `dyn` hop are then paid
//! once.
//!
//! The checks are written against [`Evaluator`], not `Kernel`, so they can also run on a plain Rust closure
//! (the hand-written twins used in tests and benches).

use crate::builtins::Mode;
use super::Backend;
use crate::ir::{Formula, Input, InputSet, N_INPUTS};
use std::sync::Arc;
use std::time::Duration;

/// Structure-of-arrays inputs for a batch: one column per input, in [`Input::ALL`] order. Columns of inputs the
/// formula does not read may be empty; the others must all have the length of the output.
#[derive(Clone, Copy, Debug)]
pub struct Columns<'a> {
    pub cols: [&'a [f64]; N_INPUTS],
}

impl<'a> Columns<'a> {
    pub fn new(cols: [&'a [f64]; N_INPUTS]) -> Columns<'a> {
        Columns { cols }
    }
    pub(crate) fn col(&self, i: Input) -> &'a [f64] {
        self.cols[i.index()]
    }
}

/// Any evaluator as `&dyn Evaluator` (lets [`Evaluator::prepare`]'s default keep `self` without `Self: Sized`).
pub trait AsEvaluator {
    fn as_evaluator(&self) -> &dyn Evaluator;
}

impl<T: Evaluator> AsEvaluator for T {
    fn as_evaluator(&self) -> &dyn Evaluator {
        self
    }
}

/// Anything that evaluates a BRDF: the interpreter, JIT code, or a Rust closure.
pub trait Evaluator: AsEvaluator + Send + Sync {
    /// One evaluation. `x` holds the cosines (NL, NV, NH, VR, VH), `params` the parameter values.
    fn eval(&self, x: &[f64; N_INPUTS], params: &[f64]) -> f64;

    /// Binds `params` for many [`Prepared::eval`] calls: what `eval` redoes per call (length checks, the
    /// JIT's prepared parameter block) is done here once. Same results as `eval`, bit for bit. The default
    /// keeps the parameters and calls `eval`.
    fn prepare(&self, params: &[f64]) -> Prepared<'_> {
        Prepared::Other(self.as_evaluator(), params.to_vec())
    }

    /// Builds whatever the first batch call would build lazily (the JIT's batched kernel), so that timing a
    /// batch measures evaluation only. The default does nothing.
    fn warm_up(&self) {}

    /// The JIT tier that ran this evaluator's batches so far when it chooses one itself (automatic tiering);
    /// `None` for every other evaluator (its kernel's backend says).
    fn ran_on(&self) -> Option<super::Backend> {
        None
    }

    /// A batch: `out[i] = f(cols[..][i])`. The default loops over [`Evaluator::eval`].
    fn eval_batch(&self, cols: &Columns, params: &[f64], out: &mut [f64]) {
        let mut x = [0.0; N_INPUTS];
        for (i, o) in out.iter_mut().enumerate() {
            for (k, c) in cols.cols.iter().enumerate() {
                x[k] = c.get(i).copied().unwrap_or(0.0);
            }
            *o = self.eval(&x, params);
        }
    }
}

/// An evaluator bound to one parameter vector (from [`Evaluator::prepare`]), for loops over many points with
/// the same parameters. Dispatch is a `match` on three shapes, not a `dyn` call: native code (either JIT tier:
/// the generated code called directly with its prepared block, no per-call cache lookup), the interpreter, or
/// any other evaluator. Not `Sync` (the interpreter's scratch): prepare one per thread.
pub enum Prepared<'a> {
    Native(super::native::NativeCall<'a>),
    Interp(super::interp::PreparedInterp<'a>),
    /// Any other evaluator (closures, wrappers): its `eval` with the kept parameters.
    Other(&'a dyn Evaluator, Vec<f64>),
}

impl Prepared<'_> {
    /// Always inlined: the `match` belongs in the caller's loop (left to the optimiser, whether it was inlined
    /// varied between builds of the same source and moved the cheapest formulas' call by ~0.5 ns).
    #[inline(always)]
    pub fn eval(&self, x: &[f64; N_INPUTS]) -> f64 {
        match self {
            Prepared::Native(n) => n.eval(x),
            Prepared::Interp(i) => i.eval(x),
            Prepared::Other(ev, params) => ev.eval(x, params),
        }
    }
}

/// A Rust closure as an evaluator (hand-written twins in tests and benches).
pub struct FnEvaluator<F>(pub F);

impl<F: Fn(&[f64; N_INPUTS], &[f64]) -> f64 + Send + Sync> Evaluator for FnEvaluator<F> {
    fn eval(&self, x: &[f64; N_INPUTS], params: &[f64]) -> f64 {
        (self.0)(x, params)
    }
}

/// A simplified formula with its evaluator.
#[derive(Clone)]
pub struct Kernel {
    pub formula: Arc<Formula>,
    pub backend: Backend,
    /// The math mode the builtins were compiled in.
    pub math: Mode,
    evaluator: Arc<dyn Evaluator>,
    /// Code generation time (zero for the interpreter beyond its flattening).
    pub compile_time: Duration,
}

impl Kernel {
    pub fn new(
        formula: Arc<Formula>,
        backend: Backend,
        math: Mode,
        evaluator: Arc<dyn Evaluator>,
        compile_time: Duration,
    ) -> Kernel {
        Kernel { formula, backend, math, evaluator, compile_time }
    }

    /// Inputs the formula reads; the renderer computes only these.
    pub fn used_inputs(&self) -> InputSet {
        self.formula.used_inputs()
    }

    /// Default parameter values (declaration order).
    pub fn default_params(&self) -> Vec<f64> {
        self.formula.default_params()
    }

    pub fn evaluator(&self) -> &Arc<dyn Evaluator> {
        &self.evaluator
    }

    /// The backend that evaluates it now: its `backend`, except under automatic tiering, where it is the tier
    /// the kernel has reached (Cranelift, then LLVM once it has evaluated enough points).
    pub fn backend_used(&self) -> Backend {
        self.evaluator.ran_on().unwrap_or(self.backend)
    }
}

impl Evaluator for Kernel {
    fn eval(&self, x: &[f64; N_INPUTS], params: &[f64]) -> f64 {
        self.evaluator.eval(x, params)
    }
    fn eval_batch(&self, cols: &Columns, params: &[f64], out: &mut [f64]) {
        self.evaluator.eval_batch(cols, params, out)
    }
    fn prepare(&self, params: &[f64]) -> Prepared<'_> {
        self.evaluator.prepare(params)
    }
    fn warm_up(&self) {
        self.evaluator.warm_up()
    }
    fn ran_on(&self) -> Option<Backend> {
        self.evaluator.ran_on()
    }
}

impl std::fmt::Debug for Kernel {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Kernel")
            .field("formula", &self.formula.to_program_text())
            .field("backend", &self.backend)
            .field("math", &self.math)
            .field("compile_time", &self.compile_time)
            .finish()
    }
}
