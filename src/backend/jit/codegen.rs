//! IR → Cranelift IR: the tier's primitives over one translator, generic over the lane type, and its
//! function shapes ([`crate::backend::native::abi`]'s signatures):
//!
//! * prepare: the carried parameter-only nodes of the [`Plan`], in `F64`;
//! * scalar: in `F64`;
//! * batched: the loop in `F64X2` lanes, the remaining element (odd `len`) in `F64`.
//!
//! The translator implements the math library's [`Emit`] and the native layer's [`Lower`] and [`Frame`], so
//! the node dispatch, the inline builtins and the builtins' code ([`crate::backend::native::lower`]) and what
//! each function computes in which order ([`crate::backend::native::frame`]) are emitted in the translator's
//! lanes; what differs between lane types (splatting, lanes, masks and bit casts, the select
//! that becomes `maxpd`/`minpd`) is the [`Lanes`] trait.
//!
//! None of them checks anything at run time; the safe wrappers in `native::abi` validate lengths before calling.
//!
//! Parameter-only nodes (e.g. `pow(Q, 1/k)`) are computed by the prepare function and loaded from the block;
//! constants and parameters are splatted in the batched function's entry, so the loop body holds only work
//! that depends on the inputs (Cranelift may still rematerialise a cheap constant next to its use).
//!
//! Codegen never sees text from the user: the only names are the builtins table's symbols, and every error
//! is a [`NativeError`] rather than a panic.

use crate::backend::native::frame::{self, Frame};
use crate::backend::native::lower::{Lower, Scope};
use crate::backend::native::ops::{self, Bits, Branch, Callee, Calls};
use crate::backend::native::{NativeError, Plan};
use crate::builtins::dd::Arith;
use crate::builtins::math::{self, Emit};
use crate::builtins::{Builtin, Libm, Lowering, Mode};
use crate::ir::{Input, Ir, Node, NodeId, N_INPUTS};
use cranelift_codegen::ir::condcodes::{FloatCC, IntCC};
use cranelift_codegen::ir::immediates::Ieee64;
use cranelift_codegen::ir::{
    types, AbiParam, Block, BlockArg, Endianness, FuncRef, InstBuilder, MemFlagsData, Signature, Type, Value,
};
use cranelift_codegen::Context;
use cranelift_frontend::{FunctionBuilder, FunctionBuilderContext};
use cranelift_jit::JITModule;
use cranelift_module::{FuncId, Linkage, Module};
use std::marker::PhantomData;

// The shading program's batched function: a child module, so it reuses the translator and lanes as they are.
#[path = "shade.rs"]
pub(super) mod shade;

/// The functions a module imports, by builtin (indexed by `Builtin as usize`): with the library inlined, the
/// C-library fallback of each trigonometric builtin (huge arguments); with it outlined, each math builtin's
/// compiled library function ([`Builtin::outlined`]), which includes its fallback.
pub(super) type Imports = [Option<FuncId>; Builtin::ALL.len()];

/// Each distinct builtin of `ir` that imports a function: its symbol, pointer and arity.
fn symbols(ir: &Ir, mode: Mode, outline: bool) -> Vec<(Builtin, &'static str, *const u8, usize)> {
    let mut seen = [false; Builtin::ALL.len()];
    let mut out = vec![];
    for n in ir.nodes() {
        let Node::Call(b, _) = n else { continue };
        if b.info().lowering != Lowering::Math || std::mem::replace(&mut seen[*b as usize], true) {
            continue;
        }
        // With the library inlined, expmuldiv's and sinnear's rare lanes call their compiled functions
        // (`Emit::rare_call`).
        let (symbol, f) = if outline || matches!(b, Builtin::ExpMulDiv | Builtin::SinNear) {
            match b.outlined(mode) {
                Some(s) => s,
                None => continue,
            }
        } else {
            match (b.info().symbol, b.info().libm) {
                ("", _) => continue,
                (s, f) => (s, f),
            }
        };
        let (ptr, arity) = match f {
            Libm::F1(f) => (f as *const u8, 1),
            Libm::F2(f) => (f as *const u8, 2),
            Libm::F3(f) => (f as *const u8, 3),
            Libm::Exact => continue,
        };
        out.push((*b, symbol, ptr, arity));
    }
    out
}

/// Declares (as imports) the functions the formula may call. The caller registered each symbol with the
/// `JITBuilder` ([`used_symbols`]), so `finalize_definitions` can resolve every import.
pub(super) fn declare_imports(module: &mut JITModule, ir: &Ir, mode: Mode, outline: bool) -> Result<Imports, NativeError> {
    let mut imports: Imports = [None; Builtin::ALL.len()];
    for (b, symbol, _, arity) in symbols(ir, mode, outline) {
        let mut sig = module.make_signature();
        sig.params.extend(std::iter::repeat_n(AbiParam::new(types::F64), arity));
        sig.returns.push(AbiParam::new(types::F64));
        imports[b as usize] = Some(module.declare_function(symbol, Linkage::Import, &sig)?);
    }
    Ok(imports)
}

