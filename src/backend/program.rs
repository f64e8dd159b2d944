//! Multi-output programs: one compacted lobe IR over per-element data columns (`Node::Column` leaves) with
//! several outputs, some of them computed only inside guarded regions. Run by the interpreter
//! ([`super::interp::ProgramInterp`]) and compiled by either native tier (Cranelift: `jit::codegen::shade`;
//! LLVM: `llvm::codegen::build_program`) to one batched function, planned and called by [`super::native`].
//!
//! The backends know nothing of what a program computes (the renderer's lighting model writes one per
//! material: `render::program`); they see the IR, its outputs and its regions.
//!
//! Guarded regions. A region is a set of nodes evaluated only when its `lit` value is non-zero: the nodes
//! reachable only through the region's outputs. A backend evaluates a region when `lit` is non-zero (the
//! interpreter per element, the JIT per vector of lanes: a branch on `any(lit)`), and otherwise takes +0 for
//! its outputs. The builder must make each output +0 wherever `lit` is zero (e.g. `select(lit, x, 0)`), so
//! skipping is invisible in the results and both backends agree bit for bit.
//!
//! Classes. Nodes that read no column are invariant (once per call), the rest are computed per element
//! outside every region (outer) or inside one (guarded). Work several regions need is outer, computed once.

use crate::ir::{Ir, Node, NodeId};

/// Most data columns a program may read.
pub(crate) const MAX_COLUMNS: usize = 16;

/// Most outputs a program may have.
pub(crate) const MAX_OUTPUTS: usize = 16;

/// A region of nodes evaluated only when `lit` is non-zero (module doc).
#[derive(Clone, Debug, PartialEq)]
pub struct Region {
    pub lit: NodeId,
    /// The values leaving the region (+0 when it is skipped).
    pub outputs: Vec<NodeId>,
    /// The region's nodes in order (those reachable from `outputs` that are neither invariant nor outer).
    pub nodes: Vec<NodeId>,
    /// Emitted when the walk over the arena reaches this node (the last of `outputs`).
    pub at: NodeId,
}

/// Where a node is computed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Class {
    /// Reads no column: computed once per call (constants, parameters, parameter-only work).
    Invariant,
    /// Computed for every element.
    Outer,
    /// Computed inside guarded regions only.
    Guarded,
}

/// A multi-output program: a compacted IR (every node live) with its outputs and guarded regions.
#[derive(Clone, Debug)]
pub struct Program {
    pub ir: Ir,
    pub outputs: Vec<NodeId>,
    pub regions: Vec<Region>,
    pub class: Vec<Class>,
    /// Data columns read (`max index + 1`).
    pub columns: usize,
    /// Parameter slots the program's formulas declare.
    pub n_params: usize,
}

impl Program {
    /// Parameter slots a run must supply: those the program's formulas declare, and every slot it reads.
    pub(crate) fn params_read(&self) -> usize {
        let read = self.ir.nodes().iter().filter_map(|n| if let Node::Param(k) = n { Some(*k as usize + 1) } else { None }).max();
        read.unwrap_or(0).max(self.n_params)
    }

    /// The program computing `outputs` of `ir`, with `guarded` = (lit, outputs) regions (module doc); compacts
    /// the IR to the live nodes. Regions whose order does not allow guarding are dropped (their nodes are then
    /// computed for every element: the same values).
    pub(crate) fn new(ir: &Ir, outputs: &[NodeId], guarded: &[(NodeId, Vec<NodeId>)], n_params: usize) -> Result<Program, String> {
        if outputs.is_empty() || outputs.len() > MAX_OUTPUTS {
            return Err(format!("a program has 1 to {MAX_OUTPUTS} outputs, not {}", outputs.len()));
        }
        let len = ir.len();
        let inside = |id: &NodeId| id.index() < len;
        if !outputs.iter().all(inside) || !guarded.iter().all(|(l, o)| inside(l) && o.iter().all(inside)) {
            return Err("a program's output or region is outside its IR".into());
        }
        let mut roots: Vec<NodeId> = outputs.to_vec();
        for (lit, o) in guarded {
            roots.push(*lit);
            roots.extend(o);
        }
        let (ir, map) = ir.compact_many(&roots);
        let outs: Vec<NodeId> = map[..outputs.len()].to_vec();
        let mut at = outputs.len();
        let mut regions = vec![];
        for (_, o) in guarded {
            regions.push((map[at], map[at + 1..at + 1 + o.len()].to_vec()));
            at += 1 + o.len();
        }
        let columns = ir.nodes().iter().filter_map(|n| if let Node::Column(k) = n { Some(usize::from(*k) + 1) } else { None }).max().unwrap_or(0);
        if columns > MAX_COLUMNS {
            return Err(format!("a program reads at most {MAX_COLUMNS} data columns, not {columns}"));
        }
        Ok(Program::with_regions(ir, outs, regions, columns, n_params))
    }

