//! IR → IR rewrites to a fixpoint (placeholder until the simplifier lands: bakes parameters only).

use crate::ir::{Formula, Node};

/// Replaces baked parameters by constants without any other rewrite.
pub fn bake_only(f: &Formula, bake: &[(usize, f64)]) -> Formula {
    let mut ir = crate::ir::Ir::new();
    let mut map = Vec::with_capacity(f.ir.len());
    for id in f.ir.ids() {
        let n = match *f.ir.node(id) {
            Node::Param(p) => match bake.iter().find(|(i, _)| *i == p as usize) {
                Some((_, v)) => Node::constant(*v),
                None => Node::Param(p),
            },
            n => n.map_args(|a| map[a.index()]),
        };
        map.push(ir.push(n, f.ir.span(id)));
    }
    let (ir, root) = ir.compact(map[f.root.index()]);
    Formula { ir, root, ..f.clone() }
}

pub fn simplify(f: &Formula, bake: &[(usize, f64)]) -> Formula {
    bake_only(f, bake)
}