/// The symbols `ir` imports, with the function pointer to register.
pub(super) fn used_symbols(ir: &Ir, mode: Mode, outline: bool) -> Vec<(&'static str, *const u8)> {
    symbols(ir, mode, outline).into_iter().map(|(_, s, p, _)| (s, p)).collect()
}

/// A lane type the translator emits: how many elements one value holds and the few operations whose
/// instructions differ by lane type. At the boundary (constants, parameters, libm fallbacks, table loads)
/// values are `F64` scalars; `splat` and `lane` convert. `F64` serves the scalar kernel and the batch tail,
/// `F64X2` the batch loop. Another lane type (e.g. `F32X4` for a wider fast mode) is one more impl, converting
/// in `splat`/`lane`; it would also need its own column loads (`Translator::input` loads `TY` from `f64`
/// columns), f32 versions of the math library's bit operations, and a tail loop (the batch tail handles one
/// element).
trait Lanes {
    /// The Cranelift type of one value.
    const TY: Type;
    /// The integer type of the same shape (for bit operations).
    const ITY: Type;
    /// Elements per value (a power of two).
    const LANES: u8;
    /// Every lane set to the `F64` scalar `s`.
    fn splat(b: &mut FunctionBuilder, s: Value) -> Value;
    /// Every lane set to the constant with bits `bits`.
    fn konst(b: &mut FunctionBuilder, bits: u64) -> Value;
    /// Every lane set to the integer `v` (type `ITY`).
    fn iconst(b: &mut FunctionBuilder, v: u64) -> Value;
    /// Reinterprets `v` as type `ty` (`TY` ↔ `ITY`, or a mask as `TY`).
    fn bitcast(b: &mut FunctionBuilder, ty: Type, v: Value) -> Value;
    /// Lane `i` of `v` as an `F64` scalar.
    fn lane(b: &mut FunctionBuilder, v: Value, i: u8) -> Value;
    /// `cond ? x : y` lane-wise, `cond` being an `fcmp` of two values of this type (or a combination of such
    /// masks), in the shape Cranelift's x64 backend matches to `min/max{sd,pd}`.
    fn select(b: &mut FunctionBuilder, cond: Value, x: Value, y: Value) -> Value;
    /// The complement of a mask.
    fn not(b: &mut FunctionBuilder, m: Value) -> Value;
    /// Whether any lane of the mask `m` is set, as a value `brif` can test.
    fn any(b: &mut FunctionBuilder, m: Value) -> Value;
    /// A value from its lanes (`F64` scalars, lane 0 first).
    fn from_lanes(b: &mut FunctionBuilder, lanes: &[Value]) -> Value {
        let mut v = Self::splat(b, lanes[0]);
        for (i, l) in lanes.iter().enumerate().skip(1) {
            v = b.ins().insertlane(v, *l, i as u8);
        }
        v
    }
}

/// One `f64`: the scalar kernel and the batch tail.
struct F64;

impl Lanes for F64 {
    const TY: Type = types::F64;
    const ITY: Type = types::I64;
    const LANES: u8 = 1;
    fn splat(_: &mut FunctionBuilder, s: Value) -> Value {
        s
    }
    fn konst(b: &mut FunctionBuilder, bits: u64) -> Value {
        b.ins().f64const(Ieee64::with_bits(bits))
    }
    fn iconst(b: &mut FunctionBuilder, v: u64) -> Value {
        b.ins().iconst(types::I64, v as i64)
    }
    fn bitcast(b: &mut FunctionBuilder, ty: Type, v: Value) -> Value {
        b.ins().bitcast(ty, MemFlagsData::new(), v)
    }
    fn lane(_: &mut FunctionBuilder, v: Value, _: u8) -> Value {
        v
    }
    fn select(b: &mut FunctionBuilder, cond: Value, x: Value, y: Value) -> Value {
        b.ins().select(cond, x, y)
    }
    /// A scalar `fcmp` is 0 or 1, so its complement flips bit 0 (`bnot` would give 0xfe: still true).
    fn not(b: &mut FunctionBuilder, m: Value) -> Value {
        b.ins().bxor_imm_u(m, 1)
    }
    fn any(_: &mut FunctionBuilder, m: Value) -> Value {
        m
    }
}

/// Two `f64` lanes (SSE2 on x86-64, NEON on aarch64): the batch loop.
struct F64X2;