    /// Classifies the nodes and builds the regions (dropping them all if their order does not allow guarding).
    fn with_regions(ir: Ir, outputs: Vec<NodeId>, guarded: Vec<(NodeId, Vec<NodeId>)>, columns: usize, n_params: usize) -> Program {
        let len = ir.len();
        let inv = ir.invariant();
        // Deduplicated regions whose outputs all vary (a region of invariant values guards nothing).
        let mut guarded: Vec<(NodeId, Vec<NodeId>)> = guarded.into_iter().filter(|(_, o)| !o.is_empty() && o.iter().all(|x| !inv[x.index()])).collect();
        guarded.sort_by_key(|(_, o)| o.iter().max().copied());
        guarded.dedup();
        let classify = |guarded: &[(NodeId, Vec<NodeId>)]| {
            let mut boundary = vec![false; len];
            let mut outer = vec![false; len];
            for (_, o) in guarded {
                o.iter().for_each(|x| boundary[x.index()] = true);
            }
            // Outer: reachable from the outputs (and the lit values) without entering a region's outputs.
            for r in outputs.iter().chain(guarded.iter().map(|(l, _)| l)) {
                if !boundary[r.index()] {
                    outer[r.index()] = true;
                }
            }
            for i in (0..len).rev() {
                if outer[i] {
                    ir.node(NodeId(i as u32)).for_each_arg(|a| {
                        if !boundary[a.index()] {
                            outer[a.index()] = true;
                        }
                    });
                }
            }
            let mut regions = vec![];
            // Nodes several regions need (light-independent work, say) are computed once per element, outside
            // the regions; their operands are then needed by the same regions, so the outer set stays closed
            // under operands.
            let mut needed_by = vec![0u32; len];
            for pass in 0..2 {
                regions.clear();
                for (lit, o) in guarded {
                    let mut mine = vec![false; len];
                    o.iter().for_each(|x| mine[x.index()] = true);
                    let top = o.iter().map(|x| x.index()).max().unwrap_or(0);
                    for i in (0..=top).rev() {
                        if mine[i] {
                            ir.node(NodeId(i as u32)).for_each_arg(|a| {
                                if !outer[a.index()] && !inv[a.index()] {
                                    mine[a.index()] = true;
                                }
                            });
                        }
                    }
                    let nodes: Vec<NodeId> = (0..=top).filter(|i| mine[*i]).map(|i| NodeId(i as u32)).collect();
                    nodes.iter().for_each(|n| needed_by[n.index()] += 1);
                    regions.push(Region { lit: *lit, outputs: o.clone(), nodes, at: NodeId(top as u32) });
                }
                if pass == 0 {
                    for (o, n) in outer.iter_mut().zip(&needed_by) {
                        *o |= *n > 1;
                    }
                }
            }
            (outer, regions)
        };
        let (mut outer, mut regions) = classify(&guarded);
        // Guarding needs every outer user of a region's outputs after the region's emission point, and the
        // lit value outer and before it.
        let ok = regions.iter().all(|r| {
            outer[r.lit.index()] && r.lit < r.at && {
                let mut fine = true;
                for (i, _) in outer.iter().enumerate().take(r.at.index()).filter(|(_, o)| **o) {
                    ir.node(NodeId(i as u32)).for_each_arg(|a| fine &= !r.outputs.contains(&a));
                }
                fine
            }
        });
        if !ok {
            (outer, regions) = classify(&[]);
        }
        let class = (0..len)
            .map(|i| if inv[i] { Class::Invariant } else if outer[i] { Class::Outer } else { Class::Guarded })
            .collect();
        Program { ir, outputs, regions, class, columns, n_params }
    }

    /// Every root a compiled program depends on (for the code cache key): outputs, then per region its lit
    /// value and outputs.
    pub(crate) fn roots(&self) -> Vec<NodeId> {
        let mut r = self.outputs.clone();
        for g in &self.regions {
            r.push(g.lit);
            r.extend(&g.outputs);
        }
        r
    }
}
