//! Backends: everything that turns a simplified [`Formula`](crate::ir::Formula) into something that runs or
//! prints. [`Evaluator`] is the one interface the renderer and the numerics call; [`Kernel`] pairs a formula
//! with its evaluator. [`interp`] is the reference semantics; [`native`] is what the two JIT tiers share (the
//! plan, the lowering over the math library's `Emit`, the calling convention and the one place generated code
//! is called, caches, errors), [`jit`] (Cranelift) and `llvm` (cargo feature `llvm`, LLVM 19) only their
//! primitives; [`glsl`] emits GLSL/WGSL text. All read builtins from the one table. [`program`] is the
//! multi-output form (several outputs over data columns, guarded regions) that the interpreter and both JIT
//! tiers also run. `unsafe` is confined to [`native`] (calling generated code) and the tiers (turning their
//! compilers' addresses into function pointers, owning and freeing the code).
//!
//! This module alone names the tiers ([`Backend`], [`Tier`]); [`Kernel`] and [`Prepared`] see only native code,
//! the interpreter, or another evaluator.

mod kernel;

pub mod drjit;
pub mod glsl;
pub mod interp;
pub mod jit;
#[cfg(feature = "llvm")]
pub mod llvm;
pub mod native;
pub mod program;
#[cfg(feature = "llvm")]
pub(crate) mod tiered;
#[cfg(feature = "llvm")]
pub use tiered::AUTO_LLVM_POINTS;

pub use kernel::{AsEvaluator, Columns, Evaluator, FnEvaluator, Kernel, Prepared};

/// Which backend evaluates a kernel.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum Backend {
    Interp,
    /// The Cranelift JIT.
    #[default]
    Jit,
    /// The LLVM tier (kernels only; a build without the cargo feature `llvm` refuses it with a diagnostic).
    Llvm,
    /// Automatic tiering (the `auto` tier in a build with the LLVM tier): kernels start on Cranelift and move to
    /// LLVM once they have evaluated a few thousand points in batches (`backend::tiered`); shading programs,
    /// which run for a whole render, are LLVM's from the start.
    Auto,
}

impl Backend {
    pub fn name(self) -> &'static str {
        match self {
            Backend::Interp => "interp",
            Backend::Jit => "jit",
            Backend::Llvm => "llvm",
            Backend::Auto => "auto",
        }
    }

    /// The JIT tier of this backend (`None` for the interpreter).
    pub fn tier(self) -> Option<Tier> {
        match self {
            Backend::Interp => None,
            Backend::Jit => Some(Tier::Cranelift),
            Backend::Llvm => Some(Tier::Llvm),
            Backend::Auto => Some(Tier::Auto),
        }
    }
}

/// Which compiler a JIT kernel is built with: `cranelift` (fast to compile, two lanes), `llvm` (LLVM 19, the
/// host's widest lanes; cargo feature `llvm`), or `auto` (Cranelift first and LLVM for big work when this build
/// has it — [`Backend::Auto`] — else Cranelift).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum Tier {
    #[default]
    Cranelift,
    Llvm,
    Auto,
}

impl Tier {
    pub fn name(self) -> &'static str {
        match self {
            Tier::Cranelift => "cranelift",
            Tier::Llvm => "llvm",
            Tier::Auto => "auto",
        }
    }

    /// The backend that `backend` with this tier means: the tier picks the JIT; the interpreter has none
    /// (the interpreter with the LLVM tier is a contradiction, reported as such).
    pub fn resolve(self, backend: Backend) -> Result<Backend, String> {
        match (backend, self) {
            (Backend::Interp, Tier::Cranelift | Tier::Auto) => Ok(Backend::Interp),
            (Backend::Interp, Tier::Llvm) => Err("the LLVM tier is a JIT; it does not apply to the interpreter backend".into()),
            (_, Tier::Cranelift) => Ok(Backend::Jit),
            (_, Tier::Llvm) => Ok(Backend::Llvm),
            (_, Tier::Auto) => Ok(if Tier::llvm_available() { Backend::Auto } else { Backend::Jit }),
        }
    }

    /// The LLVM tier's lanes on this host (`None` in a build without it).
    pub fn llvm_lanes() -> Option<u32> {
        #[cfg(feature = "llvm")]
        {
            llvm::host().ok().map(|h| h.lanes)
        }
        #[cfg(not(feature = "llvm"))]
        {
            None
        }
    }

    /// Whether this build has the LLVM tier and it can target the host.
    pub fn llvm_available() -> bool {
        #[cfg(feature = "llvm")]
        {
            llvm::available()
        }
        #[cfg(not(feature = "llvm"))]
        {
            false
        }
    }
}

impl std::str::FromStr for Tier {
    type Err = String;
    fn from_str(s: &str) -> Result<Tier, String> {
        match s {
            "cranelift" => Ok(Tier::Cranelift),
            "llvm" => Ok(Tier::Llvm),
            "auto" => Ok(Tier::Auto),
            _ => Err(format!("unknown tier `{s}`; expected `cranelift`, `llvm` or `auto`")),
        }
    }
}

impl std::str::FromStr for Backend {
    type Err = String;
    fn from_str(s: &str) -> Result<Backend, String> {
        match s {
            "interp" | "interpreter" => Ok(Backend::Interp),
            "jit" => Ok(Backend::Jit),
            _ => Err(format!("unknown backend `{s}`; expected `jit` or `interp`")),
        }
    }
}