impl Lanes for F64X2 {
    const TY: Type = types::F64X2;
    const ITY: Type = types::I64X2;
    const LANES: u8 = 2;
    fn splat(b: &mut FunctionBuilder, s: Value) -> Value {
        b.ins().splat(Self::TY, s)
    }
    fn konst(b: &mut FunctionBuilder, bits: u64) -> Value {
        let bytes: Vec<u8> = [bits, bits].iter().flat_map(|w| w.to_le_bytes()).collect();
        let c = b.func.dfg.constants.insert(bytes.into());
        b.ins().vconst(Self::TY, c)
    }
    fn iconst(b: &mut FunctionBuilder, v: u64) -> Value {
        let bytes: Vec<u8> = [v, v].iter().flat_map(|w| w.to_le_bytes()).collect();
        let c = b.func.dfg.constants.insert(bytes.into());
        b.ins().vconst(Self::ITY, c)
    }
    fn bitcast(b: &mut FunctionBuilder, ty: Type, v: Value) -> Value {
        let flags = MemFlagsData::new().with_endianness(Endianness::Little);
        b.ins().bitcast(ty, flags, v)
    }
    fn lane(b: &mut FunctionBuilder, v: Value, i: u8) -> Value {
        b.ins().extractlane(v, i)
    }
    fn select(b: &mut FunctionBuilder, cond: Value, x: Value, y: Value) -> Value {
        let mask = Self::bitcast(b, Self::TY, cond);
        b.ins().bitselect(mask, x, y)
    }
    /// A vector `fcmp` sets all bits of a lane or none.
    fn not(b: &mut FunctionBuilder, m: Value) -> Value {
        b.ins().bnot(m)
    }
    fn any(b: &mut FunctionBuilder, m: Value) -> Value {
        b.ins().vany_true(m)
    }
    /// Lane 0 by `scalar_to_vector` (a load there folds into `movsd`), lane 1 by `movlhps`: two instructions
    /// where a splat and an insert take three.
    fn from_lanes(b: &mut FunctionBuilder, lanes: &[Value]) -> Value {
        let v = b.ins().scalar_to_vector(Self::TY, lanes[0]);
        b.ins().insertlane(v, lanes[1], 1)
    }
}

/// Where input values come from.
#[derive(Clone, Copy)]
enum Source {
    /// `x[i]` from the scalar kernel's input pointer.
    Ptr(Value),
    /// `col_i[off]` (one value of the lane type) from the batched kernel's hoisted column bases.
    Cols { bases: [Option<Value>; N_INPUTS], off: Value },
    /// A shading program's data columns (`Node::Column(k)` reads `data_k[off]`); it has no `Input` nodes.
    Data { bases: [Option<Value>; crate::backend::program::MAX_COLUMNS], off: Value },
}

type Callees = [Option<FuncRef>; Builtin::ALL.len()];

/// What every translator of one function shares, whatever its lane type.
struct Shared<'a> {
    ir: &'a Ir,
    /// The `params` pointer.
    params: Value,
    /// The prepared block's pointer (written by the prepare function, read by the others).
    block: Value,
    callees: Callees,
    /// `F64` values of the loop invariants computed before the loop (none in the scalar kernel): the batch
    /// tail uses them directly.
    invariants: Vec<Option<Value>>,
    /// Which library code the transcendental builtins emit.
    mode: Mode,
    /// Whether the host has a fused multiply-add (exact two-products in two instructions).
    fma: bool,
    /// Whether math builtins are calls to the compiled library ([`crate::backend::native::OUTLINE_AT`]) rather than inline code.
    outline: bool,
}

impl Shared<'_> {
    /// A translator in lane type `L` whose table starts as `vals` (e.g. the invariants' splats).
    fn translator<'a, 'b, L: Lanes>(
        &'a self,
        b: &'a mut FunctionBuilder<'b>,
        vals: Vec<Option<Value>>,
        source: Source,
    ) -> Translator<'a, 'b, L> {
        Translator { b, cx: self, vals, source, error: None, lanes: PhantomData }
    }
}

/// Translates IR nodes into Cranelift values of lane type `L`: one method per IR node kind, for every lane type.
struct Translator<'a, 'b, L> {
    b: &'a mut FunctionBuilder<'b>,
    cx: &'a Shared<'a>,
    /// Value of each translated node, in lane type `L`.
    vals: Vec<Option<Value>>,
    source: Source,
    /// An error raised inside an [`Emit`] method (which cannot return one), reported after the builtin.
    error: Option<NativeError>,
    lanes: PhantomData<L>,
}

fn mem() -> MemFlagsData {
    // The wrapper guarantees the pointers are valid (so no trap); vector loads are not necessarily aligned.
    MemFlagsData::new().with_notrap()
}

/// Where the native lowering's values come from in Cranelift: the translator's table, the input pointer or
/// columns, the parameters, `fmin`/`fmax`, and the imported library functions.
impl<L: Lanes> Lower for Translator<'_, '_, L> {
    fn scope(&self) -> Scope<'_> {
        Scope { ir: self.cx.ir, mode: self.cx.mode, outline: self.cx.outline, fma: self.cx.fma }
    }
    fn table(&mut self) -> &mut [Option<Value>] {
        &mut self.vals
    }
    fn input(&mut self, i: Input) -> Result<Value, NativeError> {
        Ok(match self.source {
            Source::Ptr(x) => self.b.ins().load(L::TY, mem(), x, (i.index() * 8) as i32),
            Source::Cols { bases, off } => {
                let base = bases[i.index()].ok_or_else(|| NativeError::Internal(format!("input {} has no column", i.name())))?;
                let addr = self.b.ins().iadd(base, off);
                self.b.ins().load(L::TY, mem(), addr, 0)
            }
            Source::Data { .. } => return Err(NativeError::Internal(format!("input {} in a shading program", i.name()))),
        })
    }
    /// `data_k[off]`: a shading program's column ([`shade`]).
    fn column(&mut self, k: u16) -> Result<Value, NativeError> {
        let Source::Data { bases, off } = self.source else {
            return Err(NativeError::Internal(format!("data column {k} outside a shading program")));
        };
        let base = bases.get(usize::from(k)).copied().flatten().ok_or_else(|| NativeError::Internal(format!("data column {k} has no base")))?;
        let addr = self.b.ins().iadd(base, off);
        Ok(self.b.ins().load(L::TY, mem(), addr, 0))
    }
    fn param(&mut self, p: u16) -> Result<Value, NativeError> {
        let v = self.b.ins().load(types::F64, mem(), self.cx.params, i32::from(p) * 8);
        Ok(L::splat(self.b, v))
    }
    fn minimum(&mut self, a: Value, b: Value) -> Value {
        self.b.ins().fmin(a, b)
    }
    fn maximum(&mut self, a: Value, b: Value) -> Value {
        self.b.ins().fmax(a, b)
    }
    fn library(&mut self, f: Builtin, args: &[Value]) -> Result<Value, NativeError> {
        ops::library(self, f, args)
    }
    fn take_error(&mut self) -> Option<NativeError> {
        self.error.take()
    }
}

