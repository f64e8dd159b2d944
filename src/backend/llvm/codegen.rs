//! IR → LLVM IR: the tier's primitives over one generator of `<W x double>` lanes (W = 1 for the prepare and
//! scalar functions, the host's lane count for the batch loop), implementing the math library's [`Emit`] and
//! the native layer's [`Lower`], so the node dispatch, the inline builtins and every builtin's code (the
//! definition the interpreter runs on `f64`) are [`crate::backend::native::lower`]'s, emitted in these lanes.
//!
//! The native layer's function shapes ([`crate::backend::native::abi`]):
//! * `lobe_prepare(params: *const f64, block: *mut f64)`: the carried parameter-only nodes ([`Plan`]);
//! * `lobe_scalar(x: *const f64, params, block) -> f64`: a kernel on one point;
//! * `lobe_batch(cols: *const *const f64, params, block, out: *mut f64, len: usize)`: a kernel;
//! * `lobe_program(cols, params, block, outs: *const *mut f64, len: usize)`: a multi-output program;
//!
//! the last two over one loop ([`batch_loop`]).
//!
//! Values are vectors of `W` lanes (`<1 x double>` in the prepare function, which LLVM scalarises); masks are
//! `<W x i1>`; the bit operations work on `<W x i64>`. No instruction carries fast-math flags, and nothing is
//! written as `llvm.fmuladd`, so LLVM neither reassociates, contracts nor approximates: every operation is the
//! IEEE operation the interpreter performs (the tests check the machine code for fused or estimated ops).
//!
//! Where the Cranelift tier calls a Rust function (the library compiled by rustc for outlined call sites and
//! the rare lanes of `expmuldiv`, the C library's trigonometric fallbacks), this calls the same `extern "C"`
//! function, once per lane, through its address as a constant. Errors are collected (the first one, as a
//! [`NativeError`]), never panicked on.

use crate::backend::native::frame::{self, Frame};
use crate::backend::native::lower::{Lower, Scope};
use crate::backend::native::ops::{self, Bits, Branch, Callee, Calls};
use crate::backend::native::{NativeError, Plan};
use crate::backend::program::{Program, MAX_COLUMNS};
use crate::builtins::dd::Arith;
use crate::builtins::math::{self, Emit};
use crate::builtins::{Builtin, Libm, Mode};
use crate::ir::{Input, Ir, N_INPUTS};
use inkwell::attributes::AttributeLoc;
use inkwell::basic_block::BasicBlock;
use inkwell::builder::{Builder, BuilderError};
use inkwell::context::Context;
use inkwell::intrinsics::Intrinsic;
use inkwell::module::Module;
use inkwell::types::{BasicTypeEnum, VectorType};
use inkwell::values::{BasicMetadataValueEnum, BasicValue, BasicValueEnum, FunctionValue, IntValue, PointerValue, VectorValue};
use inkwell::{FloatPredicate, IntPredicate};

/// Names of the functions: a kernel's module has the scalar function and the batch loop, a program's the
/// program loop; both may have the prepare function.
pub(super) const BATCH: &str = "lobe_batch";
pub(super) const PREPARE: &str = "lobe_prepare";
pub(super) const PROGRAM: &str = "lobe_program";
pub(super) const SCALAR: &str = "lobe_scalar";

/// What every function of one module shares.
pub(super) struct Unit<'a, 'ctx> {
    pub cx: &'ctx Context,
    pub module: &'a Module<'ctx>,
    pub ir: &'a Ir,
    pub plan: &'a Plan,
    pub mode: Mode,
    /// The host has a fused multiply-add (exact two-products in two instructions, as the Cranelift tier).
    pub fma: bool,
    /// The host has AVX-512 ([`super::Host::avx512`]).
    pub avx512: bool,
    /// Math builtins are calls to the compiled library ([`crate::backend::native::OUTLINE_AT`]), not inline code.
    pub outline: bool,
    /// `target-cpu` and `target-features` of every function: the host's.
    pub cpu: &'a str,
    pub features: &'a str,
}

/// Translates IR nodes into LLVM values of `W` lanes.
struct Gen<'a, 'ctx> {
    u: &'a Unit<'a, 'ctx>,
    b: Builder<'ctx>,
    func: FunctionValue<'ctx>,
    w: u32,
    /// `<W x double>`, `<W x i64>`, `<W x i1>`.
    fty: VectorType<'ctx>,
    ity: VectorType<'ctx>,
    mty: VectorType<'ctx>,
    params: PointerValue<'ctx>,
    /// The prepared block (written by the prepare function, read by the others).
    block: PointerValue<'ctx>,
    /// The value of each translated node.
    vals: Vec<Option<VectorValue<'ctx>>>,
    /// The loop step's input vectors.
    inputs: [Option<VectorValue<'ctx>>; N_INPUTS],
    /// A program's data columns in the loop step (`Node::Column(k)`).
    columns: Vec<Option<VectorValue<'ctx>>>,
    /// The first error raised (inside an [`Emit`] method, which cannot return one).
    error: Option<NativeError>,
}

impl<'a, 'ctx> Gen<'a, 'ctx> {
    fn new(u: &'a Unit<'a, 'ctx>, func: FunctionValue<'ctx>, w: u32, params: PointerValue<'ctx>, block: PointerValue<'ctx>) -> Self {
        Gen {
            u,
            b: u.cx.create_builder(),
            func,
            w,
            fty: u.cx.f64_type().vec_type(w),
            ity: u.cx.i64_type().vec_type(w),
            mty: u.cx.bool_type().vec_type(w),
            params,
            block,
            vals: vec![None; u.ir.len()],
            inputs: [None; N_INPUTS],
            columns: vec![None; MAX_COLUMNS],
            error: None,
        }
    }

