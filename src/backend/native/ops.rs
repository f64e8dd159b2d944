//! The math library's operations that are not one instruction, written once over a tier's primitives: the bit
//! sequences ([`Emit::mask_bits`], [`Emit::pow2i`], [`Emit::exponent_field`]) over [`Bits`]' integer lanes;
//! the compare-and-select and the exact product (`Arith::positive_select`, `Arith::two_prod`); the calls of a
//! compiled function once per lane ([`Lower::library`], [`Emit::rare_call`], [`Emit::fallback`]) over
//! [`Calls`]; and the rare block ([`Emit::rare`]) over [`Branch`]. A tier's `Emit`/`Arith`/`Lower` method is
//! then one line calling the function here, so both tiers emit the same instructions in the same order.

use super::lower::Lower;
use super::NativeError;
use crate::builtins::math::{self, Emit};
use crate::builtins::Builtin;

/// A tier's integer lanes of the same shape as its values, for the bit sequences below.
pub(crate) trait Bits: Emit {
    /// `u64` lanes.
    type I: Copy;
    /// The bits of `x` (a reinterpretation).
    fn to_bits(&mut self, x: Self::V) -> Self::I;
    /// The value of bits `i`.
    fn of_bits(&mut self, i: Self::I) -> Self::V;
    /// `v` in every lane.
    fn int(&mut self, v: u64) -> Self::I;
    fn iand(&mut self, a: Self::I, b: Self::I) -> Self::I;
    fn ior(&mut self, a: Self::I, b: Self::I) -> Self::I;
    /// Wrapping addition.
    fn iadd(&mut self, a: Self::I, b: Self::I) -> Self::I;
    /// `i << n`.
    fn shl(&mut self, i: Self::I, n: u32) -> Self::I;
    /// `i >> n`, logical.
    fn ushr(&mut self, i: Self::I, n: u32) -> Self::I;
}

/// [`Emit::mask_bits`]: `from_bits((bits(x) & and) | or)`.
pub(crate) fn mask_bits<T: Bits>(t: &mut T, x: T::V, and: u64, or: u64) -> T::V {
    let i = t.to_bits(x);
    let m = t.int(and);
    let mut i = t.iand(i, m);
    if or != 0 {
        let o = t.int(or);
        i = t.ior(i, o);
    }
    t.of_bits(i)
}

/// [`Emit::pow2i`]: `from_bits((bits(k + MAGIC) + 1023 − bits(MAGIC)) << 52)`.
pub(crate) fn pow2i<T: Bits>(t: &mut T, k: T::V) -> T::V {
    let magic = t.konst(math::MAGIC);
    let s = t.add(k, magic);
    let i = t.to_bits(s);
    let bias = t.int(1023u64.wrapping_sub(math::MAGIC.to_bits()));
    let i = t.iadd(i, bias);
    let i = t.shl(i, 52);
    t.of_bits(i)
}

/// [`Emit::exponent_field`]: `from_bits(((bits(x) >> 52) & 0x7ff) | bits(2^52)) − 2^52`.
pub(crate) fn exponent_field<T: Bits>(t: &mut T, x: T::V) -> T::V {
    const TWO52: f64 = 4503599627370496.0;
    let i = t.to_bits(x);
    let i = t.ushr(i, 52);
    let m = t.int(0x7ff);
    let i = t.iand(i, m);
    let o = t.int(TWO52.to_bits());
    let i = t.ior(i, o);
    let f = t.of_bits(i);
    let c = t.konst(TWO52);
    t.sub(f, c)
}

/// `Arith::positive_select`: `0 < c ? a : b`.
pub(crate) fn positive_select<T: Emit>(t: &mut T, c: T::V, a: T::V, b: T::V) -> T::V {
    let zero = t.konst(0.0);
    let m = t.lt(zero, c);
    t.select(m, a, b)
}

/// `Arith::two_prod`: `p = a·b` and its exact error `fma(a, b, −p)` with a hardware FMA, Dekker's split
/// without one.
pub(crate) fn two_prod<T: Lower>(t: &mut T, a: T::V, b: T::V) -> (T::V, T::V) {
    if !t.scope().fma {
        return math::dekker_two_prod(t, a, b);
    }
    let p = t.mul(a, b);
    let np = t.neg(p);
    (p, t.fma(a, b, np))
}

/// Which compiled function of a builtin a call site wants.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Callee {
    /// Its library function compiled by rustc ([`Builtin::outlined`]).
    Library,
    /// The C library's version, for the arguments the inline code leaves to it ([`Builtin::libm1`]).
    Fallback,
}

