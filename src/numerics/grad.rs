//! A formula's value and gradient as one compiled multi-output kernel.
//!
//! For every colour channel, the value and ∂f/∂v for each variable v ([`derive::variables`]: every declared
//! parameter, then every input the value reads) are ordinary scalar formulas ([`derive::derive`] of the
//! lowered channel). Each goes the value's own way: [`crate::simplified`] (baking, the simplifier, and the
//! accuracy pass when the options carry one), so a partial is as accurate as any formula lobe compiles. The
//! outputs are then merged into one hash-consed arena whose inputs are the data columns of a multi-output
//! [`Program`] (the form shading programs use), so the value's and the partials' common work is computed once,
//! and compiled by the tier the options name: the interpreter's [`ProgramInterp`], Cranelift or LLVM — the same
//! program code paths as shading, bit-identical across tiers. A program has at most
//! [`crate::backend::program`]'s 16 outputs; more outputs (a colour formula, many parameters) are split into
//! consecutive programs of up to 16.
//!
//! The value output is bit-identical to the kernel [`crate::compile_formula`] builds with the same options
//! (the same simplified formula through the same library code).

use crate::backend::interp::ProgramInterp;
use crate::backend::native::ShadeCode;
use crate::backend::program::{Program, MAX_OUTPUTS};
use crate::backend::Backend;
use crate::base::diag::{Diagnostic, Diagnostics};
use crate::builtins::Mode;
use crate::ir::{Formula, Input, InputSet, Ir, Node, NodeId, N_INPUTS};
pub use crate::simplify::derive::{self, Var};
use crate::Options;
use std::sync::Arc;

enum Code {
    Interp(ProgramInterp),
    Native(Arc<ShadeCode>),
}

/// One compiled program and the output slots it computes.
struct Part {
    code: Code,
    /// Indices into the gradient's outputs ([`Gradient::slot`]).
    slots: Vec<usize>,
}

/// A compiled value-and-gradient kernel (module doc).
pub struct Gradient {
    /// The formula as lowered (its declarations name the parameters).
    pub formula: Arc<Formula>,
    /// What each gradient entry differentiates by, in output order.
    pub vars: Vec<Var>,
    /// 1, or 3 for a colour formula.
    pub channels: usize,
    /// The inputs any output reads.
    pub used: InputSet,
    /// Each output's simplified formula, in slot order ([`Gradient::slot`]).
    pub outputs: Vec<Formula>,
    pub backend: Backend,
    pub mode: Mode,
    parts: Vec<Part>,
}

/// The values and gradients at a set of points: `value[c][i]`, `grad[v][c][i]` for channel c, variable v, point i.
#[derive(Clone, Debug, PartialEq)]
pub struct GradValues {
    pub value: Vec<Vec<f64>>,
    pub grad: Vec<Vec<Vec<f64>>>,
}

impl Gradient {
    /// Compiles the value and gradient of `f` with `opts` (backend, math mode, baked values, accuracy pass).
    pub fn compile(f: &Formula, opts: &Options) -> Result<Gradient, Diagnostics> {
        Gradient::compile_vars(f, opts, None)
    }

