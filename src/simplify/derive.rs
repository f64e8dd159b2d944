//! Symbolic differentiation of a formula: forward accumulation over the arena.
//!
//! For one variable v (a parameter, or an input), one walk in arena order gives every node its tangent dn/dv
//! from its operands' tangents by the rule of its operation ([`crate::builtins::derive`]: one rule per builtin
//! and per arithmetic operation, the kink choices stated there). The tangents are new nodes pushed into a copy
//! of the formula's arena, so hash-consing shares them with the value's nodes (`sin(x)` of the value and of
//! `d cos(x)` are one node), and a node whose operands do not depend on v has no tangent at all (no node, no
//! cost). The result is an ordinary scalar formula with the original's declarations: callers simplify it,
//! run the accuracy pass on it and compile it exactly as they do the value (`numerics::grad` compiles the
//! value and every partial as one multi-output program).
//!
//! Derive the *lowered* formula, before baking: the derivative with respect to a parameter a run bakes is
//! then still there, and baking folds it afterwards. The lowering's clamps of the inputs to [0, 1]
//! are differentiated like any clamp (inside-closed: ∂/∂NH = 1 on 0 ≤ NH ≤ 1).
//!
//! Cost: one walk per variable, linear in the arena; each tangent node is a handful of nodes (a product rule
//! two multiplications and an addition), guards (a compare and a select) only where a factor may be infinite.

use crate::base::span::Span;
use crate::builtins::derive::{self as rule, Build, Tangent};
use crate::builtins::Builtin;
use crate::ir::{BinOp, Formula, Input, Ir, Node, NodeId};

/// A variable to differentiate by.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Var {
    /// Index into [`Formula::params`].
    Param(u16),
    Input(Input),
}

impl Var {
    /// The variable's name: the parameter's or the input's.
    pub fn name(self, f: &Formula) -> String {
        match self {
            Var::Param(k) => f.params[usize::from(k)].name.clone(),
            Var::Input(i) => i.name().to_string(),
        }
    }
}

/// What a gradient differentiates by: every declared parameter (in declaration order), then every input the
/// formula (each colour channel) reads.
pub fn variables(f: &Formula) -> Vec<Var> {
    let reads: crate::ir::InputSet = f.channels().iter().map(Formula::used_inputs).collect();
    (0..f.params.len() as u16).map(Var::Param).chain(reads.iter().map(Var::Input)).collect()
}

/// [`Build`] over an arena: each rule's nodes carry the span of the node they differentiate.
struct IrBuild<'a> {
    ir: &'a mut Ir,
    span: Span,
}

impl Build for IrBuild<'_> {
    type V = NodeId;
    fn konst(&mut self, v: f64) -> NodeId {
        self.ir.konst(v, self.span)
    }
    fn as_const(&self, v: NodeId) -> Option<f64> {
        self.ir.node(v).as_const()
    }
    fn add(&mut self, a: NodeId, b: NodeId) -> NodeId {
        self.ir.bin(BinOp::Add, a, b, self.span)
    }
    fn sub(&mut self, a: NodeId, b: NodeId) -> NodeId {
        self.ir.bin(BinOp::Sub, a, b, self.span)
    }
    fn mul(&mut self, a: NodeId, b: NodeId) -> NodeId {
        self.ir.bin(BinOp::Mul, a, b, self.span)
    }
    fn div(&mut self, a: NodeId, b: NodeId) -> NodeId {
        self.ir.bin(BinOp::Div, a, b, self.span)
    }
    fn neg(&mut self, a: NodeId) -> NodeId {
        self.ir.neg(a, self.span)
    }
    fn call(&mut self, f: Builtin, args: &[NodeId]) -> NodeId {
        self.ir.call(f, args, self.span)
    }
}