/// The prepared block in Cranelift: `F64` loads and stores at `block + 8·k`.
impl<L: Lanes> Frame for Translator<'_, '_, L> {
    fn load_block(&mut self, k: usize) -> Result<Value, NativeError> {
        let v = self.b.ins().load(types::F64, mem(), self.cx.block, (k * 8) as i32);
        Ok(L::splat(self.b, v))
    }
    fn store_block(&mut self, k: usize, v: Value) -> Result<(), NativeError> {
        let s = L::lane(self.b, v, 0);
        self.b.ins().store(mem(), s, self.cx.block, (k * 8) as i32);
        Ok(())
    }
}

/// The math library's primitives as Cranelift instructions in lane type `L`: one instruction each (the bit
/// operations a short integer sequence), so the JIT runs exactly the code the interpreter runs on `f64`.
impl<L: Lanes> Arith for Translator<'_, '_, L> {
    type V = Value;
    fn konst(&mut self, c: f64) -> Value {
        L::konst(self.b, c.to_bits())
    }
    fn add(&mut self, a: Value, b: Value) -> Value {
        self.b.ins().fadd(a, b)
    }
    fn sub(&mut self, a: Value, b: Value) -> Value {
        self.b.ins().fsub(a, b)
    }
    fn mul(&mut self, a: Value, b: Value) -> Value {
        self.b.ins().fmul(a, b)
    }
    fn div(&mut self, a: Value, b: Value) -> Value {
        self.b.ins().fdiv(a, b)
    }
    fn neg(&mut self, a: Value) -> Value {
        self.b.ins().fneg(a)
    }
    fn sqrt(&mut self, a: Value) -> Value {
        self.b.ins().sqrt(a)
    }
    /// One instruction with a hardware FMA; otherwise Cranelift calls the `fma` symbol per lane (registered
    /// with the JIT builder), which is correctly rounded too, so the bits are the same.
    fn fma(&mut self, a: Value, b: Value, c: Value) -> Value {
        self.b.ins().fma(a, b, c)
    }
    fn positive_select(&mut self, c: Value, a: Value, b: Value) -> Value {
        ops::positive_select(self, c, a, b)
    }
    fn two_prod(&mut self, a: Value, b: Value) -> (Value, Value) {
        ops::two_prod(self, a, b)
    }
}