    /// [`Gradient::compile`] with the partials by `only` these variables (in this order), or by every
    /// variable (`None`): a fit needs the free parameters' partials only.
    pub fn compile_vars(f: &Formula, opts: &Options, only: Option<&[Var]>) -> Result<Gradient, Diagnostics> {
        let chans = f.channels();
        let values: Vec<Formula> = chans.iter().map(|c| crate::simplified(c, opts)).collect::<Result<_, _>>()?;
        let reads: InputSet = values.iter().map(Formula::used_inputs).collect();
        let vars: Vec<Var> = match only {
            Some(v) => v.to_vec(),
            None => (0..f.params.len() as u16).map(Var::Param).chain(reads.iter().map(Var::Input)).collect(),
        };
        let mut outputs = Vec::with_capacity(chans.len() * (1 + vars.len()));
        for (c, v) in chans.iter().zip(values) {
            outputs.push(v);
            for var in &vars {
                outputs.push(crate::simplified(&derive::derive(c, *var), opts)?);
            }
        }
        let used = outputs.iter().map(Formula::used_inputs).collect();
        let (ir, roots) = merge(&outputs);
        let mut parts = vec![];
        let fail = |e: String| Diagnostics::single(&f.file, Diagnostic::error(format!("the gradient's program: {e}")));
        for (k, chunk) in roots.chunks(MAX_OUTPUTS).enumerate() {
            let p = Program::new(&ir, chunk, &[], f.params.len()).map_err(fail)?;
            let code = match opts.backend {
                Backend::Interp => Code::Interp(ProgramInterp::new(&p, opts.math)),
                // Automatic tiering: a gradient's program starts where kernels do, on Cranelift.
                Backend::Jit | Backend::Auto => Code::Native(crate::backend::jit::shade_code(&p, opts.math).map_err(|e| Diagnostics::single(&f.file, e.to_diagnostic()))?),
                #[cfg(feature = "llvm")]
                Backend::Llvm => Code::Native(crate::backend::llvm::program_code(&p, opts.math).map_err(|e| Diagnostics::single(&f.file, e.to_diagnostic()))?),
                #[cfg(not(feature = "llvm"))]
                Backend::Llvm => return Err(Diagnostics::single(&f.file, crate::llvm_missing())),
            };
            let slots = (k * MAX_OUTPUTS..k * MAX_OUTPUTS + chunk.len()).collect();
            parts.push(Part { code, slots });
        }
        Ok(Gradient { formula: Arc::new(f.clone()), vars, channels: chans.len(), used, outputs, backend: opts.backend, mode: opts.math, parts })
    }

    /// The output slot of channel `c`'s value (`v = None`) or of its derivative by variable `v`.
    pub fn slot(&self, c: usize, v: Option<usize>) -> usize {
        c * (1 + self.vars.len()) + v.map_or(0, |v| v + 1)
    }

    /// The variables' names, in order.
    pub fn names(&self) -> Vec<String> {
        self.vars.iter().map(|v| v.name(&self.formula)).collect()
    }

    /// Every output at `len` points: `cols` are the inputs' columns in [`Input::ALL`] order (an input no
    /// output reads may be empty), `params` every declared parameter's value.
    pub fn run(&self, cols: &[&[f64]; N_INPUTS], params: &[f64], len: usize) -> GradValues {
        let zeros = vec![0.0; len];
        let cols: Vec<&[f64]> = Input::ALL.iter().map(|i| if self.used.contains(*i) && cols[i.index()].len() >= len { cols[i.index()] } else { &zeros[..] }).collect();
        let mut outs = vec![vec![f64::NAN; len]; self.channels * (1 + self.vars.len())];
        for part in &self.parts {
            let mut mine: Vec<Vec<f64>> = part.slots.iter().map(|_| vec![f64::NAN; len]).collect();
            let mut refs: Vec<&mut [f64]> = mine.iter_mut().map(|v| &mut v[..]).collect();
            match &part.code {
                Code::Interp(i) => i.run(&cols, params, &mut refs, len),
                Code::Native(n) => {
                    let block = n.prepare(params);
                    if n.run(&cols, params, &block, &mut refs, len).is_err() {
                        refs.iter_mut().for_each(|o| o.iter_mut().for_each(|x| *x = f64::NAN));
                    }
                }
            }
            for (s, v) in part.slots.iter().zip(mine) {
                outs[*s] = v;
            }
        }
        let m = self.vars.len();
        let value = (0..self.channels).map(|c| std::mem::take(&mut outs[self.slot(c, None)])).collect();
        let grad = (0..m).map(|v| (0..self.channels).map(|c| std::mem::take(&mut outs[c * (1 + m) + v + 1])).collect()).collect();
        GradValues { value, grad }
    }

    /// The value (per channel) and gradient (`[variable][channel]`) at one point.
    pub fn eval(&self, x: &[f64; N_INPUTS], params: &[f64]) -> (Vec<f64>, Vec<Vec<f64>>) {
        let cols: [&[f64]; N_INPUTS] = std::array::from_fn(|i| std::slice::from_ref(&x[i]));
        let r = self.run(&cols, params, 1);
        (r.value.iter().map(|v| v[0]).collect(), r.grad.iter().map(|g| g.iter().map(|v| v[0]).collect()).collect())
    }
}