    fn fail(&mut self, e: impl std::fmt::Display) {
        if self.error.is_none() {
            self.error = Some(NativeError::internal(e));
        }
    }

    /// A builder result that is a vector (of the type of `like` on error, after recording it).
    fn vec_of(&mut self, r: Result<BasicValueEnum<'ctx>, BuilderError>, like: VectorType<'ctx>) -> VectorValue<'ctx> {
        match r {
            Ok(BasicValueEnum::VectorValue(v)) => v,
            Ok(other) => {
                self.fail(format!("expected a vector, got {other:?}"));
                like.get_poison()
            }
            Err(e) => {
                self.fail(e);
                like.get_poison()
            }
        }
    }

    fn ok(&mut self, r: Result<VectorValue<'ctx>, BuilderError>, like: VectorType<'ctx>) -> VectorValue<'ctx> {
        r.unwrap_or_else(|e| {
            self.fail(e);
            like.get_poison()
        })
    }

    fn f(&mut self, r: Result<VectorValue<'ctx>, BuilderError>) -> VectorValue<'ctx> {
        self.ok(r, self.fty)
    }

    fn m(&mut self, r: Result<VectorValue<'ctx>, BuilderError>) -> VectorValue<'ctx> {
        self.ok(r, self.mty)
    }

    fn i(&mut self, r: Result<VectorValue<'ctx>, BuilderError>) -> VectorValue<'ctx> {
        self.ok(r, self.ity)
    }

    /// Records a builder error of a statement (store, branch).
    fn done<T>(&mut self, r: Result<T, BuilderError>) {
        if let Err(e) = r {
            self.fail(e);
        }
    }

    fn scalar<T>(&mut self, r: Result<T, BuilderError>, poison: T) -> T {
        r.unwrap_or_else(|e| {
            self.fail(e);
            poison
        })
    }

    fn i64c(&self, v: u64) -> IntValue<'ctx> {
        self.u.cx.i64_type().const_int(v, false)
    }

    fn i32c(&self, v: u64) -> IntValue<'ctx> {
        self.u.cx.i32_type().const_int(v, false)
    }

    /// Every lane the double with bits `bits` (exact: NaN payloads and signed zeros included).
    fn fconst(&self, bits: u64) -> VectorValue<'ctx> {
        let c = self.u.cx.f64_type().const_float(f64::from_bits(bits));
        VectorType::const_vector(&vec![c; self.w as usize])
    }

    fn iconst(&self, v: u64) -> VectorValue<'ctx> {
        VectorType::const_vector(&vec![self.i64c(v); self.w as usize])
    }

    fn all_true(&self) -> VectorValue<'ctx> {
        VectorType::const_vector(&vec![self.u.cx.bool_type().const_int(1, false); self.w as usize])
    }

    /// The scalar `s` in every lane.
    fn splat(&mut self, s: BasicValueEnum<'ctx>, ty: VectorType<'ctx>) -> VectorValue<'ctx> {
        let one = self.b.build_insert_element(ty.get_poison(), s, self.i32c(0), "");
        let one = self.ok(one, ty);
        if self.w == 1 {
            return one;
        }
        let zeros = VectorType::const_vector(&vec![self.u.cx.i32_type().const_zero(); self.w as usize]);
        let r = self.b.build_shuffle_vector(one, ty.get_poison(), zeros, "");
        self.ok(r, ty)
    }

    /// A double loaded from `base + 8·k`, alignment 8.
    fn load_f64(&mut self, base: PointerValue<'ctx>, k: u64) -> BasicValueEnum<'ctx> {
        let p = self.offset(base, self.i64c(8 * k));
        let f = self.u.cx.f64_type();
        let v = self.b.build_load(f, p, "");
        self.scalar(v, f.get_poison().as_basic_value_enum())
    }

    /// `base + bytes` (integer arithmetic on the address: no `getelementptr`, which inkwell marks unsafe).
    fn offset(&mut self, base: PointerValue<'ctx>, bytes: IntValue<'ctx>) -> PointerValue<'ctx> {
        let i64t = self.u.cx.i64_type();
        let ptr = self.u.cx.ptr_type(Default::default());
        let a = self.b.build_ptr_to_int(base, i64t, "");
        let a = self.scalar(a, i64t.get_poison());
        let s = self.b.build_int_add(a, bytes, "");
        let s = self.scalar(s, i64t.get_poison());
        let p = self.b.build_int_to_ptr(s, ptr, "");
        self.scalar(p, ptr.get_poison())
    }

    fn intrinsic(&mut self, name: &str, tys: &[BasicTypeEnum<'ctx>]) -> Option<FunctionValue<'ctx>> {
        let f = Intrinsic::find(name).and_then(|i| i.get_declaration(self.u.module, tys));
        if f.is_none() {
            self.fail(format!("LLVM has no intrinsic {name}"));
        }
        f
    }

    /// A call of the intrinsic `name` overloaded on the lane type, returning a vector of type `ret`.
    fn call_intrinsic(&mut self, name: &str, tys: &[BasicTypeEnum<'ctx>], args: &[BasicMetadataValueEnum<'ctx>], ret: VectorType<'ctx>) -> VectorValue<'ctx> {
        let Some(f) = self.intrinsic(name, tys) else { return ret.get_poison() };
        match self.b.build_call(f, args, "") {
            Ok(c) => match c.try_as_basic_value() {
                inkwell::values::ValueKind::Basic(v) => self.vec_of(Ok(v), ret),
                inkwell::values::ValueKind::Instruction(_) => {
                    self.fail(format!("{name} returned nothing"));
                    ret.get_poison()
                }
            },
            Err(e) => {
                self.fail(e);
                ret.get_poison()
            }
        }
    }

    /// [`Emit::lookup_pair`] of a table of at most 16 rows in eight AVX-512 lanes, by the low bits of `index`
    /// (the bits above are ignored, as the masked index of the gathers ignores them): each column is one
    /// register of constants and one `vpermpd` (up to 8 rows, repeated to fill the register, so the index bits
    /// above the table's are moot), or two registers and one `vpermi2pd` (16 rows). No memory access, where two
    /// gathers took a quarter of exp's time.
    fn permute_pair(&mut self, table: &[[f64; 2]], index: VectorValue<'ctx>) -> (VectorValue<'ctx>, VectorValue<'ctx>) {
        let f64t = self.u.cx.f64_type();
        let n = table.len();
        let reg = |col: usize, first: usize| VectorType::const_vector(&(first..first + 8).map(|j| f64t.const_float(table[j % n][col])).collect::<Vec<_>>());
        let column = |g: &mut Self, col: usize| {
            if n <= 8 {
                g.call_intrinsic("llvm.x86.avx512.permvar.df.512", &[], &[reg(col, 0).into(), index.into()], g.fty)
            } else {
                g.call_intrinsic("llvm.x86.avx512.vpermi2var.pd.512", &[], &[reg(col, 0).into(), index.into(), reg(col, 8).into()], g.fty)
            }
        };
        let heads = column(self, 0);
        (heads, column(self, 1))
    }

    /// [`Emit::lookup_pair`] in a table of at most four rows without AVX-512's permutation: a tree of selects on
    /// `index`'s two low bits (no memory access; a gather per column costs more).
    fn select_pair(&mut self, table: &[[f64; 2]], index: VectorValue<'ctx>) -> (VectorValue<'ctx>, VectorValue<'ctx>) {
        let n = table.len();
        let row = |j: usize| table[j % n];
        let bit = |g: &mut Self, b: u64| {
            let r = g.b.build_and(index, g.iconst(b), "");
            let set = g.i(r);
            let r = g.b.build_int_compare(IntPredicate::NE, set, g.iconst(0), "");
            g.m(r)
        };
        let (b0, b1) = (bit(self, 1), bit(self, 2));
        let column = |g: &mut Self, col: usize| {
            let c = |g: &mut Self, j: usize| g.fconst(row(j)[col].to_bits());
            let (r0, r1, r2, r3) = (c(g, 0), c(g, 1), c(g, 2), c(g, 3));
            let lo = Emit::select(g, b0, r1, r0);
            let hi = Emit::select(g, b0, r3, r2);
            Emit::select(g, b1, hi, lo)
        };
        let heads = column(self, 0);
        (heads, column(self, 1))
    }

    /// A lane-wise floating-point intrinsic (`llvm.sqrt`, `llvm.fma`, `llvm.minimum`, …).
    fn fop(&mut self, name: &str, args: &[VectorValue<'ctx>]) -> VectorValue<'ctx> {
        let args: Vec<BasicMetadataValueEnum> = args.iter().map(|a| (*a).into()).collect();
        self.call_intrinsic(name, &[self.fty.into()], &args, self.fty)
    }

    /// Whether any lane of `m` is set, as an `i1`.
    fn any(&mut self, m: VectorValue<'ctx>) -> IntValue<'ctx> {
        let wide = match std::num::NonZeroU32::new(self.w).map(|w| self.u.cx.custom_width_int_type(w)) {
            Some(Ok(t)) => t,
            _ => {
                self.fail(format!("no {}-bit integer type", self.w));
                return self.u.cx.bool_type().get_poison();
            }
        };
        let bits = self.b.build_bit_cast(m, wide, "");
        let bits = match bits {
            Ok(BasicValueEnum::IntValue(i)) => i,
            Ok(_) | Err(_) => {
                self.fail("mask bitcast");
                wide.get_poison()
            }
        };
        let r = self.b.build_int_compare(IntPredicate::NE, bits, wide.const_zero(), "");
        self.scalar(r, self.u.cx.bool_type().get_poison())
    }

    /// The lanes whose index is below `rem` (recomputed where used: a value of `load_part` does not dominate
    /// `store_part`).
    fn part_mask(&mut self, rem: IntValue<'ctx>) -> VectorValue<'ctx> {
        let iota = VectorType::const_vector(&(0..self.w).map(|k| self.i64c(u64::from(k))).collect::<Vec<_>>());
        let r = self.splat(rem.into(), self.ity);
        let m = self.b.build_int_compare(IntPredicate::ULT, iota, r, "");
        self.m(m)
    }

    /// Sets a load's or store's alignment to 8 (columns are `f64` slices, not vector-aligned).
    fn align(&mut self, v: Result<inkwell::values::InstructionValue<'ctx>, BuilderError>) {
        match v {
            Ok(ins) => {
                if ins.set_alignment(8).is_err() {
                    self.fail("alignment");
                }
            }
            Err(e) => self.fail(e),
        }
    }

    /// A new block after the current one.
    fn block(&self, name: &str) -> BasicBlock<'ctx> {
        self.u.cx.append_basic_block(self.func, name)
    }

    fn current(&mut self) -> BasicBlock<'ctx> {
        match self.b.get_insert_block() {
            Some(bb) => bb,
            None => {
                self.fail("builder outside a block");
                self.block("lost")
            }
        }
    }
}

/// Where the native lowering's values come from in LLVM: the generator's table, the loaded inputs and
/// columns, the parameters, `llvm.minimum`/`llvm.maximum` (IEEE 754-2019's: NaN-propagating, −0 < +0, which x86
/// runs as a compare, a blend and a repair of the zeros' signs), and the library's functions by address.
impl<'ctx> Lower for Gen<'_, 'ctx> {
    fn scope(&self) -> Scope<'_> {
        Scope { ir: self.u.ir, mode: self.u.mode, outline: self.u.outline, fma: self.u.fma }
    }
    fn table(&mut self) -> &mut [Option<VectorValue<'ctx>>] {
        &mut self.vals
    }
    fn input(&mut self, i: Input) -> Result<VectorValue<'ctx>, NativeError> {
        self.inputs[i.index()].ok_or_else(|| NativeError::Internal(format!("input {} has no column", i.name())))
    }
    fn param(&mut self, p: u16) -> Result<VectorValue<'ctx>, NativeError> {
        let s = self.load_f64(self.params, u64::from(p));
        Ok(self.splat(s, self.fty))
    }
    fn column(&mut self, k: u16) -> Result<VectorValue<'ctx>, NativeError> {
        self.columns.get(usize::from(k)).copied().flatten().ok_or_else(|| NativeError::Internal(format!("data column {k} is not loaded")))
    }
    fn minimum(&mut self, a: VectorValue<'ctx>, b: VectorValue<'ctx>) -> VectorValue<'ctx> {
        self.fop("llvm.minimum", &[a, b])
    }
    fn maximum(&mut self, a: VectorValue<'ctx>, b: VectorValue<'ctx>) -> VectorValue<'ctx> {
        self.fop("llvm.maximum", &[a, b])
    }
    fn library(&mut self, f: Builtin, args: &[VectorValue<'ctx>]) -> Result<VectorValue<'ctx>, NativeError> {
        ops::library(self, f, args)
    }
    fn take_error(&mut self) -> Option<NativeError> {
        self.error.take()
    }
}

/// The prepared block in LLVM: one double at `block + 8·k`, splatted when loaded.
impl<'ctx> Frame for Gen<'_, 'ctx> {
    fn load_block(&mut self, k: usize) -> Result<VectorValue<'ctx>, NativeError> {
        let s = self.load_f64(self.block, k as u64);
        Ok(self.splat(s, self.fty))
    }
    fn store_block(&mut self, k: usize, v: VectorValue<'ctx>) -> Result<(), NativeError> {
        let s = self.b.build_extract_element(v, self.i32c(0), "");
        let s = self.scalar(s, self.u.cx.f64_type().get_poison().into());
        let p = self.offset(self.block, self.i64c(8 * k as u64));
        let st = self.b.build_store(p, s);
        self.done(st);
        Ok(())
    }
}

