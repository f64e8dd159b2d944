//! A multi-output program ([`crate::backend::program`]) → one batched function over data columns with
//! several outputs:
//!
//! `extern "C" fn(cols: *const *const f64, params, block, outs: *const *mut f64, len: usize)`
//!
//! the batched kernel's loop (`batch_loop`: F64X2 body, one F64 tail element), preceded, when the program
//! calls the math library or has several regions, by its wide step of four vectors, their nodes interleaved
//! ([`interleaves`]);
//! the same translator (so the lanes, the hoisted invariants and the prepared parameter block, and the inline
//! math library are the kernel's), reading `Node::Column(k)` from `cols[k]` and storing each output to
//! `outs[o]`. A guarded region is a branch on `any(lit)` over the step's lanes: its nodes are translated in a
//! block of their own, and its outputs reach the rest through the join block's parameters (+0 when the branch
//! is not taken); the outer values it reads are pinned before the first region that reads them
//! ([`anchors`]), so they are computed once per element.
//!
//! Cost: per element the program's own operations plus one 16-byte store per
//! anchored value; the interleaved loop costs spills (16 vector registers for four vectors' live values) and wins
//! where latency dominates (measured: BENCHMARKS.md).
//!
//! A child of `codegen`, so it uses the translator's private parts and its one loop builder as they are. The
//! program's plan, the columns it reads and its step (the nodes in order, each region's nodes between its
//! branch and its join) are the native layer's, shared with the LLVM tier ([`Plan::of_program`],
//! [`frame::program_columns`], [`frame::program_step`]); this tier's are the branch, the join and the anchors.

use super::*;
use crate::backend::program::{Class, Program, Region, MAX_COLUMNS};
use crate::backend::native::frame::ProgramStep;
use crate::backend::native::lower;
use crate::backend::native::ops::Branch;
use crate::backend::native::plan::calls_math;
use cranelift_codegen::ir::{Block, StackSlotData, StackSlotKind};

/// `fn(cols: *const *const f64, params: *const f64, block: *const f64, outs: *const *mut f64, len: usize)`.
pub(in crate::backend::jit) fn signature(module: &JITModule) -> Signature {
    super::signature(module, 5, false)
}

/// Builds the program's function (see the module doc; the loop: [`batch_loop`], [`STEP`] vectors per wide
/// step when [`interleaves`] holds).
pub(in crate::backend::jit) fn build(
    module: &mut JITModule,
    ctx: &mut Context,
    fctx: &mut FunctionBuilderContext,
    w: &Build,
    p: &Program,
) -> Result<(), NativeError> {
    let ptr = module.target_config().pointer_type();
    let plan = w.plan;
    let (mut b, callees, args) = begin(module, ctx, fctx, signature(module), w.imports);
    let [cols, params, block, outs, len] = args[..] else { return Err(NativeError::internal("program signature")) };

    let bases = column_bases::<MAX_COLUMNS>(&mut b, ptr, cols, frame::program_columns(p)?);
    let out_bases: Vec<Value> = (0..p.outputs.len()).map(|k| b.ins().load(ptr, mem(), outs, (k * 8) as i32)).collect();
    let zero = b.ins().iconst(ptr, 0);
    let mut cx = w.shared(params, block, callees);
    let splats = entry(&mut b, &mut cx, plan, Source::Data { bases, off: zero })?;
    let (first, count) = anchors(p);
    let slot = b.create_sized_stack_slot(StackSlotData::new(StackSlotKind::ExplicitSlot, (16 * STEP * count.max(1)) as u32, 4));
    let anchor = b.ins().stack_addr(ptr, slot, 0);
    let step = Step { cx: &cx, p, bases, outs: &out_bases, anchor, first: &first, stride: 16 * count as i32 };
    // With transcendental math or several regions: STEP vectors per step while that many remain, then
    // one vector and one element.
    let wide = if interleaves(p) { STEP } else { 1 };
    batch_loop(&mut b, ptr, len, zero, splats, cx.invariants.clone(), &step, wide)?;
    b.finalize(module.target_config());
    Ok(())
}

/// Vectors the main loop interleaves ([`interleaves`]; a power of two; four measured faster than two on
/// Cook–Torrance and no slower elsewhere: BENCHMARKS.md).
const STEP: usize = 4;

/// Whether the main loop interleaves [`STEP`] vectors: when the program calls the math library or has several
/// regions (lights, in the renderer's programs). Cranelift schedules no instructions, so one vector's long
/// chains (roots, divisions, the library's polynomials: hundreds of cycles from the loads to the outputs) leave
/// the core idle unless an independent vector's instructions sit beside them in program order; interleaving
/// costs registers (more spills), which one region of cheap arithmetic does not win back (measured: BENCHMARKS.md §7).
fn interleaves(p: &Program) -> bool {
    p.regions.len() > 1 || calls_math(p)
}

/// One step of the program's loop, whatever its lane type.
struct Step<'a> {
    cx: &'a Shared<'a>,
    p: &'a Program,
    bases: [Option<Value>; MAX_COLUMNS],
    outs: &'a [Value],
    /// The address of a scratch slot the outer values regions read are stored to ([`anchors`]).
    anchor: Value,
    first: &'a [Vec<(NodeId, i32)>],
    /// Bytes of the anchor slot one copy uses.
    stride: i32,
}

