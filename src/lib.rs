//! lobe: a compiler and JIT for BRDF formulas.
//!
//! The pipeline, one layer per folder; every import points down this list, and the library does not know the
//! CLI (the binary's `cli` modules) exists:
//!
//! ```text
//! base       spans, diagnostics, reading sources, file polling
//! ir         the resolved expression (arena, hash-consed); builtins: the one table of functions
//! frame      the shading frame: N, X, Y and the directions L, V → the kernel inputs
//! front      .brdf text → logos tokens → lalrpop AST with spans → names/arity resolved → ir::Formula
//! simplify   fixpoint rewrites, baked parameters, integer powers, used inputs
//! backend    the Evaluator interface and Kernel; interpreter (reference), Cranelift JIT, the LLVM tier (cargo
//!            feature `llvm`: batched kernels in the host's widest lanes), GLSL/WGSL emission
//! measured   MERL .binary tables: read (checked), write, tabulate, the half/difference lookup; each channel an
//!            Evaluator, so a measurement goes wherever a kernel goes
//! lib.rs     the compile entry points: compile_source, compile_formula, build_kernel
//! numerics   energy and normalisation, accuracy against a reference, the domain sweep, fits, twins; the
//!            higher-precision truth and the accuracy pass's measured choice (passed down as a FormulaChooser)
//! bsdf       every formula a full BSDF: sample() and pdf() that agree with eval(), built from kernels (tabulated
//!            half-vector distributions, an exact path for one-cosine lobes); the χ² validation
//! render     scenes, shapes, camera, rasteriser, shading, images, image comparison
//! report     bench rows (measured) and tables, plots (cargo feature `plot`)
//! serve      the interactive page's HTTP server, page assets embedded (cargo feature `serve`)
//! main.rs    the `lobe` binary (cargo feature `cli`): its cli modules hold the clap subcommands over the layers
//!            above
//! ```
//!
//! Cargo enforces the top of that list: the argument parser and progress bars (clap, indicatif) are optional
//! dependencies of the `cli` feature, which the binary requires; the HTTP stack (tokio, hyper) is the `serve`
//! feature's and plotters the `plot` feature's. All three are on by default, so `cargo run` builds the whole
//! command; the Python module depends on the library with `default-features = false` and compiles none of them.
//!
//! The front end knows nothing of Cranelift; every backend consumes only [`ir::Formula`]; builtins come from
//! the one table in [`builtins`]. Numerical checks consume kernels ([`backend::Evaluator`]), never text.
//!
//! # Start here
//! The root re-exports what a caller needs to compile and run a formula: [`compile_source`] (text → [`Kernel`])
//! or [`front::parse()`] then [`compile_formula`] with [`Options`] ([`Backend`], [`Tier`], [`Mode`], baked
//! values, the accuracy pass from [`numerics::robust::with_pass`]); a [`Kernel`] is an [`Evaluator`] of the
//! inputs ([`Input`], [`N_INPUTS`]; from directions through [`Frame`]), one point or [`Columns`] at a time;
//! errors are [`Diagnostics`] with [`Hint`]s. The layer modules below are public for the `lobe` binary, the
//! Python module and the benchmarks; items no caller outside the crate uses are `pub(crate)`.
#![deny(unsafe_code)]
// Module docs say why the code is as it is, naming crate-private items; rustdoc resolves those links when it
// documents private items.
#![allow(rustdoc::private_intra_doc_links)]

pub mod base;
pub mod builtins;
pub mod ir;
pub mod frame;
pub mod front;
pub mod simplify;
pub mod backend;
pub mod measured;
pub mod numerics;
pub mod bsdf;
pub mod render;
pub mod report;
#[cfg(feature = "serve")]
pub mod serve;

pub use builtins::Mode;
pub use backend::{Backend, Columns, Evaluator, Kernel, Tier};
pub use base::diag::{Diagnostic, Diagnostics, Hint};
pub use frame::{from_cosines, Frame};
pub use ir::{Formula, Input, N_INPUTS};

use std::sync::Arc;
use std::time::Instant;

/// Picks the formula to compile among the accuracy pass's candidates by measuring them. The measuring needs
/// the truth evaluator and a backend, which live above this file (`numerics::robust::Chooser`), so it is
/// passed in rather than called.
pub trait FormulaChooser: Send + Sync + std::fmt::Debug {
    /// `original` as lowered, the baked values, and its plain simplification; returns the formula to compile.
    fn choose(&self, original: &Formula, bake: &[(usize, f64)], simplified: Formula) -> Formula;
}

/// How to compile a formula.
#[derive(Clone, Debug, Default)]
pub struct Options {
    pub backend: Backend,
    /// Parameters baked into the code as constants (n = 50 for a fixed material). Parameters not listed
    /// stay live: read from the params slice at run time, so changing them needs no recompilation.
    pub bake: Vec<(String, f64)>,
    /// Skip the simplifier (for testing the simplifier itself against the unsimplified formula).
    pub no_simplify: bool,
    /// Which definition of the transcendental builtins the kernel runs.
    pub math: Mode,
    /// The accuracy pass (`numerics::robust::with_pass`); `None` compiles the plain simplification.
    pub accuracy: Option<Arc<dyn FormulaChooser>>,
}

/// Parses, lowers and simplifies a formula, then builds its kernel for the chosen backend.
pub fn compile_source(file: &str, src: &str, opts: &Options) -> Result<Kernel, Diagnostics> {
    let f = front::parse(file, src)?;
    compile_formula(f, opts)
}

/// [`compile_source`] for an already lowered formula.
pub fn compile_formula(f: Formula, opts: &Options) -> Result<Kernel, Diagnostics> {
    build_kernel(Arc::new(simplified(&f, opts)?), opts.backend, opts.math)
}