/// Branches in LLVM: a conditional branch on the mask's bits (weighted 1 : 2000 into a rare block), a phi per
/// value at the join.
impl<'ctx> Branch for Gen<'_, 'ctx> {
    /// The block that branched, the join, the values from the skipping edge.
    type Open = (BasicBlock<'ctx>, BasicBlock<'ctx>, Vec<VectorValue<'ctx>>);
    fn branch_any(&mut self, m: Self::M, skip: &[Self::V], rare: bool) -> Self::Open {
        let any = self.any(m);
        let from = self.current();
        let inside = self.block(if rare { "rare" } else { "region" });
        let join = self.block("join");
        match self.b.build_conditional_branch(any, inside, join) {
            Ok(br) if rare => {
                let cx = self.u.cx;
                let i32t = cx.i32_type();
                let weights = cx.metadata_node(&[cx.metadata_string("branch_weights").into(), i32t.const_int(1, false).into(), i32t.const_int(2000, false).into()]);
                if br.set_metadata(weights, cx.get_kind_id("prof")).is_err() {
                    self.fail("branch weights");
                }
            }
            Ok(_) => {}
            Err(e) => self.fail(e),
        }
        self.b.position_at_end(inside);
        (from, join, skip.to_vec())
    }
    fn join(&mut self, (from, join, skip): Self::Open, vals: &[Self::V]) -> Vec<Self::V> {
        let end = self.current();
        let br = self.b.build_unconditional_branch(join);
        self.done(br);
        self.b.position_at_end(join);
        let mut out = Vec::with_capacity(vals.len());
        for (s, v) in skip.iter().zip(vals) {
            match self.b.build_phi(self.fty, "") {
                Ok(phi) => {
                    phi.add_incoming(&[(s, from), (v, end)]);
                    out.push(self.vec_of(Ok(phi.as_basic_value()), self.fty));
                }
                Err(e) => {
                    self.fail(e);
                    out.push(*s);
                }
            }
        }
        out
    }
    fn nonzero(&mut self, v: Self::V) -> Self::M {
        let zero = self.fconst(0);
        let m = self.b.build_float_compare(FloatPredicate::UNE, v, zero, "");
        self.m(m)
    }
}

