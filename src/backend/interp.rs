//! The reference interpreter: the semantics every other backend must match.
//!
//! Design: the IR arena is already in topological order, so "compiling" for the interpreter is flattening the
//! live nodes into a `Vec<Instr>` with operand slots resolved to indices into a scratch array; evaluation is
//! one forward loop with a `match` per instruction. Evaluation is in f64; builtins run the table's definition in
//! the interpreter's math mode ([`Builtin::eval_in`]: the math library's code on `f64`), the same code the JIT
//! emits, so the two agree bit for bit.
//!
//! Multi-output programs ([`super::program::Program`]) run through the same instructions ([`ProgramInterp`]):
//! the invariant nodes once per call, then per element the outer nodes and each guarded region whose lit
//! value is non-zero (a skipped region's outputs are +0, as the JIT's branch gives).
//!
//! Cost: one dispatch (the `match`) and one scratch write per live node, so time grows linearly with the
//! simplified formula's size; this per-node overhead is what the JIT removes (measured ratios and times:
//! BENCHMARKS.md).

use crate::builtins::{Builtin, Mode};
use crate::ir::{BinOp, Formula, Node, N_INPUTS};
use super::program::{Class, Program};
use super::{Columns, Evaluator, Prepared};
use std::cell::RefCell;

/// One node's operation, its operands slots of the scratch array.
#[derive(Clone, Copy, Debug)]
enum Instr {
    Const(f64),
    Input(u8),
    Column(u16),
    Param(u16),
    Neg(u32),
    Bin(BinOp, u32, u32),
    Call1(Builtin, u32),
    Call2(Builtin, u32, u32),
    Call3(Builtin, u32, u32, u32),
}

impl Instr {
    fn of(node: Node) -> Instr {
        match node {
            Node::Const(b) => Instr::Const(f64::from_bits(b)),
            Node::Input(i) => Instr::Input(i.index() as u8),
            Node::Column(k) => Instr::Column(k),
            Node::Param(p) => Instr::Param(p),
            Node::Neg(a) => Instr::Neg(a.0),
            Node::Binary(op, a, b) => Instr::Bin(op, a.0, b.0),
            Node::Call(b, a) => match b.arity() {
                1 => Instr::Call1(b, a[0].0),
                2 => Instr::Call2(b, a[0].0, a[1].0),
                _ => Instr::Call3(b, a[0].0, a[1].0, a[2].0),
            },
        }
    }

    /// The value for element `i`: operands from `s`, inputs from `x`, data columns from `cols` (a missing
    /// input, column or parameter reads as NaN, never out of bounds: formulas have no columns, programs no
    /// inputs).
    #[inline(always)]
    fn exec(self, s: &[f64], x: &[f64], cols: &[&[f64]], i: usize, params: &[f64], mode: Mode) -> f64 {
        match self {
            Instr::Const(c) => c,
            Instr::Input(k) => x.get(k as usize).copied().unwrap_or(f64::NAN),
            Instr::Column(k) => cols.get(k as usize).and_then(|c| c.get(i)).copied().unwrap_or(f64::NAN),
            Instr::Param(p) => params.get(p as usize).copied().unwrap_or(f64::NAN),
            Instr::Neg(a) => -s[a as usize],
            Instr::Bin(op, a, b) => op.apply(s[a as usize], s[b as usize]),
            Instr::Call1(f, a) => f.eval_in(mode, &[s[a as usize]]),
            Instr::Call2(f, a, b) => f.eval_in(mode, &[s[a as usize], s[b as usize]]),
            Instr::Call3(f, a, b, c) => f.eval_in(mode, &[s[a as usize], s[b as usize], s[c as usize]]),
        }
    }
}

/// A flattened formula ready for interpretation.
#[derive(Clone, Debug)]
pub struct Interp {
    code: Vec<Instr>,
    /// Which definition of the transcendental builtins runs.
    mode: Mode,
}

