//! What every native function computes in which order, written once over a tier's few frame primitives: the
//! prepare function, the scalar kernel, a batched function's entry, the kernel's loop step, and a program's
//! step with its guarded regions. A tier keeps only what its instructions make different: declaring a
//! function, its loop over the elements (how it handles the elements after the last full vector), the loads
//! and stores at an element, and the branch and join of a region.
//!
//! The order of the calls below is the order of the instructions each tier emits, so both tiers compute the
//! same nodes in the same places ([`Plan`]) and the interpreter's bits.

use super::lower::{self, Lower, Walk};
use super::ops::Branch;
use super::{NativeError, Plan};
use crate::backend::program::{Program, Region, MAX_COLUMNS};
use crate::ir::{Ir, Node, NodeId};

/// A translator's access to the prepared parameter block ([`Plan::carried`], slot `k` at `block + 8·k`).
pub(crate) trait Frame: Lower {
    /// The `f64` in slot `k` of the block, in every lane.
    fn load_block(&mut self, k: usize) -> Result<Self::V, NativeError>;
    /// Lane 0 of `v` stored to slot `k` of the block (the prepare function, one lane).
    fn store_block(&mut self, k: usize, v: Self::V) -> Result<(), NativeError>;
}

/// The prepare function's body: every invariant node computed, the carried ones stored to the block.
pub(crate) fn prepare<T: Frame>(t: &mut T, plan: &Plan) -> Result<(), NativeError> {
    lower::nodes(t, plan.len(), |id| plan.in_prepare(id))?;
    for (k, id) in plan.carried.iter().enumerate() {
        let v = t.value(*id)?;
        t.store_block(k, v)?;
    }
    Ok(())
}

/// The carried nodes' values loaded from the block into the translator's table.
fn load_carried<T: Frame>(t: &mut T, plan: &Plan) -> Result<(), NativeError> {
    for (k, id) in plan.carried.iter().enumerate() {
        let v = t.load_block(k)?;
        t.set(*id, v)?;
    }
    Ok(())
}

/// The scalar kernel's body: the carried nodes loaded, what the plan computes per call; the root's value.
pub(crate) fn scalar<T: Frame>(t: &mut T, plan: &Plan) -> Result<T::V, NativeError> {
    load_carried(t, plan)?;
    lower::nodes(t, plan.len(), |id| plan.in_scalar(id))?;
    t.value(plan.root)
}

/// A batched function's entry (kernel or program), before its loop: the carried nodes loaded, the invariant
/// constants and parameters computed.
pub(crate) fn entry<T: Frame>(t: &mut T, plan: &Plan) -> Result<(), NativeError> {
    load_carried(t, plan)?;
    lower::nodes(t, plan.len(), |id| plan.in_entry(id))
}

/// One step of a kernel's loop over the invariants already in the table: the nodes that vary per element;
/// the root's value (stored to `out` by the tier's loop).
pub(crate) fn kernel_step<T: Lower>(t: &mut T, plan: &Plan) -> Result<T::V, NativeError> {
    lower::nodes(t, plan.len(), |id| plan.variant(id))?;
    t.value(plan.root)
}

/// The inputs (by index) a kernel reads, whose column bases its batched function loads.
pub(crate) fn kernel_columns(ir: &Ir, plan: &Plan) -> Vec<usize> {
    ir.used_inputs(plan.root).iter().map(|i| i.index()).collect()
}

/// The data columns (by index) a program reads, whose bases its function loads.
pub(crate) fn program_columns(p: &Program) -> Result<Vec<usize>, NativeError> {
    let mut read = [false; MAX_COLUMNS];
    for n in p.ir.nodes() {
        if let Node::Column(k) = n {
            match read.get_mut(usize::from(*k)) {
                Some(r) => *r = true,
                None => return Err(NativeError::Internal(format!("data column {k} beyond the {MAX_COLUMNS} a program may read"))),
            }
        }
    }
    Ok((0..MAX_COLUMNS).filter(|k| read[*k]).collect())
}

/// A program's step as a tier emits it (over one vector or several interleaved copies): node translation,
/// and the branch into and the join out of a guarded region.
pub(crate) trait ProgramStep {
    /// What [`ProgramStep::open`] hands to [`ProgramStep::close`]: the join and the tables from before the
    /// region.
    type Open;
    /// Translates node `id` (in every copy).
    fn node(&mut self, id: NodeId) -> Result<(), NativeError>;
    /// Region `r`: `any(lit ≠ 0)` (not equal or unordered: a NaN lit runs it, as the interpreter's `lit != 0`)
    /// branches to a block of its own, where the builder is left; the other edge goes to the join with +0.
    fn open(&mut self, r: usize, region: &Region) -> Result<Self::Open, NativeError>;
    /// Leaves the region's block for the join with its outputs; from there on the tables are as before the
    /// region (its values live only in its block) plus its outputs, the join's values.
    fn close(&mut self, region: &Region, open: Self::Open) -> Result<(), NativeError>;
}

/// A program's step on one translator (a tier that emits one copy of the step): a region is
/// [`Branch::branch_any`] on `lit ≠ 0` into its block, its outputs the join's values (+0 from the skipping edge).
impl<T: Lower + Branch> ProgramStep for T {
    /// The table from before the region, and the branch.
    type Open = (Vec<Option<T::V>>, <T as Branch>::Open);
    fn node(&mut self, id: NodeId) -> Result<(), NativeError> {
        lower::node(self, id).map(drop)
    }
    fn open(&mut self, _: usize, r: &Region) -> Result<Self::Open, NativeError> {
        let lit = self.value(r.lit)?;
        let m = self.nonzero(lit);
        let zero = self.konst(0.0);
        let open = self.branch_any(m, &vec![zero; r.outputs.len()], false);
        Ok((self.table().to_vec(), open))
    }
    fn close(&mut self, r: &Region, (saved, open): Self::Open) -> Result<(), NativeError> {
        let outs = r.outputs.iter().map(|o| self.value(*o)).collect::<Result<Vec<_>, _>>()?;
        let joined = self.join(open, &outs);
        self.table().copy_from_slice(&saved);
        for (o, v) in r.outputs.iter().zip(joined) {
            self.set(*o, v)?;
        }
        Ok(())
    }
}

/// One step of a program ([`lower::program_step`]'s order): the outer nodes, and each guarded region's nodes
/// between its branch and its join. The outputs are then in the tables, for the tier's stores.
pub(crate) fn program_step<S: ProgramStep>(s: &mut S, p: &Program) -> Result<(), NativeError> {
    for w in lower::program_step(p) {
        match w {
            Walk::Outer(id) => s.node(id)?,
            Walk::Region(r, region) => {
                let open = s.open(r, region)?;
                for id in &region.nodes {
                    s.node(*id)?;
                }
                s.close(region, open)?;
            }
        }
    }
    Ok(())
}