/// The address of a library function.
fn libm_addr(l: Libm) -> usize {
    match l {
        Libm::F1(f) => f as usize,
        Libm::F2(f) => f as usize,
        Libm::F3(f) => f as usize,
        Libm::Exact => 0,
    }
}

/// The library's IEEE primitives as LLVM instructions without fast-math flags.
impl<'ctx> Arith for Gen<'_, 'ctx> {
    type V = VectorValue<'ctx>;
    fn konst(&mut self, c: f64) -> Self::V {
        self.fconst(c.to_bits())
    }
    fn add(&mut self, a: Self::V, b: Self::V) -> Self::V {
        let r = self.b.build_float_add(a, b, "");
        self.f(r)
    }
    fn sub(&mut self, a: Self::V, b: Self::V) -> Self::V {
        let r = self.b.build_float_sub(a, b, "");
        self.f(r)
    }
    fn mul(&mut self, a: Self::V, b: Self::V) -> Self::V {
        let r = self.b.build_float_mul(a, b, "");
        self.f(r)
    }
    fn div(&mut self, a: Self::V, b: Self::V) -> Self::V {
        let r = self.b.build_float_div(a, b, "");
        self.f(r)
    }
    fn neg(&mut self, a: Self::V) -> Self::V {
        let r = self.b.build_float_neg(a, "");
        self.f(r)
    }
    fn sqrt(&mut self, a: Self::V) -> Self::V {
        self.fop("llvm.sqrt", &[a])
    }
    /// `llvm.fma`: correctly rounded always (a call of the C library's `fma` on a host without the instruction).
    fn fma(&mut self, a: Self::V, b: Self::V, c: Self::V) -> Self::V {
        self.fop("llvm.fma", &[a, b, c])
    }
    fn positive_select(&mut self, c: Self::V, a: Self::V, b: Self::V) -> Self::V {
        ops::positive_select(self, c, a, b)
    }
    fn two_prod(&mut self, a: Self::V, b: Self::V) -> (Self::V, Self::V) {
        ops::two_prod(self, a, b)
    }
}

