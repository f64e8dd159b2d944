//! An [`Arith`] emitter that appends hash-consed nodes to an [`Ir`], every node with one span: how the
//! accuracy pass builds its double-double terms ([`crate::builtins::dd`]) and how any code written over
//! `Arith` (the shading frame's input formulas, [`crate::frame`]) becomes IR. Because the arena hash-conses,
//! re-emitting an operation the caller already built (`s = a + b` before `dd::two_sum_err(a, b, s)`) adds no
//! node.

use crate::base::span::Span;
use crate::builtins::dd::Arith;
use crate::builtins::Builtin;
use crate::ir::{BinOp, Ir, NodeId};

/// Appends to `ir`, each node spanning `sp`.
pub(crate) struct IrEmit<'a> {
    pub ir: &'a mut Ir,
    pub sp: Span,
}

impl<'a> IrEmit<'a> {
    pub(crate) fn new(ir: &'a mut Ir, sp: Span) -> IrEmit<'a> {
        IrEmit { ir, sp }
    }
}

impl Arith for IrEmit<'_> {
    type V = NodeId;
    fn konst(&mut self, c: f64) -> NodeId {
        self.ir.konst(c, self.sp)
    }
    fn add(&mut self, a: NodeId, b: NodeId) -> NodeId {
        self.ir.bin(BinOp::Add, a, b, self.sp)
    }
    fn sub(&mut self, a: NodeId, b: NodeId) -> NodeId {
        self.ir.bin(BinOp::Sub, a, b, self.sp)
    }
    fn mul(&mut self, a: NodeId, b: NodeId) -> NodeId {
        self.ir.bin(BinOp::Mul, a, b, self.sp)
    }
    fn div(&mut self, a: NodeId, b: NodeId) -> NodeId {
        self.ir.bin(BinOp::Div, a, b, self.sp)
    }
    fn neg(&mut self, a: NodeId) -> NodeId {
        self.ir.neg(a, self.sp)
    }
    fn sqrt(&mut self, a: NodeId) -> NodeId {
        self.ir.call(Builtin::Sqrt, &[a], self.sp)
    }
    fn fma(&mut self, a: NodeId, b: NodeId, c: NodeId) -> NodeId {
        self.ir.call(Builtin::Fma, &[a, b, c], self.sp)
    }
    fn known(&self, v: NodeId) -> Option<f64> {
        self.ir.node(v).as_const()
    }
    fn positive_select(&mut self, c: NodeId, a: NodeId, b: NodeId) -> NodeId {
        let zero = self.ir.konst(0.0, self.sp);
        let m = self.ir.call(Builtin::Lt, &[zero, c], self.sp);
        self.ir.call(Builtin::Select, &[m, a, b], self.sp)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::builtins::dd;
    use crate::ir::{Input, Node};

    #[test]
    fn sum_error_reuses_the_sum_node() {
        let mut ir = Ir::new();
        let sp = Span::default();
        let (a, b) = (ir.input(Input::NL, sp), ir.input(Input::NV, sp));
        let s = ir.bin(BinOp::Add, a, b, sp);
        let before = ir.len();
        let (s2, _) = dd::two_sum(&mut IrEmit::new(&mut ir, sp), a, b);
        assert_eq!(s2, s);
        // bb, ab, da, db and their sum: five new nodes.
        assert_eq!(ir.len(), before + 5);
        let (p, e) = IrEmit::new(&mut ir, sp).two_prod(a, b);
        assert!(matches!(ir.node(p), Node::Binary(BinOp::Mul, ..)));
        assert!(matches!(ir.node(e), Node::Call(Builtin::Fma, _)));
    }
}
