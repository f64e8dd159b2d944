//! What a native kernel or program computes where: the prepared parameter block's nodes, the entry's, the
//! loop's, and whether the math library is inlined or called. Both tiers build exactly these plans, so they
//! compute the same nodes in the same places.

use super::NativeError;
use crate::backend::program::Program;
use crate::builtins::Lowering;
use crate::ir::{Ir, Node, NodeId};

/// Above this many math-library call sites a formula calls the library instead of inlining it: inlined, each
/// site is 20–200 instructions and the compiler's time grows with them (Cranelift: ~5 ms per `sin`), so a
/// 3 000-term formula would take seconds to compile; called, each site is one call per lane, and the results
/// are the same bits.
pub const OUTLINE_AT: usize = 24;

/// Math-library call sites in `ir`.
fn math_calls(ir: &Ir) -> usize {
    ir.nodes().iter().filter(|n| matches!(n, Node::Call(b, _) if b.info().lowering == Lowering::Math)).count()
}

/// Whether `ir`'s math builtins are called rather than inlined ([`OUTLINE_AT`]).
pub(crate) fn outlines(ir: &Ir) -> bool {
    math_calls(ir) > OUTLINE_AT
}

/// Whether a program calls the math library instead of inlining it: [`OUTLINE_AT`] applies per copy of the
/// formula (one per region: a light in the renderer's programs), so more regions do not switch a formula to
/// calls.
pub(crate) fn program_outlines(p: &Program) -> bool {
    math_calls(&p.ir) / p.regions.len().max(1) > OUTLINE_AT
}

/// Whether the program calls the math library at all (inline or outlined).
pub(crate) fn calls_math(p: &Program) -> bool {
    math_calls(&p.ir) > 0
}

/// Where each node of a compacted IR is computed: the prepared parameter block or the kernels.
///
/// Nodes that read no input are *invariant*. The non-trivial ones a kernel needs (read by an input-dependent
/// node, or the root itself when the formula reads no input) are *carried*: the prepare function computes them
/// once per parameter set into a block of `f64`s, and the kernels load them from there, so per-call and
/// per-element work is only what depends on the inputs. Constants and bare parameters are not carried (a
/// constant is an immediate, a parameter one load).
pub(crate) struct Plan {
    inv: Vec<bool>,
    /// Block slot of each carried node, in block order.
    pub(crate) carried: Vec<NodeId>,
    pub(crate) root: NodeId,
    /// Whether each node is a constant or a bare parameter.
    trivial: Vec<bool>,
}

impl Plan {
    /// The plan of a kernel: `ir` compacted, `root` its last node.
    pub(crate) fn new(ir: &Ir, root: NodeId) -> Plan {
        let n = root.index() + 1;
        let inv = ir.invariant();
        let mut needed = vec![false; ir.len()];
        for id in ir.ids().take(n) {
            if !inv[id.index()] {
                ir.node(id).for_each_arg(|a| needed[a.index()] |= inv[a.index()]);
            }
        }
        needed[root.index()] |= inv[root.index()];
        let trivial: Vec<bool> = ir.nodes().iter().map(|n| matches!(n, Node::Const(_) | Node::Param(_))).collect();
        let carried = ir.ids().take(n).filter(|id| needed[id.index()] && !trivial[id.index()]).collect();
        Plan { inv, carried, root, trivial }
    }

    /// The plan of a multi-output program: the kernel's over the whole arena, plus every output that reads no
    /// column and is not a bare constant or parameter (the loop stores it from the block).
    pub(crate) fn of_program(p: &Program) -> Result<Plan, NativeError> {
        let last = p.ir.len().checked_sub(1).ok_or(NativeError::internal("empty program"))?;
        let mut plan = Plan::new(&p.ir, NodeId(last as u32));
        for &o in &p.outputs {
            if !plan.variant(o) && !plan.trivial[o.index()] && !plan.carried.contains(&o) {
                plan.carried.push(o);
            }
        }
        Ok(plan)
    }

    /// Nodes up to the root, the range every function walks.
    pub(crate) fn len(&self) -> usize {
        self.root.index() + 1
    }

    /// Whether node `id` is computed per call / per element (reads an input).
    pub(crate) fn variant(&self, id: NodeId) -> bool {
        !self.inv[id.index()]
    }

    /// Whether the prepare function computes `id` (every invariant node; it stores the carried ones).
    pub(crate) fn in_prepare(&self, id: NodeId) -> bool {
        !self.variant(id)
    }

    /// Whether a batched function computes `id` in its entry, before the loop: an invariant constant or
    /// parameter (the carried nodes are loaded from the block there).
    pub(crate) fn in_entry(&self, id: NodeId) -> bool {
        !self.variant(id) && self.trivial[id.index()]
    }

    /// Whether the scalar kernel computes `id`: what varies, and the constants and parameters it reads
    /// (the carried nodes are loaded from the block).
    pub(crate) fn in_scalar(&self, id: NodeId) -> bool {
        self.variant(id) || self.trivial[id.index()]
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::base::span::Span;
    use crate::builtins::Builtin;
    use crate::ir::{BinOp, Input};

    /// `pow(NH, n·2) · (n + 1)`: `n·2` and `n + 1` are carried, `n` and the constants are computed in the
    /// entry, the rest per element.
    #[test]
    fn carries_parameter_only_work() {
        let s = Span::default();
        let mut ir = Ir::new();
        let (x, n, two, one) = (ir.input(Input::NH, s), ir.param(0, s), ir.konst(2.0, s), ir.konst(1.0, s));
        let e = ir.bin(BinOp::Mul, n, two, s);
        let p = ir.call(Builtin::Pow, &[x, e], s);
        let k = ir.bin(BinOp::Add, n, one, s);
        let r = ir.bin(BinOp::Mul, p, k, s);
        let plan = Plan::new(&ir, r);
        assert_eq!(plan.carried, vec![e, k]);
        assert!(plan.in_entry(n) && plan.in_entry(two) && !plan.in_entry(e));
        assert!(plan.in_prepare(e) && !plan.in_prepare(p));
        assert!(plan.in_scalar(p) && plan.in_scalar(n) && !plan.in_scalar(e));
        assert_eq!(plan.len(), ir.len());
    }

    /// A formula that reads no input carries its root.
    #[test]
    fn an_invariant_root_is_carried() {
        let s = Span::default();
        let mut ir = Ir::new();
        let n = ir.param(0, s);
        let r = ir.call(Builtin::Sqrt, &[n], s);
        assert_eq!(Plan::new(&ir, r).carried, vec![r]);
    }
}