/// ∂f/∂v for a scalar formula `f` (a colour formula: differentiate each of [`Formula::channels`]), as a
/// formula with `f`'s declarations; 0 where f does not depend on v.
pub fn derive(f: &Formula, v: Var) -> Formula {
    let mut ir = f.ir.clone();
    let len = f.root.index() + 1;
    let mut t: Vec<Option<Tangent<NodeId>>> = Vec::with_capacity(len);
    for id in (0..len as u32).map(NodeId) {
        let node = *f.ir.node(id);
        let mut b = IrBuild { ir: &mut ir, span: f.ir.span(id) };
        let one = |b: &mut IrBuild| Some(Tangent::tame(b.konst(1.0)));
        let d = match node {
            Node::Const(_) | Node::Column(_) => None,
            Node::Input(i) => if v == Var::Input(i) { one(&mut b) } else { None },
            Node::Param(k) => if v == Var::Param(k) { one(&mut b) } else { None },
            Node::Neg(a) => rule::neg(&mut b, t[a.index()]),
            Node::Binary(op, x, y) => {
                let (dx, dy) = (t[x.index()], t[y.index()]);
                match op {
                    BinOp::Add => rule::add(&mut b, dx, dy),
                    BinOp::Sub => rule::sub(&mut b, dx, dy),
                    BinOp::Mul => rule::mul(&mut b, x, y, dx, dy),
                    BinOp::Div => rule::div(&mut b, y, id, dx, dy),
                }
            }
            Node::Call(g, args) => {
                let n = g.arity();
                let d: Vec<_> = args[..n].iter().map(|a| t[a.index()]).collect();
                rule::tangent(g, &mut b, &args[..n], id, &d)
            }
        };
        t.push(d);
    }
    let root = match t[f.root.index()] {
        Some(d) => d.v,
        None => ir.konst(0.0, f.ir.span(f.root)),
    };
    let (ir, root) = ir.compact(root);
    Formula { ir, root, rgb: None, ..f.clone() }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::backend::interp::Interp;
    use crate::backend::Evaluator;
    use crate::ir::N_INPUTS;

    fn parse(src: &str) -> Formula {
        crate::front::parse("t.brdf", src).unwrap()
    }

    fn at(f: &Formula, x: &[f64; N_INPUTS], p: &[f64]) -> f64 {
        Interp::new(f).eval(x, p)
    }

    #[test]
    fn derivatives_of_a_small_formula_match_their_closed_forms() {
        let f = parse("param a = 2 in 0.1..10\nexp(-a * (1 - NH)) * sqrt(NL) + pow(NV, a)");
        let mut x = [0.0; N_INPUTS];
        x[Input::NH.index()] = 0.8;
        x[Input::NL.index()] = 0.3;
        x[Input::NV.index()] = 0.6;
        let p = [50.0, 2.0];
        let a = f.param_index("a").unwrap() as u16;
        let e = (-2.0f64 * 0.2).exp();
        let da = at(&derive(&f, Var::Param(a)), &x, &p);
        let want_a = -0.2 * e * 0.3f64.sqrt() + 0.6f64.powf(2.0) * 0.6f64.ln();
        assert!((da - want_a).abs() < 1e-14, "{da} vs {want_a}");
        let dnh = at(&derive(&f, Var::Input(Input::NH)), &x, &p);
        assert!((dnh - 2.0 * e * 0.3f64.sqrt()).abs() < 1e-14);
        let dnl = at(&derive(&f, Var::Input(Input::NL)), &x, &p);
        assert!((dnl - e * 0.5 / 0.3f64.sqrt()).abs() < 1e-14);
        // n is not read: its derivative is the constant 0.
        let dn = derive(&f, Var::Param(0));
        assert_eq!(dn.ir.node(dn.root).as_const(), Some(0.0));
    }

    #[test]
    fn kinks_are_nan_free() {
        // sqrt at NL = 0 where NL moves: +∞; NH·sqrt(NL) with NH = 0: 0, not 0·∞.
        let f = parse("NH * sqrt(NL)");
        let x = [0.0; N_INPUTS];
        let dnl = at(&derive(&f, Var::Input(Input::NL)), &x, &[50.0]);
        assert_eq!(dnl, 0.0);
        let g = parse("sqrt(NL) + acos(NH)");
        let mut x = [0.0; N_INPUTS];
        x[Input::NH.index()] = 1.0;
        x[Input::NL.index()] = 0.0;
        assert_eq!(at(&derive(&g, Var::Input(Input::NL)), &x, &[50.0]), f64::INFINITY);
        // acos at its clamp: 0.
        assert_eq!(at(&derive(&g, Var::Input(Input::NH)), &x, &[50.0]), 0.0);
    }
}