/// The truth's partial derivative of `f` by `v` at (`x`, `params`), what derivatives are measured against:
/// central differences of the truth ([`crate::numerics::truth`], ~104 bits, unbounded exponent, nothing
/// rounded until the end) at steps h = 2⁻²⁰·max(|v|, 2⁻¹⁰), h/2 and h/4, each pair Richardson-extrapolated
/// ((4·D(h/2) − D(h))/3: truncation O(h⁴) ≈ 2⁻⁸⁰ relative, rounding ≈ 2⁻⁸⁴·|f|/|v·∂f/∂v|). `None` where the two
/// extrapolations differ by more than 2⁻⁵⁸ relative (a kink, a step or a pole within the steps, or a derivative
/// so small against the value that the truth cannot resolve it), or where the one-sided differences disagree
/// (a kink exactly at the point), or where the change over the step is below the truth's resolution of f
/// (2⁻⁹⁰·|f|): the derivative is not established there. A variable f does not read has derivative 0.
pub fn truth_partial(f: &Formula, v: Var, x: &[f64; N_INPUTS], params: &[f64]) -> Option<f64> {
    use crate::numerics::truth::{eval_x, Xf};
    let at = |d: f64| -> (Xf, f64) {
        let (mut x, mut p) = (*x, params.to_vec());
        let moved = match v {
            Var::Input(i) => &mut x[i.index()],
            Var::Param(k) => &mut p[usize::from(k)],
        };
        *moved += d;
        let m = *moved;
        (eval_x(f, &x, &p), m)
    };
    let base = match v {
        Var::Input(i) => x[i.index()],
        Var::Param(k) => params[usize::from(k)],
    };
    let read = match v {
        Var::Input(i) => f.used_inputs().contains(i),
        Var::Param(k) => f.ir.used_params(f.root).contains(&k),
    };
    if !read {
        return Some(0.0);
    }
    let h = base.abs().max(2f64.powi(-10)) * 2f64.powi(-20);
    let diff = |h: f64| {
        let ((fp, xp), (fm, xm)) = (at(h), at(-h));
        (fp - fm) / (Xf::from_f64(xp) - Xf::from_f64(xm))
    };
    let (d1, d2, d4) = (diff(h), diff(h / 2.0), diff(h / 4.0));
    let (four, three) = (Xf::from_f64(4.0), Xf::from_f64(3.0));
    let r1 = ((four * d2) - d1) / three;
    let r2 = ((four * d4) - d2) / three;
    let (a, b) = (r1.to_f64(), r2.to_f64());
    if !(a.is_finite() && b.is_finite()) {
        return None;
    }
    let gap = (r1 - r2).to_f64().abs();
    if gap > 2f64.powi(-58) * a.abs().max(b.abs()) {
        return None;
    }
    // A kink exactly at the point (min(n, a) at n = a) passes the central test with the mean of the two slopes:
    // the one-sided differences (extrapolated: 2·D(h/2) − D(h), O(h²)) must agree too.
    let (f0, x0) = at(0.0);
    let side = |s: f64| {
        let one = |h: f64| {
            let (fh, xh) = at(s * h);
            (fh - f0) / (Xf::from_f64(xh) - Xf::from_f64(x0))
        };
        ((Xf::from_f64(2.0) * one(h / 2.0)) - one(h)).to_f64()
    };
    let (right, left) = (side(1.0), side(-1.0));
    if (right - left).abs() > 2f64.powi(-30) * right.abs().max(left.abs()).max(b.abs()) {
        return None;
    }
    // The truth's ~104 bits resolve a change of f only above ~2⁻¹⁰⁰·|f|: a smaller one (a term absorbed by a
    // much larger one, −m + 10²⁹⁹) reads as no change at all.
    let resolvable = 2f64.powi(-90) * f0.to_f64().abs();
    (b.abs() * h >= resolvable).then_some(b)
}