/// A tier's calls of a compiled `extern "C"` function of `f64`s: one lane at a time.
pub(crate) trait Calls: Lower {
    /// What the tier calls (an imported function, an address).
    type Func: Copy;
    /// One lane of a value, an `f64` as the call takes it.
    type Lane: Copy;
    /// `f`'s compiled function of kind `which` in this function's code, if it has one.
    fn function(&mut self, f: Builtin, which: Callee) -> Option<Self::Func>;
    /// Lane `i` of `v`.
    fn lane(&mut self, v: Self::V, i: u32) -> Self::Lane;
    /// `func(args)`.
    fn call(&mut self, func: Self::Func, args: &[Self::Lane]) -> Result<Self::Lane, NativeError>;
    /// A value from its lanes, lane 0 first.
    fn gather(&mut self, lanes: &[Self::Lane]) -> Self::V;
    /// Records an error raised inside an [`Emit`] method (the first one is kept), for [`Lower::take_error`].
    fn record(&mut self, e: NativeError);
}

/// `func` called on each lane of `args`, the results gathered into one value.
fn call_lanes<T: Calls>(t: &mut T, func: T::Func, args: &[T::V]) -> Result<T::V, NativeError> {
    let mut lanes = Vec::with_capacity(t.lanes() as usize);
    for lane in 0..t.lanes() {
        let vals: Vec<T::Lane> = args.iter().map(|a| t.lane(*a, lane)).collect();
        lanes.push(t.call(func, &vals)?);
    }
    Ok(t.gather(&lanes))
}

/// `any(m) ? (m ? func(args) : r) : r`, one call per lane inside an [`Emit::rare`] block.
fn rare_lanes<T: Calls>(t: &mut T, m: T::M, r: T::V, func: T::Func, args: &[T::V]) -> T::V {
    let args = args.to_vec();
    t.rare(m, r, &mut |t| match call_lanes(t, func, &args) {
        Ok(y) => t.select(m, y, r),
        Err(e) => {
            t.record(e);
            r
        }
    })
}

/// [`Lower::library`]: `f`'s library function called on each lane of `args`.
pub(crate) fn library<T: Calls>(t: &mut T, f: Builtin, args: &[T::V]) -> Result<T::V, NativeError> {
    let func = t.function(f, Callee::Library).ok_or_else(|| NativeError::Internal(format!("builtin `{}` has no library function here", f.name())))?;
    call_lanes(t, func, args)
}

/// [`Emit::rare_call`]: `f`'s library function on the rare lanes when this code has it (the rare code's
/// constants then do not stay live across the common path), else `slow`, the rest of `f`'s code.
pub(crate) fn rare_call<T: Calls>(t: &mut T, m: T::M, r: T::V, f: Builtin, args: &[T::V], slow: &mut dyn FnMut(&mut T) -> T::V) -> T::V {
    match t.function(f, Callee::Library) {
        Some(func) => rare_lanes(t, m, r, func, args),
        None => t.rare(m, r, slow),
    }
}

/// [`Emit::fallback`]: `any(m) ? (m ? libm(x) : r) : r`, the C library's version of `f` on the lanes that need it.
pub(crate) fn fallback<T: Calls>(t: &mut T, m: T::M, x: T::V, r: T::V, f: Builtin) -> T::V {
    match t.function(f, Callee::Fallback) {
        Some(func) => rare_lanes(t, m, r, func, &[x]),
        None => {
            t.record(NativeError::Internal(format!("`{}` has no C library fallback here", f.name())));
            r
        }
    }
}

/// A tier's two-way branch on any lane of a mask, and the join after it (a rare block, a program's region).
pub(crate) trait Branch: Emit {
    /// What [`Branch::join`] needs of the branch.
    type Open;
    /// Branches on `any(m)` into a new block, where the builder is left; the other edge goes to the join with
    /// `skip`. `rare`: the block is rarely run (a tier may weight the branch so).
    fn branch_any(&mut self, m: Self::M, skip: &[Self::V], rare: bool) -> Self::Open;
    /// Leaves the block for the join with `vals` (one for each `skip`), where the builder is left; the join's
    /// values, `vals` or `skip` by the edge taken.
    fn join(&mut self, open: Self::Open, vals: &[Self::V]) -> Vec<Self::V>;
    /// `v ≠ 0`, not equal or unordered (a NaN is nonzero, as the interpreter's `lit != 0`).
    fn nonzero(&mut self, v: Self::V) -> Self::M;
}

/// [`Emit::rare`]: `any(m) ? slow() : r`, the slow code in a block of its own.
pub(crate) fn rare<T: Branch>(t: &mut T, m: T::M, r: T::V, slow: &mut dyn FnMut(&mut T) -> T::V) -> T::V {
    let open = t.branch_any(m, &[r], true);
    let v = slow(t);
    t.join(open, &[v]).first().copied().unwrap_or(r)
}