impl LoopBody for Step<'_> {
    /// The step for the vectors at indices `at` (one copy each, their instructions interleaved node by
    /// node): the native layer's [`frame::program_step`] over the copies, then the stores.
    fn emit<L: Lanes>(&self, b: &mut FunctionBuilder, vals: Vec<Vec<Option<Value>>>, at: &[Value]) -> Result<(), NativeError> {
        let offs: Vec<Value> = at.iter().map(|i| b.ins().ishl_imm_u(*i, 3)).collect();
        let src = offs.iter().map(|&off| Source::Data { bases: self.bases, off }).collect();
        let mut k = Copies::<L> { step: self, b, vals, src, lanes: PhantomData };
        frame::program_step(&mut k, self.p)?;
        for (c, off) in offs.iter().enumerate() {
            for (o, base) in self.p.outputs.iter().zip(self.outs) {
                let v = arg(&k.vals[c], *o)?;
                let dst = k.b.ins().iadd(*base, *off);
                k.b.ins().store(mem(), v, dst, 0);
            }
        }
        Ok(())
    }
}

/// The copies of one step in lane type `L`: their translation tables and column sources (swapped in and out
/// of one translator per node), and the builder.
struct Copies<'s, 'a, 'f, L> {
    step: &'s Step<'a>,
    b: &'s mut FunctionBuilder<'f>,
    vals: Vec<Vec<Option<Value>>>,
    src: Vec<Source>,
    lanes: PhantomData<L>,
}

impl<'f, L: Lanes> Copies<'_, '_, 'f, L> {
    /// A translator over the builder for [`Branch`]'s branch and join (which read no node).
    fn brancher(&mut self) -> Result<Translator<'_, 'f, L>, NativeError> {
        let src = *self.src.first().ok_or(NativeError::internal("a step of no vectors"))?;
        Ok(self.step.cx.translator::<L>(self.b, vec![], src))
    }
}

/// A region of the copies: `any(lit ≠ 0 in some copy) ? region's outputs : +0`, every copy's nodes
/// (interleaved) in a block of their own; first the outer values it is the first to read are stored to the
/// anchor slot ([`anchors`]). A copy with no lit lane may run the region too: its outputs are then the
/// selects' +0. The join's block parameters carry the outputs.
impl<L: Lanes> ProgramStep for Copies<'_, '_, '_, L> {
    /// The tables from before the region, and the branch (its join and the join's parameters).
    type Open = (Vec<Vec<Option<Value>>>, (Block, Vec<Value>));
    fn node(&mut self, id: NodeId) -> Result<(), NativeError> {
        for c in 0..self.vals.len() {
            let mut t = self.step.cx.translator::<L>(self.b, std::mem::take(&mut self.vals[c]), self.src[c]);
            let v = lower::node(&mut t, id);
            self.vals[c] = std::mem::take(&mut t.vals);
            v?;
        }
        Ok(())
    }
    fn open(&mut self, r: usize, region: &Region) -> Result<Self::Open, NativeError> {
        let (s, b) = (self.step, &mut *self.b);
        let first = s.first.get(r).ok_or(NativeError::internal("a region without its anchors"))?;
        for (c, vals) in self.vals.iter().enumerate() {
            for &(a, off) in first {
                b.ins().store(mem(), arg(vals, a)?, s.anchor, off + c as i32 * s.stride);
            }
        }
        let z = L::konst(b, 0);
        let mut any_mask = None;
        for vals in &self.vals {
            let m = b.ins().fcmp(FloatCC::NotEqual, arg(vals, region.lit)?, z);
            any_mask = Some(any_mask.map_or(m, |a| b.ins().bor(a, m)));
        }
        let any = any_mask.ok_or(NativeError::internal("a step of no vectors"))?;
        let zeros = vec![z; self.vals.len() * region.outputs.len()];
        let open = self.brancher()?.branch_any(any, &zeros, false);
        Ok((self.vals.clone(), open))
    }
    fn close(&mut self, region: &Region, (saved, open): Self::Open) -> Result<(), NativeError> {
        let mut outs = vec![];
        for vals in &self.vals {
            for o in &region.outputs {
                outs.push(arg(vals, *o)?);
            }
        }
        let params = self.brancher()?.join(open, &outs);
        self.vals = saved;
        for (c, vals) in self.vals.iter_mut().enumerate() {
            for (j, o) in region.outputs.iter().enumerate() {
                vals[o.index()] = Some(params[c * region.outputs.len() + j]);
            }
        }
        Ok(())
    }
}

/// The value of an already translated node in one copy's table.
fn arg(vals: &[Option<Value>], id: NodeId) -> Result<Value, NativeError> {
    vals.get(id.index()).copied().flatten().ok_or_else(|| NativeError::Internal(format!("operand t{} used before it was translated", id.0)))
}

/// The outer values guarded regions read, each with its own offset in the anchor slot, listed under the
/// first region that reads it; and how many there are.
///
/// Cranelift places a pure value where its first use is reached in dominator order, so a value several
/// regions share (NV, 1/|v|, …) and nothing outside them uses would be computed inside the first region's
/// block and again inside each later one, which that block does not dominate. Storing it (a fixed use,
/// never read; distinct offsets, so no store is dead) before the first region's branch keeps it there,
/// computed once per element.
fn anchors(p: &Program) -> (Vec<Vec<(NodeId, i32)>>, usize) {
    let mut seen = vec![false; p.ir.len()];
    let mut count = 0;
    let first = p
        .regions
        .iter()
        .map(|r| {
            let mut mine = vec![];
            for id in &r.nodes {
                p.ir.node(*id).for_each_arg(|a| {
                    if p.class[a.index()] == Class::Outer && !std::mem::replace(&mut seen[a.index()], true) {
                        mine.push((a, 16 * count as i32));
                        count += 1;
                    }
                });
            }
            mine
        })
        .collect();
    (first, count)
}