/// The outputs' formulas in one arena whose inputs are data columns (column k = input k), and their roots.
fn merge(outputs: &[Formula]) -> (Ir, Vec<NodeId>) {
    let mut ir = Ir::new();
    let mut roots = vec![];
    for g in outputs {
        let (gir, groot) = g.ir.compact(g.root);
        let mut map: Vec<NodeId> = Vec::with_capacity(gir.len());
        for id in gir.ids() {
            let n = match *gir.node(id) {
                Node::Input(i) => Node::Column(i.index() as u16),
                n => n.map_args(|a| map[a.index()]),
            };
            map.push(ir.push(n, gir.span(id)));
        }
        roots.push(map[groot.index()]);
    }
    (ir, roots)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::Evaluator;

    #[test]
    fn the_value_output_is_the_kernels_value_and_partials_match_differences() {
        let src = "param a = 2 in 0.1..10\nparam k = 0.5 in 0..1\nlet t = exp(-a * (1 - NH)) * sqrt(NL)\nk * t + (1 - k) * pow(NV, a)";
        let f = crate::front::parse("t.brdf", src).unwrap();
        for backend in [Backend::Interp, Backend::Jit] {
            let opts = Options { backend, ..Options::default() };
            let g = Gradient::compile(&f, &opts).unwrap();
            assert_eq!(g.names(), ["n", "a", "k", "NL", "NV", "NH"]);
            let kern = crate::compile_formula(f.clone(), &opts).unwrap();
            let mut x = [0.0; N_INPUTS];
            x[Input::NL.index()] = 0.4;
            x[Input::NV.index()] = 0.7;
            x[Input::NH.index()] = 0.9;
            let p = [50.0, 2.5, 0.3];
            let (v, d) = g.eval(&x, &p);
            assert_eq!(v[0].to_bits(), kern.eval(&x, &p).to_bits(), "{backend:?}");
            let h = 1e-6;
            for (j, var) in g.vars.iter().enumerate() {
                let (mut xp, mut xm, mut pp, mut pm) = (x, x, p, p);
                match var {
                    Var::Param(k) => {
                        pp[*k as usize] += h;
                        pm[*k as usize] -= h;
                    }
                    Var::Input(i) => {
                        xp[i.index()] += h;
                        xm[i.index()] -= h;
                    }
                }
                let c = (kern.eval(&xp, &pp) - kern.eval(&xm, &pm)) / (2.0 * h);
                assert!((d[j][0] - c).abs() < 1e-7 * c.abs().max(1.0), "{backend:?} ∂{}: {} vs {c}", g.names()[j], d[j][0]);
            }
        }
    }

    #[test]
    fn colour_formulas_and_many_outputs_split_into_programs() {
        let mut src = String::new();
        for k in 0..7 {
            src.push_str(&format!("param p{k} = 0.5 in 0..1\n"));
        }
        src.push_str("rgb(p0*NH + p1*NL, p2*NV*p3, p4 + p5*p6*NH)");
        let f = crate::front::parse("t.brdf", &src).unwrap();
        let g = Gradient::compile(&f, &Options { backend: Backend::Interp, ..Options::default() }).unwrap();
        // 8 parameters (n and p0..p6) and 3 inputs: 12 outputs per channel, 36 in all, in three programs.
        assert_eq!((g.channels, g.vars.len(), g.parts.len()), (3, 11, 3));
        let mut x = [0.0; N_INPUTS];
        x[Input::NH.index()] = 0.5;
        x[Input::NL.index()] = 0.25;
        x[Input::NV.index()] = 1.0;
        let p = [50.0, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7];
        let (v, d) = g.eval(&x, &p);
        assert_eq!(v, vec![0.1 * 0.5 + 0.2 * 0.25, 0.3 * 1.0 * 0.4, 0.5 + 0.6 * 0.7 * 0.5]);
        let names = g.names();
        let at = |n: &str| d[names.iter().position(|m| m == n).unwrap()].clone();
        assert_eq!(at("p0"), vec![0.5, 0.0, 0.0]);
        assert_eq!(at("p6"), vec![0.0, 0.0, 0.6 * 0.5]);
        assert_eq!(at("NH"), vec![0.1, 0.0, 0.6 * 0.7]);
    }
}
