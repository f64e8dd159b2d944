//! What the native tiers share: a simplified formula or a multi-output program → machine code, whichever
//! compiler makes it. Below this sit the tiers, each only its primitives: [`crate::backend::jit`] (Cranelift:
//! fast to compile, two lanes) and `llvm` (cargo feature `llvm`: LLVM 19, the host's widest lanes).
//!
//! - [`plan`]: what a kernel or program computes where (the prepared parameter block's nodes, the entry's, the
//!   loop's) and whether the math library is inlined or called ([`OUTLINE_AT`]);
//! - [`lower`]: the IR → values translation written once over the math library's `Emit` (node dispatch,
//!   builtin calls, the inline builtins with their constant-operand forms, a program step's order); a tier
//!   implements [`lower::Lower`]'s primitives;
//! - [`ops`]: the math library's operations that are not one instruction (bit sequences, compare-and-select,
//!   the exact product, calls of a compiled function once per lane, the rare block), written once over
//!   [`ops::Bits`]' integer lanes, [`ops::Calls`]' per-lane calls and [`ops::Branch`]'s branch and join; a
//!   tier's method is one line calling them;
//! - [`frame`]: what each function shape computes in which order (the prepare function, the scalar kernel, a
//!   batched function's entry, a kernel's loop step, a program's step with its guarded regions), written once
//!   over [`frame::Frame`]'s block access and [`frame::ProgramStep`]'s branch and join (for one translator:
//!   [`ops::Branch`]'s);
//! - [`abi`]: the four signatures generated code is called with and the one place it is called (`unsafe`,
//!   each call with its `# Safety` note): [`NativeKernel`] (the [`crate::Evaluator`] of either tier's kernel),
//!   [`NativeCall`] (its prepared form, what [`crate::backend::Prepared::eval`] calls directly), and
//!   [`ShadeCode`] (either tier's program);
//! - [`cache`]: the bounded code caches keyed by the IR's structure;
//! - [`NativeError`]: the one error type of both tiers.
//!
//! A third tier costs its primitives: an `Emit` + [`lower::Lower`] + [`ops::Bits`] + [`ops::Calls`] +
//! [`ops::Branch`] + [`frame::Frame`] implementation (with them its program step and regions are
//! [`frame::ProgramStep`]'s for one translator), its function declarations and its loop over the elements (the
//! loads and stores at an element, and what it does with the elements after the last full vector), and a
//! [`abi::KernelCode`] owning its code.
//!
//! Mirrored code (a target of at most 150 lines per tier): a function of one tier that does another tier's
//! function's job step for step, only the builder API differing, belongs here over primitives; `.ci/mirrored`
//! lists the pairs left and counts their lines (its docstring has the rule).

// The one module allowed `unsafe` besides the tiers' ownership of their code: calling generated code.
#![allow(unsafe_code)]

pub(crate) mod abi;
pub(crate) mod cache;
mod error;
pub(crate) mod frame;
pub(crate) mod lower;
pub(crate) mod ops;
pub(crate) mod plan;

pub(crate) use abi::evaluator;
pub use abi::{NativeCall, NativeKernel, ShadeCode};
pub use error::NativeError;
pub use plan::OUTLINE_AT;
pub(crate) use plan::{outlines, Plan};
