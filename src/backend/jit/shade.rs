//! A shading program ([`crate::backend::shading`]) → one batched function over data columns with several
//! outputs:
//!
//! `extern "C" fn(cols: *const *const f64, params, block, outs: *const *mut f64, len: usize)`
//!
//! the same loop shape as the batched kernel (F64X2 body, one F64 tail element), the same translator (so the
//! lanes, the hoisted invariants and the prepared parameter block, and the inline math library are the
//! kernel's), reading `Node::Column(k)` from `cols[k]` and storing each output to `outs[o]`. A guarded region
//! is a branch on `any(lit)` over the vector's lanes: its nodes are translated in a block of their own, and
//! its outputs reach the rest through the join block's parameters (+0 when the branch is not taken).
//!
//! A child of `codegen`, so it uses the translator's private parts as they are; codegen only gained the
//! `Source::Data` variant and the `Node::Column` arm.

use super::*;
use crate::backend::shading::{Class, Program, Region, N_OUTPUTS};
pub use crate::backend::shading::MAX_COLUMNS;

/// The carried-node plan of a program: the kernel's plan over the whole arena, plus every output that reads
/// no column and is not a bare constant or parameter (the loop stores it from the block).
pub(in crate::backend::jit) fn plan(p: &Program) -> Result<Plan, JitError> {
    let last = NodeId(p.ir.len().checked_sub(1).ok_or(JitError::Internal("empty shading program".into()))? as u32);
    let mut plan = Plan::new(&p.ir, last);
    for o in p.outputs {
        let trivial = matches!(p.ir.node(o), Node::Const(_) | Node::Param(_));
        if !plan.variant(o) && !trivial && !plan.carried.contains(&o) {
            plan.carried.push(o);
        }
    }
    Ok(plan)
}

/// Whether the program calls the math library instead of inlining it: [`OUTLINE_AT`] applies per copy of
/// the formula (one per light region), so a scene with more lights does not switch its formula to calls.
pub(in crate::backend::jit) fn outlines(p: &Program) -> bool {
    let calls = p.ir.nodes().iter().filter(|n| matches!(n, Node::Call(b, _) if b.info().lowering == Lowering::Math)).count();
    calls / p.regions.len().max(1) > OUTLINE_AT
}

/// `fn(cols: *const *const f64, params: *const f64, block: *const f64, outs: *const *mut f64, len: usize)`.
pub(in crate::backend::jit) fn signature(module: &JITModule) -> Signature {
    super::signature(module, 5, false)
}

/// Builds the program's function (see the module doc; the loop is [`batch_loop`]).
pub(in crate::backend::jit) fn build(
    module: &mut JITModule,
    ctx: &mut Context,
    fctx: &mut FunctionBuilderContext,
    w: &Build,
    p: &Program,
) -> Result<(), JitError> {
    let ptr = module.target_config().pointer_type();
    let (ir, plan) = (w.ir, w.plan);
    let n = ir.len();
    let (mut b, callees, args) = begin(module, ctx, fctx, signature(module), w.imports);
    let [cols, params, block, outs, len] = args[..] else { return Err(JitError::Internal("program signature".into())) };

    let mut bases = [None; MAX_COLUMNS];
    for (k, base) in bases.iter_mut().enumerate().take(p.columns.min(MAX_COLUMNS)) {
        *base = Some(b.ins().load(ptr, mem(), cols, (k * 8) as i32));
    }
    let out_bases: Vec<Value> = (0..N_OUTPUTS).map(|k| b.ins().load(ptr, mem(), outs, (k * 8) as i32)).collect();
    let zero = b.ins().iconst(ptr, 0);
    let mut cx = Shared { ir, params, callees, invariants: vec![], mode: w.mode, fma: w.fma, outline: w.outline };
    let vals = plan.load_carried(&mut b, block, n);
    let mut t = cx.translator::<F64>(&mut b, vals, Source::Data { bases, off: zero });
    t.nodes(n, |id| !plan.variant(id) && matches!(ir.node(id), Node::Const(_) | Node::Param(_)))?;
    cx.invariants = std::mem::take(&mut t.vals);
    let mut splats = vec![None; n];
    for id in ir.ids() {
        if let (false, Some(s)) = (plan.variant(id), cx.invariants[id.index()]) {
            splats[id.index()] = Some(V::splat(&mut b, s));
        }
    }
    let step = Step { cx: &cx, p, bases, outs: &out_bases };
    batch_loop(&mut b, ptr, len, zero, splats, cx.invariants.clone(), &step)?;
    b.finalize(module.target_config());
    Ok(())
}

/// One step of the program's loop, whatever its lane type.
struct Step<'a> {
    cx: &'a Shared<'a>,
    p: &'a Program,
    bases: [Option<Value>; MAX_COLUMNS],
    outs: &'a [Value],
}

impl LoopBody for Step<'_> {
    /// The outer nodes in order, each region where the walk reaches its last output, then the stores.
    fn emit<L: Lanes>(&self, b: &mut FunctionBuilder, vals: Vec<Option<Value>>, i: Value) -> Result<(), JitError> {
        let off = b.ins().ishl_imm_u(i, 3);
        let mut t = self.cx.translator::<L>(b, vals, Source::Data { bases: self.bases, off });
        let mut next = 0;
        for id in self.p.ir.ids() {
            if self.p.class[id.index()] == Class::Outer {
                t.node(id)?;
            }
            while let Some(r) = self.p.regions.get(next).filter(|r| r.at == id) {
                region(&mut t, r)?;
                next += 1;
            }
        }
        for (o, base) in self.p.outputs.iter().zip(self.outs) {
            let v = t.arg(*o)?;
            let dst = t.b.ins().iadd(*base, off);
            t.b.ins().store(mem(), v, dst, 0);
        }
        Ok(())
    }
}

/// `any(lit ≠ 0) ? region's outputs : +0`, the region's nodes in a block of their own.
fn region<L: Lanes>(t: &mut Translator<'_, '_, L>, r: &Region) -> Result<(), JitError> {
    let lit = t.arg(r.lit)?;
    let z = L::konst(t.b, 0);
    let m = t.b.ins().fcmp(FloatCC::NotEqual, lit, z);
    let any = L::any(t.b, m);
    let inside = t.b.create_block();
    let join = t.b.create_block();
    let params: Vec<Value> = r.outputs.iter().map(|_| t.b.append_block_param(join, L::TY)).collect();
    let zeros: Vec<BlockArg> = r.outputs.iter().map(|_| BlockArg::Value(z)).collect();
    t.b.ins().brif(any, inside, &[], join, &zeros);
    t.b.switch_to_block(inside);
    t.b.seal_block(inside);
    // The region's values live only in its block: later regions recompute what they share with it.
    let saved = t.vals.clone();
    for id in &r.nodes {
        t.node(*id)?;
    }
    let outs = r.outputs.iter().map(|o| t.arg(*o).map(BlockArg::Value)).collect::<Result<Vec<_>, _>>()?;
    t.b.ins().jump(join, &outs);
    t.vals = saved;
    t.b.switch_to_block(join);
    t.b.seal_block(join);
    for (o, v) in r.outputs.iter().zip(params) {
        t.vals[o.index()] = Some(v);
    }
    Ok(())
}