/// The library's comparisons, masks and bit operations on `W` lanes.
impl<'ctx> Emit for Gen<'_, 'ctx> {
    type M = VectorValue<'ctx>;
    fn abs(&mut self, a: Self::V) -> Self::V {
        self.fop("llvm.fabs", &[a])
    }
    fn lt(&mut self, a: Self::V, b: Self::V) -> Self::M {
        let r = self.b.build_float_compare(FloatPredicate::OLT, a, b, "");
        self.m(r)
    }
    fn le(&mut self, a: Self::V, b: Self::V) -> Self::M {
        let r = self.b.build_float_compare(FloatPredicate::OLE, a, b, "");
        self.m(r)
    }
    fn eq(&mut self, a: Self::V, b: Self::V) -> Self::M {
        let r = self.b.build_float_compare(FloatPredicate::OEQ, a, b, "");
        self.m(r)
    }
    fn and(&mut self, a: Self::M, b: Self::M) -> Self::M {
        let r = self.b.build_and(a, b, "");
        self.m(r)
    }
    fn or(&mut self, a: Self::M, b: Self::M) -> Self::M {
        let r = self.b.build_or(a, b, "");
        self.m(r)
    }
    fn not(&mut self, a: Self::M) -> Self::M {
        let r = self.b.build_xor(a, self.all_true(), "");
        self.m(r)
    }
    fn select(&mut self, m: Self::M, a: Self::V, b: Self::V) -> Self::V {
        let r = self.b.build_select(m, a, b, "");
        self.vec_of(r, self.fty)
    }
    fn mask_bits(&mut self, x: Self::V, and: u64, or: u64) -> Self::V {
        ops::mask_bits(self, x, and, or)
    }
    fn pow2i(&mut self, k: Self::V) -> Self::V {
        ops::pow2i(self, k)
    }
    fn exponent_field(&mut self, x: Self::V) -> Self::V {
        ops::exponent_field(self, x)
    }
    /// The row index masked to the table (whatever `x` holds, the loads stay inside it) and scaled to bytes in
    /// all lanes, then two gathers (heads and tails) from the `'static` table, whose address is a constant.
    fn lookup_pair(&mut self, table: &'static [[f64; 2]], x: Self::V) -> (Self::V, Self::V) {
        if !table.len().is_power_of_two() {
            self.fail("lookup in a table whose length is not a power of two");
            return (x, x);
        }
        let magic = self.fconst(math::MAGIC.to_bits());
        let t = Arith::add(self, x, magic);
        let i = self.b.build_bit_cast(t, self.ity, "");
        let i = self.vec_of(i, self.ity);
        if table.len() <= 16 && self.w == 8 && self.u.avx512 {
            return self.permute_pair(table, i);
        }
        if table.len() <= 4 {
            return self.select_pair(table, i);
        }
        let r = self.b.build_and(i, self.iconst(table.len() as u64 - 1), "");
        let i = self.i(r);
        let r = self.b.build_left_shift(i, self.iconst(4), "");
        let off = self.i(r);
        let base = self.iconst(table.as_ptr() as u64);
        let r = self.b.build_int_add(base, off, "");
        let heads = self.i(r);
        let r = self.b.build_int_add(heads, self.iconst(8), "");
        let tails = self.i(r);
        let pty = self.u.cx.ptr_type(Default::default()).vec_type(self.w);
        let gather = |g: &mut Self, addrs: VectorValue<'ctx>| {
            let p = g.b.build_cast(inkwell::values::InstructionOpcode::IntToPtr, addrs, pty, "");
            let p = g.vec_of(p, pty);
            let args = [p.into(), g.i32c(8).into(), g.all_true().into(), g.fty.get_poison().into()];
            g.call_intrinsic("llvm.masked.gather", &[g.fty.into(), pty.into()], &args, g.fty)
        };
        let h = gather(self, heads);
        let t = gather(self, tails);
        (h, t)
    }
    fn lanes(&self) -> u32 {
        self.w
    }
    /// `any(m) ? slow() : r`, the slow code in a block of its own (weighted as rarely taken).
    fn rare(&mut self, m: Self::M, r: Self::V, slow: &mut dyn FnMut(&mut Self) -> Self::V) -> Self::V {
        ops::rare(self, m, r, slow)
    }
    fn rare_call(&mut self, m: Self::M, r: Self::V, f: Builtin, args: &[Self::V], slow: &mut dyn FnMut(&mut Self) -> Self::V) -> Self::V {
        ops::rare_call(self, m, r, f, args, slow)
    }
    fn fallback(&mut self, m: Self::M, x: Self::V, r: Self::V, f: Builtin) -> Self::V {
        ops::fallback(self, m, x, r, f)
    }
}