/// The simplified formula with `opts.bake` folded in (names and ranges checked first).
pub fn simplified(f: &Formula, opts: &Options) -> Result<Formula, Diagnostics> {
    let bake = resolve_bake(f, &opts.bake)?;
    if opts.no_simplify {
        return Ok(simplify::bake_only(f, &bake));
    }
    let s = simplify::simplify(f, &bake);
    Ok(match &opts.accuracy {
        Some(c) => c.choose(f, &bake, s),
        None => s,
    })
}

/// Builds the evaluator for an already simplified formula.
pub fn build_kernel(f: Arc<Formula>, backend: Backend, math: Mode) -> Result<Kernel, Diagnostics> {
    let t = Instant::now();
    let ev: Arc<dyn Evaluator> = match backend {
        Backend::Interp => Arc::new(backend::interp::Interp::with_mode(&f, math)),
        Backend::Jit => backend::native::evaluator(backend::jit::jit_kernel(&f, math)).map_err(|d| Diagnostics::single(&f.file, d))?,
        #[cfg(feature = "llvm")]
        Backend::Llvm => backend::native::evaluator(backend::llvm::llvm_kernel(&f, math)).map_err(|d| Diagnostics::single(&f.file, d))?,
        #[cfg(feature = "llvm")]
        Backend::Auto => {
            let first = backend::native::evaluator(backend::jit::jit_kernel(&f, math)).map_err(|d| Diagnostics::single(&f.file, d))?;
            Arc::new(backend::tiered::Tiered::new(first, f.clone(), math))
        }
        // Without the LLVM tier, automatic tiering is Cranelift ([`Tier::resolve`] never gives `Auto` there).
        #[cfg(not(feature = "llvm"))]
        Backend::Auto => backend::native::evaluator(backend::jit::jit_kernel(&f, math)).map_err(|d| Diagnostics::single(&f.file, d))?,
        #[cfg(not(feature = "llvm"))]
        Backend::Llvm => return Err(Diagnostics::single(&f.file, llvm_missing())),
    };
    Ok(Kernel::new(f, backend, math, ev, t.elapsed()))
}

/// Why a build without the cargo feature `llvm` cannot give an LLVM kernel, and how to get one.
pub fn llvm_missing() -> Diagnostic {
    Diagnostic::error("this build of lobe has no LLVM tier").hint(CompileAdvice::BuildWithLlvm)
}

/// Debian's packages the cargo feature `llvm` builds against.
pub const LLVM_PACKAGES: &str = "needs LLVM 19: apt-get install llvm-19-dev libpolly-19-dev libzstd-dev";

/// What to change when compiling a formula with these options fails, worded by each front end
/// ([`base::diag::Advice`]).
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum CompileAdvice {
    /// `name` is an input (a cosine), given where a parameter value was expected.
    InputNotParam { name: String },
    /// The LLVM tier was asked of a build without it: how to build it in, or use the Cranelift tier.
    BuildWithLlvm,
}

impl base::diag::Advice for CompileAdvice {
    fn plain(&self) -> String {
        match self {
            CompileAdvice::InputNotParam { name } => format!("`{name}` is an input (a cosine), not a parameter; give it as an input value"),
            CompileAdvice::BuildWithLlvm => format!("rebuild lobe with the cargo feature `llvm` ({LLVM_PACKAGES}), or use the Cranelift tier"),
        }
    }
}

/// The backend that `backend` with JIT tier `tier` means ([`Tier::resolve`]); the LLVM tier in a build (or on a
/// host) without it is [`llvm_missing`] here, not a failure at the first compile.
pub fn resolve_backend(backend: Backend, tier: Tier) -> Result<Backend, Diagnostic> {
    let b = tier.resolve(backend).map_err(|e| Diagnostic::error(e).hint("leave the tier at `cranelift`, or use the `jit` backend"))?;
    if b == Backend::Llvm && !Tier::llvm_available() {
        return Err(llvm_missing());
    }
    Ok(b)
}

/// Checks the names and ranges of parameter values to bake against the formula's declared parameters.
pub fn resolve_bake(f: &Formula, set: &[(String, f64)]) -> Result<Vec<(usize, f64)>, Diagnostics> {
    let mut out = vec![];
    let mut ds = Diagnostics::new(f.file.clone(), f.source.clone());
    for (name, v) in set {
        match f.param_index(name) {
            Some(i) => {
                let p = &f.params[i];
                if !p.admits(*v) {
                    let mut d = Diagnostic::error(format!(
                        "value {} for parameter `{name}` is outside its declared range {}..{}",
                        ir::print::number(*v),
                        ir::print::number(p.lo),
                        ir::print::number(p.hi)
                    ));
                    if let Some(s) = p.span {
                        d = d.at(s, "declared here");
                    }
                    ds.push(d.hint(format!(
                        "choose a value in {}..{} or widen the range in the file",
                        ir::print::number(p.lo),
                        ir::print::number(p.hi)
                    )));
                } else {
                    out.push((i, *v));
                }
            }
            None => {
                let names: Vec<&str> = f.params.iter().map(|p| p.name.as_str()).collect();
                let hint: Hint = if Input::from_name(name).is_some() {
                    CompileAdvice::InputNotParam { name: name.clone() }.into()
                } else {
                    front::did_you_mean(name, &names, "its parameters are: ").into()
                };
                ds.push(Diagnostic::error(format!("the formula has no parameter `{name}`")).hint(hint));
            }
        }
    }
    if ds.has_errors() {
        Err(ds)
    } else {
        Ok(out)
    }
}