thread_local! {
    static SCRATCH: RefCell<Vec<f64>> = const { RefCell::new(Vec::new()) };
}

impl Interp {
    /// The interpreter in precise math mode.
    pub fn new(f: &Formula) -> Interp {
        Interp::with_mode(f, Mode::Precise)
    }

    pub fn with_mode(f: &Formula, mode: Mode) -> Interp {
        let (ir, root) = f.ir.compact(f.root);
        // A data column (formulas have none) reads as NaN, like a missing input.
        let code = ir.nodes().iter().map(|n| Instr::of(*n)).collect::<Vec<_>>();
        debug_assert_eq!(root.index() + 1, code.len(), "compact puts the root last");
        Interp { code, mode }
    }

    fn run(&self, x: &[f64; N_INPUTS], params: &[f64], s: &mut Vec<f64>) -> f64 {
        s.clear();
        for ins in &self.code {
            let v = ins.exec(s, x, &[], 0, params, self.mode);
            s.push(v);
        }
        s.last().copied().unwrap_or(f64::NAN)
    }
}

/// The interpreter bound to one parameter vector, with its own scratch (no thread-local lookup per call).
pub struct PreparedInterp<'a> {
    interp: &'a Interp,
    params: Vec<f64>,
    scratch: RefCell<Vec<f64>>,
}

impl PreparedInterp<'_> {
    #[inline]
    pub(crate) fn eval(&self, x: &[f64; N_INPUTS]) -> f64 {
        match self.scratch.try_borrow_mut() {
            Ok(mut s) => self.interp.run(x, &self.params, &mut s),
            // Re-entrant use (the formula's evaluation calling back into this prepared form): a fresh buffer.
            Err(_) => self.interp.run(x, &self.params, &mut Vec::with_capacity(self.interp.code.len())),
        }
    }
}

impl Evaluator for Interp {
    fn prepare(&self, params: &[f64]) -> Prepared<'_> {
        let scratch = RefCell::new(Vec::with_capacity(self.code.len()));
        Prepared::Interp(PreparedInterp { interp: self, params: params.to_vec(), scratch })
    }

    fn eval(&self, x: &[f64; N_INPUTS], params: &[f64]) -> f64 {
        SCRATCH.with(|s| match s.try_borrow_mut() {
            Ok(mut s) => self.run(x, params, &mut s),
            // Re-entrant use (an evaluator calling another on the same thread): use a fresh buffer.
            Err(_) => self.run(x, params, &mut Vec::with_capacity(self.code.len())),
        })
    }

    fn eval_batch(&self, cols: &Columns, params: &[f64], out: &mut [f64]) {
        let mut s = Vec::with_capacity(self.code.len());
        let mut x = [0.0; N_INPUTS];
        for (i, o) in out.iter_mut().enumerate() {
            for (k, c) in cols.cols.iter().enumerate() {
                x[k] = c.get(i).copied().unwrap_or(0.0);
            }
            *o = self.run(&x, params, &mut s);
        }
    }
}

#[derive(Clone, Copy, Debug)]
enum Step {
    /// Slot `dst` = the instruction's value (its operands are slots of earlier nodes).
    Op(u32, Instr),
    /// If slot `lit` is zero: the slots `outs` (a range of `ProgramInterp::outs`) become +0 and the next
    /// `skip` steps are skipped.
    Guard { lit: u32, skip: u32, outs: (u32, u32) },
}

/// A flattened multi-output program: the reference semantics of [`Program`] (module doc), one loop over its
/// steps per element, its invariants once per call.
#[derive(Clone, Debug)]
pub struct ProgramInterp {
    invariant: Vec<(u32, Instr)>,
    steps: Vec<Step>,
    outs: Vec<u32>,
    outputs: Vec<u32>,
    len: usize,
    columns: usize,
    mode: Mode,
}