/// Integer lanes in LLVM: `<W x i64>`, bit casts of `<W x double>`.
impl<'ctx> Bits for Gen<'_, 'ctx> {
    type I = VectorValue<'ctx>;
    fn to_bits(&mut self, x: Self::V) -> Self::I {
        let i = self.b.build_bit_cast(x, self.ity, "");
        self.vec_of(i, self.ity)
    }
    fn of_bits(&mut self, i: Self::I) -> Self::V {
        let f = self.b.build_bit_cast(i, self.fty, "");
        self.vec_of(f, self.fty)
    }
    fn int(&mut self, v: u64) -> Self::I {
        self.iconst(v)
    }
    fn iand(&mut self, a: Self::I, b: Self::I) -> Self::I {
        let r = self.b.build_and(a, b, "");
        self.i(r)
    }
    fn ior(&mut self, a: Self::I, b: Self::I) -> Self::I {
        let r = self.b.build_or(a, b, "");
        self.i(r)
    }
    fn iadd(&mut self, a: Self::I, b: Self::I) -> Self::I {
        let r = self.b.build_int_add(a, b, "");
        self.i(r)
    }
    fn shl(&mut self, i: Self::I, n: u32) -> Self::I {
        let r = self.b.build_left_shift(i, self.iconst(u64::from(n)), "");
        self.i(r)
    }
    fn ushr(&mut self, i: Self::I, n: u32) -> Self::I {
        let r = self.b.build_right_shift(i, self.iconst(u64::from(n)), false, "");
        self.i(r)
    }
}

/// Per-lane calls in LLVM: the `extern "C"` function (the library compiled by rustc, or the C library's
/// fallback) called through its address as a constant, on `double` lanes.
impl<'ctx> Calls for Gen<'_, 'ctx> {
    type Func = usize;
    type Lane = BasicValueEnum<'ctx>;
    fn function(&mut self, f: Builtin, which: Callee) -> Option<usize> {
        match which {
            Callee::Library => f.outlined(self.u.mode).map(|(_, lib)| libm_addr(lib)),
            Callee::Fallback => f.libm1().map(|libm| libm as usize),
        }
    }
    fn lane(&mut self, v: Self::V, i: u32) -> Self::Lane {
        let x = self.b.build_extract_element(v, self.i32c(u64::from(i)), "");
        self.scalar(x, self.u.cx.f64_type().get_poison().into())
    }
    fn call(&mut self, addr: usize, args: &[Self::Lane]) -> Result<Self::Lane, NativeError> {
        let f64t = self.u.cx.f64_type();
        let arg_tys: Vec<_> = args.iter().map(|_| f64t.into()).collect();
        let fty = f64t.fn_type(&arg_tys, false);
        let callee = self.i64c(addr as u64).const_to_pointer(self.u.cx.ptr_type(Default::default()));
        let args: Vec<BasicMetadataValueEnum> = args.iter().map(|a| (*a).into()).collect();
        let c = self.b.build_indirect_call(fty, callee, &args, "").map_err(NativeError::internal)?;
        match c.try_as_basic_value() {
            inkwell::values::ValueKind::Basic(v) => Ok(v),
            inkwell::values::ValueKind::Instruction(_) => Err(NativeError::internal("a library call returned nothing")),
        }
    }
    fn gather(&mut self, lanes: &[Self::Lane]) -> Self::V {
        let mut out = self.fty.get_poison();
        for (k, l) in lanes.iter().enumerate() {
            let ins = self.b.build_insert_element(out, *l, self.i32c(k as u64), "");
            out = self.f(ins);
        }
        out
    }
    fn record(&mut self, e: NativeError) {
        if self.error.is_none() {
            self.error = Some(e);
        }
    }
}

/// Declares a function `void name(ptr × pointers[, i64])` (`double name(ptr × pointers)` for the scalar
/// function) with the host's CPU and features.
fn declare<'ctx>(u: &Unit<'_, 'ctx>, name: &str, pointers: usize, len: bool) -> FunctionValue<'ctx> {
    let ptr = u.cx.ptr_type(Default::default());
    let mut params: Vec<inkwell::types::BasicMetadataTypeEnum> = vec![ptr.into(); pointers];
    if len {
        params.push(u.cx.i64_type().into());
    }
    let fty = if name == SCALAR { u.cx.f64_type().fn_type(&params, false) } else { u.cx.void_type().fn_type(&params, false) };
    let f = u.module.add_function(name, fty, None);
    for (k, v) in [("target-cpu", u.cpu), ("target-features", u.features)] {
        f.add_attribute(AttributeLoc::Function, u.cx.create_string_attribute(k, v));
    }
    let nounwind = inkwell::attributes::Attribute::get_named_enum_kind_id("nounwind");
    f.add_attribute(AttributeLoc::Function, u.cx.create_enum_attribute(nounwind, 0));
    f
}