/// The math library's comparisons, masks and bit operations on lane type `L`.
impl<L: Lanes> Emit for Translator<'_, '_, L> {
    type M = Value;
    fn abs(&mut self, a: Value) -> Value {
        self.b.ins().fabs(a)
    }
    fn lt(&mut self, a: Value, b: Value) -> Value {
        self.b.ins().fcmp(FloatCC::LessThan, a, b)
    }
    fn le(&mut self, a: Value, b: Value) -> Value {
        self.b.ins().fcmp(FloatCC::LessThanOrEqual, a, b)
    }
    fn eq(&mut self, a: Value, b: Value) -> Value {
        self.b.ins().fcmp(FloatCC::Equal, a, b)
    }
    fn and(&mut self, a: Value, b: Value) -> Value {
        self.b.ins().band(a, b)
    }
    fn or(&mut self, a: Value, b: Value) -> Value {
        self.b.ins().bor(a, b)
    }
    fn not(&mut self, a: Value) -> Value {
        L::not(self.b, a)
    }
    fn select(&mut self, m: Value, a: Value, b: Value) -> Value {
        L::select(self.b, m, a, b)
    }
    /// Vector masks are all ones or all zeros per lane: `y & !m` (`andnpd`).
    fn zero_where(&mut self, m: Value, y: Value) -> Value {
        if L::LANES == 1 {
            let zero = L::konst(self.b, 0);
            return L::select(self.b, m, zero, y);
        }
        let mask = L::bitcast(self.b, L::TY, m);
        self.b.ins().band_not(y, mask)
    }
    fn mask_bits(&mut self, x: Value, and: u64, or: u64) -> Value {
        ops::mask_bits(self, x, and, or)
    }
    fn pow2i(&mut self, k: Value) -> Value {
        ops::pow2i(self, k)
    }
    fn exponent_field(&mut self, x: Value) -> Value {
        ops::exponent_field(self, x)
    }
    /// The row offsets masked to the table and scaled to bytes in all lanes at once (`pand`, `psllq`: whatever
    /// `x` holds, the load stays inside the table), then per lane one 16-byte row load (`F64X2`) and the heads
    /// and tails gathered by two shuffles (`punpcklqdq`/`punpckhqdq`); in `F64`, two scalar loads.
    fn lookup_pair(&mut self, table: &'static [[f64; 2]], x: Value) -> (Value, Value) {
        if !table.len().is_power_of_two() {
            self.error = Some(NativeError::internal("lookup in a table whose length is not a power of two"));
            return (x, x);
        }
        let magic = L::konst(self.b, math::MAGIC.to_bits());
        let t = self.b.ins().fadd(x, magic);
        let i = L::bitcast(self.b, L::ITY, t);
        let m = L::iconst(self.b, table.len() as u64 - 1);
        let i = self.b.ins().band(i, m);
        let off = self.b.ins().ishl_imm_u(i, 4);
        let base = self.b.ins().iconst(types::I64, table.as_ptr() as i64);
        let flags = MemFlagsData::new().with_notrap().with_readonly();
        let mut rows = Vec::with_capacity(usize::from(L::LANES));
        for lane in 0..L::LANES {
            let ol = if L::LANES == 1 { off } else { self.b.ins().extractlane(off, lane) };
            rows.push(self.b.ins().iadd(base, ol));
        }
        if L::LANES == 1 {
            let head = self.b.ins().load(types::F64, flags, rows[0], 0);
            return (head, self.b.ins().load(types::F64, flags, rows[0], 8));
        }
        if L::LANES != 2 {
            self.error = Some(NativeError::internal("lookup_pair handles one or two lanes"));
            return (x, x);
        }
        let le = MemFlagsData::new().with_endianness(Endianness::Little);
        let [r0, r1] = [rows[0], rows[1]].map(|a| {
            let row = self.b.ins().load(types::F64X2, flags, a, 0);
            self.b.ins().bitcast(types::I8X16, le, row)
        });
        // Byte shuffles that Cranelift's x64 backend emits as `punpcklqdq` / `punpckhqdq`.
        let low: [u8; 16] = std::array::from_fn(|k| if k < 8 { k as u8 } else { 8 + k as u8 });
        let high: [u8; 16] = std::array::from_fn(|k| low[k] + 8);
        let [heads, tails] = [low, high].map(|mask| {
            let imm = self.b.func.dfg.immediates.push(mask.to_vec().into());
            let v = self.b.ins().shuffle(r0, r1, imm);
            self.b.ins().bitcast(L::TY, le, v)
        });
        (heads, tails)
    }
    fn lanes(&self) -> u32 {
        u32::from(L::LANES)
    }
    fn rare(&mut self, m: Value, r: Value, slow: &mut dyn FnMut(&mut Self) -> Value) -> Value {
        ops::rare(self, m, r, slow)
    }
    fn rare_call(&mut self, m: Value, r: Value, f: Builtin, args: &[Value], slow: &mut dyn FnMut(&mut Self) -> Value) -> Value {
        ops::rare_call(self, m, r, f, args, slow)
    }
    fn fallback(&mut self, m: Value, x: Value, r: Value, f: Builtin) -> Value {
        ops::fallback(self, m, x, r, f)
    }
}

/// Branches in Cranelift: `brif` on `any(m)`, the join's values its block parameters.
impl<L: Lanes> Branch for Translator<'_, '_, L> {
    type Open = (Block, Vec<Value>);
    fn branch_any(&mut self, m: Value, skip: &[Value], _: bool) -> Self::Open {
        let inside = self.b.create_block();
        let join = self.b.create_block();
        let params: Vec<Value> = skip.iter().map(|_| self.b.append_block_param(join, L::TY)).collect();
        let any = L::any(self.b, m);
        let args: Vec<BlockArg> = skip.iter().map(|v| BlockArg::Value(*v)).collect();
        self.b.ins().brif(any, inside, &[], join, &args);
        self.b.switch_to_block(inside);
        self.b.seal_block(inside);
        (join, params)
    }
    fn join(&mut self, (join, params): Self::Open, vals: &[Value]) -> Vec<Value> {
        let args: Vec<BlockArg> = vals.iter().map(|v| BlockArg::Value(*v)).collect();
        self.b.ins().jump(join, &args);
        self.b.switch_to_block(join);
        self.b.seal_block(join);
        params
    }
    fn nonzero(&mut self, v: Value) -> Value {
        let zero = L::konst(self.b, 0);
        self.b.ins().fcmp(FloatCC::NotEqual, v, zero)
    }
}

