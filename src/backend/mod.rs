//! Backends: everything that turns a simplified [`Formula`](crate::ir::Formula) into something that runs or
//! prints. [`Evaluator`] is the one interface the renderer and the numerics call; [`Kernel`] pairs a formula
//! with its evaluator. [`interp`] is the reference semantics, [`jit`] compiles the same IR with Cranelift (the
//! only `unsafe` in lobe besides the LLVM tier), `llvm` (cargo feature `llvm`) compiles kernels and programs with LLVM 19, [`glsl`] emits GLSL/WGSL text from it. All three read builtins from the one table.
//! [`program`] is the multi-output form (several outputs over data columns, guarded regions) that the
//! interpreter and both JIT tiers also run.

mod kernel;

pub mod glsl;
pub mod interp;
pub mod jit;
#[cfg(feature = "llvm")]
pub mod llvm;
pub mod program;

pub use kernel::{AsEvaluator, Backend, Columns, Evaluator, FnEvaluator, Kernel, Prepared, Tier};