impl ProgramInterp {
    pub(crate) fn new(p: &Program, mode: Mode) -> ProgramInterp {
        let mut invariant = vec![];
        let mut steps = vec![];
        let mut outs = vec![];
        let mut next = 0;
        for id in p.ir.ids() {
            let ins = Instr::of(*p.ir.node(id));
            match p.class[id.index()] {
                Class::Invariant => invariant.push((id.0, ins)),
                Class::Outer => steps.push(Step::Op(id.0, ins)),
                Class::Guarded => {}
            }
            while let Some(r) = p.regions.get(next).filter(|r| r.at == id) {
                let o0 = outs.len() as u32;
                outs.extend(r.outputs.iter().map(|o| o.0));
                steps.push(Step::Guard { lit: r.lit.0, skip: r.nodes.len() as u32, outs: (o0, outs.len() as u32) });
                steps.extend(r.nodes.iter().map(|n| Step::Op(n.0, Instr::of(*p.ir.node(*n)))));
                next += 1;
            }
        }
        let outputs = p.outputs.iter().map(|o| o.0).collect();
        ProgramInterp { invariant, steps, outs, outputs, len: p.ir.len(), columns: p.columns, mode }
    }

    /// Runs the program on `len` elements: `cols` are the data columns, `outs` one column per output (with
    /// fewer or shorter data columns than the program reads, or fewer outputs than it has, every output is NaN;
    /// an output shorter than `len` gets its first elements).
    pub(crate) fn run(&self, cols: &[&[f64]], params: &[f64], outs: &mut [&mut [f64]], len: usize) {
        if cols.len() < self.columns || cols[..self.columns].iter().any(|c| c.len() < len) || outs.len() < self.outputs.len() {
            outs.iter_mut().for_each(|o| o.iter_mut().for_each(|x| *x = f64::NAN));
            return;
        }
        let mut s = vec![0.0; self.len];
        for &(d, ins) in &self.invariant {
            s[d as usize] = ins.exec(&s, &[], cols, 0, params, self.mode);
        }
        for i in 0..len {
            let mut k = 0;
            while k < self.steps.len() {
                match self.steps[k] {
                    Step::Op(d, ins) => s[d as usize] = ins.exec(&s, &[], cols, i, params, self.mode),
                    Step::Guard { lit, skip, outs: (a, b) } => {
                        if s[lit as usize] == 0.0 {
                            for o in &self.outs[a as usize..b as usize] {
                                s[*o as usize] = 0.0;
                            }
                            k += skip as usize;
                        }
                    }
                }
                k += 1;
            }
            for (o, &slot) in outs.iter_mut().zip(&self.outputs) {
                if let Some(x) = o.get_mut(i) {
                    *x = s[slot as usize];
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::base::span::Span;
    use crate::ir::{Input, Ir, Meta, ParamDecl, ParamKind};

    fn blinn() -> Formula {
        let mut ir = Ir::new();
        let s = Span::default();
        let nh = ir.input(Input::NH, s);
        let n = ir.param(0, s);
        let root = ir.call(Builtin::Pow, &[nh, n], s);
        Formula {
            meta: Meta::default(),
            params: vec![ParamDecl { name: "n".into(), default: 50.0, lo: 1.0, hi: 1000.0, span: None, kind: ParamKind::Float }],
            ir,
            root,
            file: "blinn".into(),
            source: String::new(),
            rgb: None,
        }
    }

    fn nh(v: f64) -> [f64; crate::N_INPUTS] {
        let mut x = [0.0; crate::N_INPUTS];
        x[Input::NH.index()] = v;
        x
    }

    #[test]
    fn evaluates_blinn() {
        let i = Interp::new(&blinn());
        let v = i.eval(&nh(0.9), &[2.0]);
        assert!((v - 0.81).abs() < 1e-15);
    }

    #[test]
    fn missing_param_is_nan_not_a_panic() {
        let i = Interp::new(&blinn());
        assert!(i.eval(&nh(0.9), &[]).is_nan());
    }
}
