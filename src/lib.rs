//! lobe: a compiler and JIT for BRDF formulas.
//!
//! The pipeline, one module per stage:
//!
//! ```text
//! text (.brdf) → front (logos tokens → lalrpop AST with spans → names/arity resolved) → ir::Formula
//!   → simplify (fixpoint rewrites, baked parameters, used inputs)
//!   → { interp (reference) | jit (Cranelift, scalar and batched) | export (GLSL) } = kernel::Kernel
//!   → check (energy, accuracy, sweep, fit) and render (tiles → image → metrics)
//! ```
//!
//! The front end knows nothing of Cranelift; every backend consumes only [`ir::Formula`]; builtins come from
//! the one table in [`builtins`]. The entry point is [`compile`].

pub mod builtins;
pub mod check;
pub mod cli;
pub mod front;
pub mod interp;
pub mod ir;
pub mod jit;
pub mod kernel;
pub mod report;
pub mod simplify;
pub mod watch;

pub use front::diag::{Diagnostic, Diagnostics};
pub use ir::{Formula, Input, N_INPUTS};
pub use kernel::{Backend, Columns, Evaluator, Kernel};

use std::sync::Arc;
use std::time::Instant;

/// How to compile a formula.
#[derive(Clone, Debug, Default)]
pub struct Options {
    pub backend: Backend,
    /// Parameters baked into the code as constants (`--set n=50` for a fixed material). Parameters not listed
    /// stay live: read from the params slice at run time, so changing them needs no recompilation.
    pub bake: Vec<(String, f64)>,
    /// Skip the simplifier (for testing the simplifier itself against the unsimplified formula).
    pub no_simplify: bool,
    /// Multiply the formula by its exact normalisation coefficient 1/(2π·Int) (the papers' lobe integral,
    /// computed by adaptive quadrature at compile time) and bake it into the kernel. The coefficient depends on
    /// every parameter, so normalising bakes them all: values from `bake`, declared defaults for the rest.
    pub normalize: bool,
}

/// Parses, lowers and simplifies a formula, then builds its kernel for the chosen backend.
pub fn compile(file: &str, src: &str, opts: &Options) -> Result<Kernel, Diagnostics> {
    let f = front::parse(file, src)?;
    compile_formula(f, opts)
}

/// [`compile`] for an already lowered formula.
pub fn compile_formula(f: Formula, opts: &Options) -> Result<Kernel, Diagnostics> {
    let mut bake = resolve_bake(&f, &opts.bake)?;
    if opts.normalize {
        for (i, p) in f.params.iter().enumerate() {
            if !bake.iter().any(|(j, _)| *j == i) {
                bake.push((i, p.default));
            }
        }
    }
    let simplified = if opts.no_simplify { simplify::bake_only(&f, &bake) } else { simplify::simplify(&f, &bake) };
    let simplified = if opts.normalize { normalized(simplified)? } else { simplified };
    build_kernel(Arc::new(simplified), opts.backend)
}

/// `coef · f` with the exact coefficient of the fully baked formula `f` (see [`Options::normalize`]).
fn normalized(f: Formula) -> Result<Formula, Diagnostics> {
    let params = f.default_params();
    let ev = interp::Interp::new(&f);
    let (lobe, _) = check::choose_lobe_input(f.used_inputs());
    let coef = check::energy::normalization_coef(&ev, &params, lobe).map_err(|e| {
        let mut d = Diagnostic::error(format!("cannot normalise {}: {e}", f.display_name()));
        if let Some(h) = &e.hint {
            d = d.hint(h.clone());
        }
        Diagnostics::single(&f.file, d)
    })?;
    let mut g = f.clone();
    let span = g.ir.span(g.root);
    let c = g.ir.konst(coef, span);
    g.root = g.ir.bin(ir::BinOp::Mul, c, g.root, span);
    Ok(simplify::simplify(&g, &[]))
}

/// Builds the evaluator for an already simplified formula.
pub fn build_kernel(f: Arc<Formula>, backend: Backend) -> Result<Kernel, Diagnostics> {
    let t = Instant::now();
    let ev: Arc<dyn Evaluator> = match backend {
        Backend::Interp => Arc::new(interp::Interp::new(&f)),
        Backend::Jit => jit::kernel_evaluator(&f).map_err(|d| Diagnostics::single(&f.file, d))?,
    };
    Ok(Kernel::new(f, backend, ev, t.elapsed()))
}

/// Checks `--set` names and ranges against the formula's declared parameters.
pub fn resolve_bake(f: &Formula, set: &[(String, f64)]) -> Result<Vec<(usize, f64)>, Diagnostics> {
    let mut out = vec![];
    let mut ds = Diagnostics::new(f.file.clone(), f.source.clone());
    for (name, v) in set {
        match f.param_index(name) {
            Some(i) => {
                let p = &f.params[i];
                if !(v.is_finite() && *v >= p.lo && *v <= p.hi) {
                    let mut d = Diagnostic::error(format!(
                        "value {v} for parameter `{name}` is outside its declared range {}..{}",
                        ir::print::number(p.lo),
                        ir::print::number(p.hi)
                    ));
                    if let Some(s) = p.span {
                        d = d.at(s, "declared here");
                    }
                    ds.push(d.hint(format!("choose a value in {}..{} or widen the range in the file", p.lo, p.hi)));
                } else {
                    out.push((i, *v));
                }
            }
            None => {
                let names: Vec<&str> = f.params.iter().map(|p| p.name.as_str()).collect();
                let mut d = Diagnostic::error(format!("the formula has no parameter `{name}`"));
                d = match front::suggest(name, names.iter().copied()) {
                    Some(s) => d.hint(format!("did you mean `{s}`?")),
                    None => d.hint(format!("its parameters are: {}", names.join(", "))),
                };
                ds.push(d);
            }
        }
    }
    if ds.has_errors() {
        Err(ds)
    } else {
        Ok(out)
    }
}

/// The tile-based software renderer (scenes, meshes, rasteriser, shading, PNG output, image comparison).
pub mod render;
