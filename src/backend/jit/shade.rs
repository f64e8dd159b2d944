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
//! program's plan and the order of a step's nodes and regions are the native layer's, shared with the LLVM
//! tier ([`Plan::of_program`], [`lower::program_step`]).

use super::*;
use crate::backend::program::{Class, Program, Region, MAX_COLUMNS};
use crate::backend::native::lower::Walk;
use crate::backend::native::plan::calls_math;
use cranelift_codegen::ir::{StackSlotData, StackSlotKind};

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
    let (ir, plan) = (w.ir, w.plan);
    let (mut b, callees, args) = begin(module, ctx, fctx, signature(module), w.imports);
    let [cols, params, block, outs, len] = args[..] else { return Err(NativeError::internal("program signature")) };

    let mut bases = [None; MAX_COLUMNS];
    for (k, base) in bases.iter_mut().enumerate().take(p.columns.min(MAX_COLUMNS)) {
        *base = Some(b.ins().load(ptr, mem(), cols, (k * 8) as i32));
    }
    let out_bases: Vec<Value> = (0..p.outputs.len()).map(|k| b.ins().load(ptr, mem(), outs, (k * 8) as i32)).collect();
    let zero = b.ins().iconst(ptr, 0);
    let mut cx = Shared { ir, params, callees, invariants: vec![], mode: w.mode, fma: w.fma, outline: w.outline };
    let splats = entry(&mut b, &mut cx, plan, block, Source::Data { bases, off: zero })?;
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
    fn emit<L: Lanes>(&self, b: &mut FunctionBuilder, vals: Vec<Vec<Option<Value>>>, at: &[Value]) -> Result<(), NativeError> {
        self.emit_copies::<L>(b, vals, at)
    }
}

impl Step<'_> {
    /// Node `id` translated in copy `c` (the copies' tables are swapped in and out of one translator).
    fn on<L: Lanes>(&self, b: &mut FunctionBuilder, k: &mut Copies, c: usize, id: NodeId) -> Result<Value, NativeError> {
        let mut t = self.cx.translator::<L>(b, std::mem::take(&mut k.vals[c]), k.src[c]);
        let v = lower::node(&mut t, id);
        k.vals[c] = std::mem::take(&mut t.vals);
        v
    }

    /// The step for the vectors at indices `at` (one copy each, their instructions interleaved node by
    /// node): the outer nodes in order, each region where the walk reaches its last output, then the stores.
    fn emit_copies<L: Lanes>(&self, b: &mut FunctionBuilder, vals: Vec<Vec<Option<Value>>>, at: &[Value]) -> Result<(), NativeError> {
        let offs: Vec<Value> = at.iter().map(|i| b.ins().ishl_imm_u(*i, 3)).collect();
        let mut k = Copies { vals, src: offs.iter().map(|&off| Source::Data { bases: self.bases, off }).collect() };
        for w in lower::program_step(self.p) {
            match w {
                Walk::Outer(id) => (0..at.len()).try_for_each(|c| self.on::<L>(b, &mut k, c, id).map(drop))?,
                Walk::Region(r, region) => self.region::<L>(b, &mut k, region, &self.first[r])?,
            }
        }
        for (c, off) in offs.iter().enumerate() {
            for (o, base) in self.p.outputs.iter().zip(self.outs) {
                let v = arg(&k.vals[c], *o)?;
                let dst = b.ins().iadd(*base, *off);
                b.ins().store(mem(), v, dst, 0);
            }
        }
        Ok(())
    }

    /// `any(lit ≠ 0 in some copy) ? region's outputs : +0`, the region's nodes (every copy's, interleaved) in a
    /// block of their own; first the outer values it is the first to read are stored to the anchor slot
    /// ([`anchors`]). A copy with no lit lane may run the region too: its outputs are then the selects' +0.
    fn region<L: Lanes>(&self, b: &mut FunctionBuilder, k: &mut Copies, r: &Region, first: &[(NodeId, i32)]) -> Result<(), NativeError> {
        let copies = k.vals.len();
        for (c, vals) in k.vals.iter().enumerate() {
            for &(a, off) in first {
                b.ins().store(mem(), arg(vals, a)?, self.anchor, off + c as i32 * self.stride);
            }
        }
        let z = L::konst(b, 0);
        let mut any_mask = None;
        for vals in &k.vals {
            let m = b.ins().fcmp(FloatCC::NotEqual, arg(vals, r.lit)?, z);
            any_mask = Some(any_mask.map_or(m, |a| b.ins().bor(a, m)));
        }
        let any = L::any(b, any_mask.ok_or(NativeError::internal("a step of no vectors"))?);
        let inside = b.create_block();
        let join = b.create_block();
        let params: Vec<Value> = (0..copies * r.outputs.len()).map(|_| b.append_block_param(join, L::TY)).collect();
        let zeros: Vec<BlockArg> = params.iter().map(|_| BlockArg::Value(z)).collect();
        b.ins().brif(any, inside, &[], join, &zeros);
        b.switch_to_block(inside);
        b.seal_block(inside);
        // The region's values live only in its block.
        let saved = k.vals.clone();
        for id in &r.nodes {
            for c in 0..copies {
                self.on::<L>(b, k, c, *id)?;
            }
        }
        let mut outs = vec![];
        for vals in &k.vals {
            for o in &r.outputs {
                outs.push(BlockArg::Value(arg(vals, *o)?));
            }
        }
        b.ins().jump(join, &outs);
        k.vals = saved;
        b.switch_to_block(join);
        b.seal_block(join);
        for (c, vals) in k.vals.iter_mut().enumerate() {
            for (j, o) in r.outputs.iter().enumerate() {
                vals[o.index()] = Some(params[c * r.outputs.len() + j]);
            }
        }
        Ok(())
    }
}

/// The per-copy translation tables and column sources of one step.
struct Copies {
    vals: Vec<Vec<Option<Value>>>,
    src: Vec<Source>,
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