/// Integer lanes in Cranelift: `L::ITY` values, bit casts of `L::TY`.
impl<L: Lanes> Bits for Translator<'_, '_, L> {
    type I = Value;
    fn to_bits(&mut self, x: Value) -> Value {
        L::bitcast(self.b, L::ITY, x)
    }
    fn of_bits(&mut self, i: Value) -> Value {
        L::bitcast(self.b, L::TY, i)
    }
    fn int(&mut self, v: u64) -> Value {
        L::iconst(self.b, v)
    }
    fn iand(&mut self, a: Value, b: Value) -> Value {
        self.b.ins().band(a, b)
    }
    fn ior(&mut self, a: Value, b: Value) -> Value {
        self.b.ins().bor(a, b)
    }
    fn iadd(&mut self, a: Value, b: Value) -> Value {
        self.b.ins().iadd(a, b)
    }
    fn shl(&mut self, i: Value, n: u32) -> Value {
        self.b.ins().ishl_imm_u(i, i64::from(n))
    }
    fn ushr(&mut self, i: Value, n: u32) -> Value {
        self.b.ins().ushr_imm_u(i, i64::from(n))
    }
}

/// Per-lane calls in Cranelift: the module's import of the builtin (one per builtin: [`symbols`] chose the
/// library function or the C library's fallback for this module), called on `F64` lanes.
impl<L: Lanes> Calls for Translator<'_, '_, L> {
    type Func = FuncRef;
    type Lane = Value;
    fn function(&mut self, f: Builtin, _: Callee) -> Option<FuncRef> {
        self.cx.callees[f as usize]
    }
    fn lane(&mut self, v: Value, i: u32) -> Value {
        L::lane(self.b, v, i as u8)
    }
    fn call(&mut self, func: FuncRef, args: &[Value]) -> Result<Value, NativeError> {
        let inst = self.b.ins().call(func, args);
        self.b.inst_results(inst).first().copied().ok_or(NativeError::internal("call without result"))
    }
    fn gather(&mut self, lanes: &[Value]) -> Value {
        L::from_lanes(self.b, lanes)
    }
    fn record(&mut self, e: NativeError) {
        self.error.get_or_insert(e);
    }
}

fn import_callees(
    module: &mut JITModule,
    func: &mut cranelift_codegen::ir::Function,
    imports: &Imports,
) -> Callees {
    let mut callees = [None; Builtin::ALL.len()];
    for (slot, id) in callees.iter_mut().zip(imports.iter()) {
        if let Some(id) = id {
            *slot = Some(module.declare_func_in_func(*id, func));
        }
    }
    callees
}

fn signature(module: &JITModule, pointers: usize, ret: bool) -> Signature {
    let ptr = module.target_config().pointer_type();
    let mut s = module.make_signature();
    s.params.extend(std::iter::repeat_n(AbiParam::new(ptr), pointers));
    if ret {
        s.returns.push(AbiParam::new(types::F64));
    }
    s
}

/// `fn(params: *const f64, block: *mut f64)`.
pub(super) fn prepare_signature(module: &JITModule) -> Signature {
    signature(module, 2, false)
}

/// `fn(x: *const f64, params: *const f64, block: *const f64) -> f64` in the host's C calling convention.
pub(super) fn scalar_signature(module: &JITModule) -> Signature {
    signature(module, 3, true)
}

/// `fn(cols: *const *const f64, params: *const f64, block: *const f64, out: *mut f64, len: usize)`.
pub(super) fn batch_signature(module: &JITModule) -> Signature {
    signature(module, 5, false)
}

/// What every function builder needs.
pub(super) struct Build<'a> {
    pub ir: &'a Ir,
    pub plan: &'a Plan,
    pub imports: &'a Imports,
    pub mode: Mode,
    /// The host has a native fused multiply-add.
    pub fma: bool,
    /// Math builtins are called, not inlined ([`crate::backend::native::outlines`]).
    pub outline: bool,
}

impl Build<'_> {
    /// What the translators of a function with these `params` and `block` pointers share.
    fn shared(&self, params: Value, block: Value, callees: Callees) -> Shared<'_> {
        Shared { ir: self.ir, params, block, callees, invariants: vec![], mode: self.mode, fma: self.fma, outline: self.outline }
    }
}

/// A function builder over `ctx` with an entry block holding the function's parameters.
fn begin<'f>(
    module: &mut JITModule,
    ctx: &'f mut Context,
    fctx: &'f mut FunctionBuilderContext,
    sig: Signature,
    imports: &Imports,
) -> (FunctionBuilder<'f>, Callees, Vec<Value>) {
    ctx.func.signature = sig;
    let callees = import_callees(module, &mut ctx.func, imports);
    let mut b = FunctionBuilder::new(&mut ctx.func, fctx);
    let entry = b.create_block();
    b.append_block_params_for_function_params(entry);
    b.switch_to_block(entry);
    b.seal_block(entry);
    let args = b.block_params(entry).to_vec();
    (b, callees, args)
}

