//! What the native tiers share: a simplified formula or a multi-output program → machine code, whichever
//! compiler makes it. Below this sit the tiers, each only its primitives: [`crate::backend::jit`] (Cranelift:
//! fast to compile, two lanes) and `llvm` (cargo feature `llvm`: LLVM 19, the host's widest lanes).
//!
//! - [`plan`]: what a kernel or program computes where (the prepared parameter block's nodes, the entry's, the
//!   loop's) and whether the math library is inlined or called ([`OUTLINE_AT`]);
//! - [`lower`]: the IR → values translation written once over the math library's `Emit` (node dispatch,
//!   builtin calls, the inline builtins with their constant-operand forms, a program step's order); a tier
//!   implements [`lower::Lower`]'s primitives;
//! - [`frame`]: what each function shape computes in which order (the prepare function, the scalar kernel, a
//!   batched function's entry, a kernel's loop step, a program's step with its guarded regions), written once
//!   over [`frame::Frame`]'s block access and [`frame::ProgramStep`]'s branch and join;
//! - [`abi`]: the four signatures generated code is called with and the one place it is called (`unsafe`,
//!   each call with its `# Safety` note): [`NativeKernel`] (the [`crate::Evaluator`] of either tier's kernel),
//!   [`NativeCall`] (its prepared form, what [`crate::backend::Prepared::eval`] calls directly), and
//!   [`ShadeCode`] (either tier's program);
//! - [`cache`]: the bounded code caches keyed by the IR's structure;
//! - [`NativeError`]: the one error type of both tiers.
//!
//! A third tier costs its primitives: an `Emit` + [`lower::Lower`] + [`frame::Frame`] implementation, a
//! [`frame::ProgramStep`] (a region's branch and join), its function declarations and its loop over the
//! elements (the loads and stores at an element, and what it does with the elements after the last full
//! vector), and a [`abi::KernelCode`] owning its code.

// The one module allowed `unsafe` besides the tiers' ownership of their code: calling generated code.
#![allow(unsafe_code)]

pub(crate) mod abi;
pub(crate) mod cache;
mod error;
pub(crate) mod frame;
pub(crate) mod lower;
pub(crate) mod plan;

pub use abi::{NativeCall, NativeKernel, ShadeCode};
pub use error::NativeError;
pub use plan::OUTLINE_AT;
pub(crate) use plan::{outlines, Plan};