fn param(f: FunctionValue<'_>, k: u32) -> Result<PointerValue<'_>, NativeError> {
    match f.get_nth_param(k) {
        Some(BasicValueEnum::PointerValue(p)) => Ok(p),
        _ => Err(NativeError::Internal(format!("parameter {k} is not a pointer"))),
    }
}

/// `lobe_prepare`: every carried node computed (one lane) and stored to the block.
pub(super) fn build_prepare(u: &Unit) -> Result<(), NativeError> {
    let f = declare(u, PREPARE, 2, false);
    let mut g = Gen::new(u, f, 1, param(f, 0)?, param(f, 1)?);
    let entry = g.block("entry");
    g.b.position_at_end(entry);
    frame::prepare(&mut g, u.plan)?;
    let r = g.b.build_return(None);
    g.done(r);
    g.error.map_or(Ok(()), Err)
}

/// `lobe_scalar(x, params, block) -> f64` in one lane: the inputs loaded from `x`, then the native layer's
/// scalar body ([`frame::scalar`]).
pub(super) fn build_scalar(u: &Unit) -> Result<(), NativeError> {
    let f = declare(u, SCALAR, 3, false);
    let x = param(f, 0)?;
    let mut g = Gen::new(u, f, 1, param(f, 1)?, param(f, 2)?);
    let entry = g.block("entry");
    g.b.position_at_end(entry);
    for k in frame::kernel_columns(u.ir, u.plan) {
        let s = g.load_f64(x, k as u64);
        g.inputs[k] = Some(g.splat(s, g.fty));
    }
    let r = frame::scalar(&mut g, u.plan)?;
    let s = g.b.build_extract_element(r, g.i32c(0), "");
    let s = g.scalar(s, u.cx.f64_type().get_poison().into());
    let ret = g.b.build_return(Some(&s));
    g.done(ret);
    g.error.map_or(Ok(()), Err)
}

/// `lobe_batch(cols, params, block, out: *mut f64, len)` in `w` lanes: the formula's inputs read from `cols`,
/// its root stored to `out`, in [`batch_loop`]'s loop.
pub(super) fn build_batch(u: &Unit, w: u32) -> Result<(), NativeError> {
    let f = declare(u, BATCH, 4, true);
    let (cols, out) = (param(f, 0)?, param(f, 3)?);
    let mut g = Gen::new(u, f, w, param(f, 1)?, param(f, 2)?);
    let entry = g.block("entry");
    g.b.position_at_end(entry);
    let bases = frame::kernel_columns(u.ir, u.plan).into_iter().map(|k| Ok((k, load_ptr(&mut g, cols, k)?))).collect::<Result<Vec<_>, NativeError>>()?;
    batch_loop(&mut g, f, &bases, &[out], |g, loaded| {
        for (k, v) in loaded {
            g.inputs[*k] = Some(*v);
        }
        Ok(vec![frame::kernel_step(g, u.plan)?])
    })
}

/// `lobe_program(cols: *const *const f64, params, block, outs: *const *mut f64, len)` in `w` lanes: a
/// multi-output program ([`crate::backend::program`]) in [`batch_loop`]'s loop, reading its data columns
/// from `cols` and storing every output to `outs[o]`. The step is the native layer's
/// ([`frame::program_step`]), its regions this tier's branch and phis ([`Branch`] for [`Gen`]).
pub(super) fn build_program(u: &Unit, w: u32, p: &Program) -> Result<(), NativeError> {
    let f = declare(u, PROGRAM, 4, true);
    let (cols, outs) = (param(f, 0)?, param(f, 3)?);
    let mut g = Gen::new(u, f, w, param(f, 1)?, param(f, 2)?);
    let entry = g.block("entry");
    g.b.position_at_end(entry);
    let bases = frame::program_columns(p)?.into_iter().map(|k| Ok((k, load_ptr(&mut g, cols, k)?))).collect::<Result<Vec<_>, NativeError>>()?;
    let out_bases = (0..p.outputs.len()).map(|o| load_ptr(&mut g, outs, o)).collect::<Result<Vec<_>, _>>()?;
    batch_loop(&mut g, f, &bases, &out_bases, |g, loaded| {
        for (k, v) in loaded {
            g.columns[*k] = Some(*v);
        }
        frame::program_step(g, p)?;
        p.outputs.iter().map(|o| g.value(*o)).collect()
    })
}

/// The loop of both function shapes, in `g`'s `W` lanes, from the entry block (where the caller loaded the
/// column bases `cols`, (slot, base) pairs, and the output bases `outs`):
///
/// ```text
/// entry:   carried nodes loaded from the block, constants and parameters, splatted; len = 0 ? exit : loop
/// loop(i): full = len − i ≥ W; full ? load : load_part
/// load:    the W column values at i                     load_part: the len − i values at i (masked loads)
/// step:    `step` on the loaded (slot, vector) pairs → one vector per output; full ? store : store_part
/// store:   outs[o][i..i+W] = vector o                   store_part: outs[o][i..len] (masked store)
/// latch:   i + W < len ? loop(i + W) : exit
/// ```
///
/// One copy of the body serves the full vectors and the tail (len not a multiple of W), so compile time does
/// not double for the tail; the two branches on `full` are taken the same way on every step but the last.
fn batch_loop<'ctx>(
    g: &mut Gen<'_, 'ctx>,
    f: FunctionValue<'ctx>,
    cols: &[(usize, PointerValue<'ctx>)],
    outs: &[PointerValue<'ctx>],
    step: impl FnOnce(&mut Gen<'_, 'ctx>, &[(usize, VectorValue<'ctx>)]) -> Result<Vec<VectorValue<'ctx>>, NativeError>,
) -> Result<(), NativeError> {
    let u = g.u;
    let len = match f.get_nth_param(4) {
        Some(BasicValueEnum::IntValue(l)) => l,
        _ => return Err(NativeError::internal("len parameter")),
    };
    let ptr = u.cx.ptr_type(Default::default());
    let i64t = u.cx.i64_type();
    frame::entry(g, u.plan)?;

    let (head, load, load_part, body, store, store_part, latch, exit) =
        (g.block("loop"), g.block("load"), g.block("load_part"), g.block("step"), g.block("store"), g.block("store_part"), g.block("latch"), g.block("exit"));
    let empty = g.b.build_int_compare(IntPredicate::EQ, len, i64t.const_zero(), "");
    let empty = g.scalar(empty, u.cx.bool_type().get_poison());
    let pre = g.current();
    let br = g.b.build_conditional_branch(empty, exit, head);
    g.done(br);

    // loop(i)
    g.b.position_at_end(head);
    let i = g.b.build_phi(i64t, "i").map_err(NativeError::internal)?;
    let iv = i.as_basic_value().into_int_value();
    let rem = g.b.build_int_sub(len, iv, "");
    let rem = g.scalar(rem, i64t.get_poison());
    let full = g.b.build_int_compare(IntPredicate::UGE, rem, g.i64c(u64::from(g.w)), "");
    let full = g.scalar(full, u.cx.bool_type().get_poison());
    let byte_off = g.b.build_left_shift(iv, g.i64c(3), "");
    let byte_off = g.scalar(byte_off, i64t.get_poison());
    let br = g.b.build_conditional_branch(full, load, load_part);
    g.done(br);

    // load / load_part, joined in `step` by a phi per column.
    g.b.position_at_end(load);
    let mut full_vals = vec![];
    for &(k, base) in cols {
        let at = g.offset(base, byte_off);
        let l = g.b.build_load(g.fty, at, "");
        let v = g.vec_of(l, g.fty);
        if let Some(ins) = v.as_instruction_value() {
            g.align(Ok(ins));
        }
        full_vals.push((k, base, v));
    }
    let br = g.b.build_unconditional_branch(body);
    g.done(br);
    g.b.position_at_end(load_part);
    let m = g.part_mask(rem);
    let mut parts = vec![];
    for (k, base, v) in full_vals {
        let at = g.offset(base, byte_off);
        let args = [at.into(), g.i32c(8).into(), m.into(), g.fty.const_zero().into()];
        let pv = g.call_intrinsic("llvm.masked.load", &[g.fty.into(), ptr.into()], &args, g.fty);
        parts.push((k, v, pv));
    }
    let br = g.b.build_unconditional_branch(body);
    g.done(br);

    // step: the body, once.
    g.b.position_at_end(body);
    let mut loaded = vec![];
    for (k, v, pv) in parts {
        let phi = g.b.build_phi(g.fty, &format!("c{k}")).map_err(NativeError::internal)?;
        phi.add_incoming(&[(&v, load), (&pv, load_part)]);
        loaded.push((k, g.vec_of(Ok(phi.as_basic_value()), g.fty)));
    }
    let results = step(g, &loaded)?;
    if results.len() != outs.len() {
        return Err(NativeError::Internal(format!("{} results for {} outputs", results.len(), outs.len())));
    }
    let br = g.b.build_conditional_branch(full, store, store_part);
    g.done(br);

    g.b.position_at_end(store);
    for (r, base) in results.iter().zip(outs) {
        let at = g.offset(*base, byte_off);
        let st = g.b.build_store(at, *r);
        g.align(st);
    }
    let br = g.b.build_unconditional_branch(latch);
    g.done(br);

    g.b.position_at_end(store_part);
    let m = g.part_mask(rem);
    let Some(ms) = g.intrinsic("llvm.masked.store", &[g.fty.into(), ptr.into()]) else { return Err(g.error.take().unwrap_or(NativeError::internal("llvm.masked.store"))) };
    for (r, base) in results.iter().zip(outs) {
        let at = g.offset(*base, byte_off);
        let c = g.b.build_call(ms, &[(*r).into(), at.into(), g.i32c(8).into(), m.into()], "");
        g.done(c);
    }
    let br = g.b.build_unconditional_branch(latch);
    g.done(br);

    g.b.position_at_end(latch);
    let next = g.b.build_int_add(iv, g.i64c(u64::from(g.w)), "");
    let next = g.scalar(next, i64t.get_poison());
    let more = g.b.build_int_compare(IntPredicate::ULT, next, len, "");
    let more = g.scalar(more, u.cx.bool_type().get_poison());
    let br = g.b.build_conditional_branch(more, head, exit);
    g.done(br);
    i.add_incoming(&[(&i64t.const_zero(), pre), (&next, latch)]);

    g.b.position_at_end(exit);
    let r = g.b.build_return(None);
    g.done(r);
    g.error.take().map_or(Ok(()), Err)
}

/// The pointer at `base[k]`.
fn load_ptr<'ctx>(g: &mut Gen<'_, 'ctx>, base: PointerValue<'ctx>, k: usize) -> Result<PointerValue<'ctx>, NativeError> {
    let at = g.offset(base, g.i64c(8 * k as u64));
    match g.b.build_load(g.u.cx.ptr_type(Default::default()), at, "") {
        Ok(BasicValueEnum::PointerValue(p)) => Ok(p),
        _ => Err(NativeError::internal("pointer load")),
    }
}