/// Builds the prepare function: every carried node computed in `F64` and stored to the block.
pub(super) fn build_prepare(
    module: &mut JITModule,
    ctx: &mut Context,
    fctx: &mut FunctionBuilderContext,
    w: &Build,
) -> Result<(), NativeError> {
    let (mut b, callees, args) = begin(module, ctx, fctx, prepare_signature(module), w.imports);
    let [params, block] = args[..] else { return Err(NativeError::internal("prepare signature")) };
    let cx = w.shared(params, block, callees);
    // Invariant nodes read no input: the source is never used.
    let mut t = cx.translator::<F64>(&mut b, vec![None; w.ir.len()], Source::Ptr(params));
    frame::prepare(&mut t, w.plan)?;
    b.ins().return_(&[]);
    b.finalize(module.target_config());
    Ok(())
}

/// Builds the scalar kernel: carried nodes loaded from the block, the rest computed.
pub(super) fn build_scalar(
    module: &mut JITModule,
    ctx: &mut Context,
    fctx: &mut FunctionBuilderContext,
    w: &Build,
) -> Result<(), NativeError> {
    let (mut b, callees, args) = begin(module, ctx, fctx, scalar_signature(module), w.imports);
    let [x, params, block] = args[..] else { return Err(NativeError::internal("scalar signature")) };
    let cx = w.shared(params, block, callees);
    let mut t = cx.translator::<F64>(&mut b, vec![None; w.ir.len()], Source::Ptr(x));
    let r = frame::scalar(&mut t, w.plan)?;
    b.ins().return_(&[r]);
    b.finalize(module.target_config());
    Ok(())
}

/// The lane type of the batch loop.
type V = F64X2;

/// Builds the batched kernel into `ctx` (a compacted arena: root last), the loop in lane type [`V`]:
///
/// ```text
/// entry:       column bases; carried nodes loaded from the block, constants and parameters, in F64;
///              splatted to V where the loop reads them
/// then         the loop of [`batch_loop`], storing the root to out[i]
/// ```
///
/// The carried nodes are computed by the prepare function, not here: Cranelift's optimizer would move their
/// pure computation into the loop (it removes loop-invariant block parameters and elaborates pure values at
/// their use), while a load from the block stays where it is written.
pub(super) fn build_batch(
    module: &mut JITModule,
    ctx: &mut Context,
    fctx: &mut FunctionBuilderContext,
    w: &Build,
) -> Result<(), NativeError> {
    let ptr = module.target_config().pointer_type();
    let plan = w.plan;
    let (mut b, callees, args) = begin(module, ctx, fctx, batch_signature(module), w.imports);
    let [cols, params, block, out, len] = args[..] else { return Err(NativeError::internal("batch signature")) };

    // Entry: column bases, the invariants the loop reads (F64), their splats, the length of the vector part.
    let bases = column_bases::<N_INPUTS>(&mut b, ptr, cols, frame::kernel_columns(w.ir, plan));
    let zero = b.ins().iconst(ptr, 0);
    let mut cx = w.shared(params, block, callees);
    let splats = entry(&mut b, &mut cx, plan, Source::Cols { bases, off: zero })?;
    // The loop-variant nodes of one step, translated in each lane type over the shared invariants.
    let step = LoopStep { cx: &cx, plan, bases, out };
    batch_loop(&mut b, ptr, len, zero, splats, cx.invariants.clone(), &step, 1)?;
    b.finalize(module.target_config());
    Ok(())
}

/// The pointers `cols[k]` for the column slots `slots` of a batched function (kernel or program), `None` in the
/// slots it does not read.
fn column_bases<const N: usize>(b: &mut FunctionBuilder, ptr: Type, cols: Value, slots: Vec<usize>) -> [Option<Value>; N] {
    let mut bases = [None; N];
    for k in slots {
        if let Some(base) = bases.get_mut(k) {
            *base = Some(b.ins().load(ptr, mem(), cols, (k * 8) as i32));
        }
    }
    bases
}

/// The entry of a batched function (kernel or program): the carried nodes loaded from the block and the
/// plan's entry nodes (invariant constants and parameters) computed in `F64`, kept in `cx.invariants` for the
/// tail; returned: their splats to [`V`], which the loop reads.
fn entry(b: &mut FunctionBuilder, cx: &mut Shared, plan: &Plan, source: Source) -> Result<Vec<Option<Value>>, NativeError> {
    let len = cx.ir.len();
    let mut t = cx.translator::<F64>(b, vec![None; len], source);
    frame::entry(&mut t, plan)?;
    cx.invariants = std::mem::take(&mut t.vals);
    let mut splats = vec![None; len];
    for id in cx.ir.ids().take(plan.len()) {
        if let (false, Some(s)) = (plan.variant(id), cx.invariants[id.index()]) {
            splats[id.index()] = Some(V::splat(b, s));
        }
    }
    Ok(splats)
}

/// One step of a batched function's loop, emitted in each lane type: `at.len()` copies, copy `c` for the
/// `L::LANES` elements at index `at[c]` over the invariants `vals[c]` (as `L` values). Copies may interleave
/// their instructions (the shading programs' wide step) or follow one another.
trait LoopBody {
    fn emit<L: Lanes>(&self, b: &mut FunctionBuilder, vals: Vec<Vec<Option<Value>>>, at: &[Value]) -> Result<(), NativeError>;
}

/// The loop of every batched function (kernels and multi-output programs), continuing from the entry block
/// (which has computed `splats`, the invariants in lane type [`V`], and `invariants`, the same in `F64`);
/// `zero` is the pointer-sized constant 0:
///
/// ```text
/// wide(i):     (when wide > 1) i < len & !(wide·V::LANES − 1) ? wide_body : header(i)
/// wide_body:   `wide` copies, the vectors at i, i + V::LANES, …; wide(i + wide·V::LANES)
/// header(i):   i < len & !(V::LANES − 1) ? body : tail_check
/// body:        the V::LANES elements at i; header(i + V::LANES)
/// tail_check:  len & (V::LANES − 1) ≠ 0 ? tail : exit
/// tail:        the last element, in F64 (one element: V has at most two lanes)
/// exit:        return
/// ```
#[allow(clippy::too_many_arguments)]
fn batch_loop<S: LoopBody>(
    b: &mut FunctionBuilder,
    ptr: Type,
    len: Value,
    zero: Value,
    splats: Vec<Option<Value>>,
    invariants: Vec<Option<Value>>,
    step: &S,
    wide: usize,
) -> Result<(), NativeError> {
    // A wider lane type leaves up to LANES − 1 elements and needs a tail loop instead of one tail element.
    const { assert!(V::LANES == 1 || V::LANES == 2, "the batch tail handles one element") };
    if !wide.is_power_of_two() {
        return Err(NativeError::Internal(format!("a loop step of {wide} vectors")));
    }
    let start = if wide > 1 {
        let (header, body, rest) = (b.create_block(), b.create_block(), b.create_block());
        let per_step = wide as i64 * i64::from(V::LANES);
        let wide_end = b.ins().band_imm_s(len, -per_step);
        b.ins().jump(header, &[BlockArg::Value(zero)]);
        b.switch_to_block(header);
        let i = b.append_block_param(header, ptr);
        let more = b.ins().icmp(IntCC::UnsignedLessThan, i, wide_end);
        b.ins().brif(more, body, &[], rest, &[BlockArg::Value(i)]);
        b.switch_to_block(body);
        b.seal_block(body);
        let at: Vec<Value> = (0..wide).map(|k| if k == 0 { i } else { b.ins().iadd_imm_u(i, (k as i64) * i64::from(V::LANES)) }).collect();
        step.emit::<V>(b, vec![splats.clone(); wide], &at)?;
        let next = b.ins().iadd_imm_u(i, per_step);
        b.ins().jump(header, &[BlockArg::Value(next)]);
        b.seal_block(header);
        b.switch_to_block(rest);
        let start = b.append_block_param(rest, ptr);
        b.seal_block(rest);
        start
    } else {
        zero
    };
    let header = b.create_block();
    let body = b.create_block();
    let tail_check = b.create_block();
    let tail = b.create_block();
    let exit = b.create_block();
    let vector_end = b.ins().band_imm_s(len, -i64::from(V::LANES));
    b.ins().jump(header, &[BlockArg::Value(start)]);

    b.switch_to_block(header);
    let i = b.append_block_param(header, ptr);
    let more = b.ins().icmp(IntCC::UnsignedLessThan, i, vector_end);
    b.ins().brif(more, body, &[], tail_check, &[]);

    b.switch_to_block(body);
    b.seal_block(body);
    step.emit::<V>(b, vec![splats], &[i])?;
    let next = b.ins().iadd_imm_u(i, i64::from(V::LANES));
    b.ins().jump(header, &[BlockArg::Value(next)]);
    b.seal_block(header);

    b.switch_to_block(tail_check);
    b.seal_block(tail_check);
    let rest = b.ins().band_imm_s(len, i64::from(V::LANES - 1));
    b.ins().brif(rest, tail, &[], exit, &[]);

    b.switch_to_block(tail);
    b.seal_block(tail);
    step.emit::<F64>(b, vec![invariants], &[vector_end])?;
    b.ins().jump(exit, &[]);

    b.switch_to_block(exit);
    b.seal_block(exit);
    b.ins().return_(&[]);
    Ok(())
}

/// What one step of the batch loop needs, whatever its lane type.
struct LoopStep<'a> {
    /// With the invariants' `F64` values.
    cx: &'a Shared<'a>,
    plan: &'a Plan,
    bases: [Option<Value>; N_INPUTS],
    out: Value,
}

impl LoopBody for LoopStep<'_> {
    /// Per copy: translates the loop-variant nodes for the `L::LANES` elements at index `i` and stores the
    /// root to `out[i..]`.
    fn emit<L: Lanes>(&self, b: &mut FunctionBuilder, vals: Vec<Vec<Option<Value>>>, at: &[Value]) -> Result<(), NativeError> {
        for (vals, &i) in vals.into_iter().zip(at) {
            let off = b.ins().ishl_imm_u(i, 3);
            let source = Source::Cols { bases: self.bases, off };
            let mut t = self.cx.translator::<L>(b, vals, source);
            let r = frame::kernel_step(&mut t, self.plan)?;
            let dst = b.ins().iadd(self.out, off);
            b.ins().store(mem(), r, dst, 0);
        }
        Ok(())
    }
}
