//! lobe's math library: every transcendental builtin defined once, as straight-line code over [`Emit`].
//!
//! Design. Each function (exp, ln, pow, sin, cos, tan, acos, asin, atan) is written once, generic over an
//! [`Emit`] implementation that supplies IEEE primitives (add, mul, div, sqrt, fused multiply-add, compare,
//! select) and three bit-level ones (2^k from an integer-valued k, the exponent field, masking bits). [`Direct`]
//! runs the code on `f64` (the interpreter and constant folding); the JIT implements `Emit` over Cranelift
//! values, in scalar and vector lanes. Every primitive is one correctly rounded IEEE operation (`fma` included:
//! one rounding, whether the host has the instruction or the JIT calls a correctly rounded library `fma`) or an
//! exact bit operation, and nothing else is fused, so the interpreter and the JIT compute the same bits for
//! every input in every lane shape. Branches are selects (both sides computed, one kept), which is what vector
//! lanes need; the one exception is the trigonometric functions' huge arguments (|x| > 2^19·π/2, ±inf, NaN):
//! those lanes call the C library through [`Emit::fallback`], a branch taken only when some lane needs it.
//!
//! Precise mode: the algorithms and minimax coefficients of fdlibm (Sun Microsystems, freely redistributable),
//! rewritten with selects, except exp; `tan` is the quotient of the sine and cosine kernels. exp is
//! table-driven (2^(j/16) in head and tail, `math_tables.rs`; a degree-7 polynomial; one FMA rounding; no
//! division). `pow` computes ln|x| and y·ln|x| in double-double (a 47-entry table of ln(j/64), exact products
//! by FMA), then that exp on the double-double argument, so exp's argument is exact far below an ulp even when
//! |y·ln x| is near 745. Measured over 10^5 points per function (edge classes included) every function is
//! within 1 ulp of the C library (tan 2); the table states 2 ulp (tan 3) against the correctly rounded result,
//! and the tests hold it to that.
//!
//! Fast mode: the same reductions with shorter polynomials (Taylor series of degree 7–9 where the argument is
//! small; exp a degree-6 Chebyshev fit with FMA reduction, one scaling and no special-case selects beyond the
//! clamp and the underflow flush), pow in plain double (error ≈ |y·ln x|·2^−53 ≤ 1e−13 relative), and no hi/lo
//! corrections; every function stays within 1e−6 relative (1e−6 absolute near zero).
//!
//! Cost model: straight-line code of 20–200 primitive operations per function (exp ≈ 45, acos ≈ 35, pow ≈ 150
//! precise / 70 fast), table loads in exp and precise pow, and special cases in rarely taken blocks, so it
//! vectorises as is. In F64X2 lanes the batched cost follows the instruction count (the loop runs at a high
//! IPC), not the divisions: a table-driven ln (three lookups, no division) measured slower than the
//! two-division one kept here. Inlined at every call site it costs compile time (~5 ms per `sin` in
//! Cranelift), which is why the JIT calls this same code, compiled by rustc, for formulas with many call sites.

// The constants are written as fdlibm publishes them (more digits than a double holds; each rounds to the
// intended bits), and some are split values of π/2 or 1/ln 2 on purpose, not approximations of std's.
#![allow(clippy::excessive_precision, clippy::approx_constant)]

use super::Builtin;
use super::dd::{fast_two_sum, two_sum, two_sum_err, Arith};
/// Dekker's product, for targets without an FMA (the JIT's [`Arith::two_prod`]).
pub(crate) use super::dd::dekker_two_prod;

/// The two math modes: which definition of each builtin a kernel runs.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Mode {
    /// Within a few ulp of the correctly rounded result on the whole domain (the table states each bound).
    #[default]
    Precise,
    /// Within 1e-6 relative (absolute near zero), fewer operations.
    Fast,
}

impl Mode {
    pub const ALL: [Mode; 2] = [Mode::Precise, Mode::Fast];

    pub fn name(self) -> &'static str {
        match self {
            Mode::Precise => "precise",
            Mode::Fast => "fast",
        }
    }
}

impl std::str::FromStr for Mode {
    type Err = String;
    fn from_str(s: &str) -> Result<Mode, String> {
        match s {
            "precise" => Ok(Mode::Precise),
            "fast" => Ok(Mode::Fast),
            _ => Err(format!("unknown math mode `{s}`; expected `precise` or `fast`")),
        }
    }
}

impl std::fmt::Display for Mode {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// The primitives the library is written in. `V` is a value (one `f64` or a vector of lanes), `M` the result of
/// a comparison (one flag per lane). Each method is one IEEE operation or an exact bit operation.
pub(crate) trait Emit: Arith {
    type M: Copy;
    fn abs(&mut self, a: Self::V) -> Self::V;
    /// `a < b` (false when either is NaN).
    fn lt(&mut self, a: Self::V, b: Self::V) -> Self::M;
    /// `a <= b` (false when either is NaN).
    fn le(&mut self, a: Self::V, b: Self::V) -> Self::M;
    /// `a == b` (false when either is NaN).
    fn eq(&mut self, a: Self::V, b: Self::V) -> Self::M;
    fn and(&mut self, a: Self::M, b: Self::M) -> Self::M;
    fn or(&mut self, a: Self::M, b: Self::M) -> Self::M;
    fn not(&mut self, a: Self::M) -> Self::M;
    /// `m ? a : b`, lane by lane.
    fn select(&mut self, m: Self::M, a: Self::V, b: Self::V) -> Self::V;
    /// `m ? +0 : y`, lane by lane: [`Emit::select`] with +0, which vector lanes do as one and-not of the mask
    /// (a blend is three micro-ops on x86).
    fn zero_where(&mut self, m: Self::M, y: Self::V) -> Self::V {
        let zero = self.konst(0.0);
        self.select(m, zero, y)
    }
    /// `from_bits((bits(x) & and) | or)`.
    fn mask_bits(&mut self, x: Self::V, and: u64, or: u64) -> Self::V;
    /// `from_bits((bits(k + MAGIC) + 1023 − bits(MAGIC)) << 52)` with wrapping integer arithmetic: 2^k for an
    /// integer-valued `k` in [−1022, 1023] (see [`pow2i`]).
    fn pow2i(&mut self, k: Self::V) -> Self::V;
    /// `from_bits(((bits(x) >> 52) & 0x7ff) | bits(2^52)) − 2^52`: the biased exponent field as a number.
    fn exponent_field(&mut self, x: Self::V) -> Self::V;
    /// `table[i & (len − 1)]` lane by lane, as the two values of that row, `i` being `bits(x + MAGIC)` (see
    /// [`table_index`]; `len` is a power of two): for |x| < 2^51 the addition rounds x to the nearest integer
    /// (ties to even) and `i`'s low bits are that integer modulo `len`; any other `x` (NaN) still reads inside
    /// the table. A row is 16 bytes, so vector lanes load it in one instruction (the tables pair a head with
    /// its tail).
    fn lookup_pair(&mut self, table: &'static [[f64; 2]], x: Self::V) -> (Self::V, Self::V);
    /// `any(m) ? slow() : r`: code for rare lanes (special cases), run only when some lane needs it. `slow` must
    /// return `r`'s value in every lane where `m` is false, so the result does not depend on the lane shape.
    fn rare(&mut self, m: Self::M, r: Self::V, slow: &mut dyn FnMut(&mut Self) -> Self::V) -> Self::V
    where
        Self: Sized;
    /// [`Emit::rare`] where `slow` is the rest of builtin `f`'s own code on `args`: the JIT may instead call
    /// `f`'s compiled library function ([`Builtin::outlined`]) per lane, the same bits, so the rare code's
    /// constants do not stay live (spilled) across the common path's loop.
    fn rare_call(&mut self, m: Self::M, r: Self::V, f: Builtin, args: &[Self::V], slow: &mut dyn FnMut(&mut Self) -> Self::V) -> Self::V
    where
        Self: Sized,
    {
        let _ = (f, args);
        self.rare(m, r, slow)
    }
    /// `m ? libm(x) : r` lane by lane, `libm` being the C library's version of `f` ([`Builtin::libm1`]).
    fn fallback(&mut self, m: Self::M, x: Self::V, r: Self::V, f: Builtin) -> Self::V;
    /// Elements per value: 1 for scalars, else the vector's lanes. Only a choice between two codings of the
    /// same bits depends on it ([`scale2`]).
    fn lanes(&self) -> u32;
}

/// 1.5·2^52: adding and subtracting it rounds |x| < 2^51 to the nearest integer (ties to even), and the integer
/// then sits in the low bits of `x + MAGIC`.
pub(crate) const MAGIC: f64 = 6755399441055744.0;
const TWO52: f64 = 4503599627370496.0;

/// The scalar definition of [`Emit::pow2i`], shared by [`Direct`] and the JIT's tests.
pub(crate) fn pow2i(k: f64) -> f64 {
    let i = (k + MAGIC).to_bits().wrapping_add(1023u64.wrapping_sub(MAGIC.to_bits()));
    f64::from_bits(i << 52)
}

/// The scalar definition of [`Emit::exponent_field`].
pub(crate) fn exponent_field(x: f64) -> f64 {
    f64::from_bits(((x.to_bits() >> 52) & 0x7ff) | TWO52.to_bits()) - TWO52
}

/// The scalar definition of the index [`Emit::lookup_pair`] reads: the low bits of `x + MAGIC`, which hold
/// the nearest integer to `x` in two's complement (MAGIC's low 51 bits are zero), masked to the table's
/// power-of-two `len`: that integer modulo `len`.
pub(crate) fn table_index(x: f64, len: usize) -> usize {
    debug_assert!(len.is_power_of_two());
    ((x + MAGIC).to_bits() & (len as u64 - 1)) as usize
}

/// Runs the library on plain `f64`: the reference semantics, used by the interpreter and constant folding.
pub(crate) struct Direct;

impl Arith for Direct {
    type V = f64;
    fn konst(&mut self, c: f64) -> f64 {
        c
    }
    fn add(&mut self, a: f64, b: f64) -> f64 {
        a + b
    }
    fn sub(&mut self, a: f64, b: f64) -> f64 {
        a - b
    }
    fn mul(&mut self, a: f64, b: f64) -> f64 {
        a * b
    }
    fn div(&mut self, a: f64, b: f64) -> f64 {
        a / b
    }
    fn neg(&mut self, a: f64) -> f64 {
        -a
    }
    fn sqrt(&mut self, a: f64) -> f64 {
        a.sqrt()
    }
    fn fma(&mut self, a: f64, b: f64, c: f64) -> f64 {
        a.mul_add(b, c)
    }
    fn positive_select(&mut self, c: f64, a: f64, b: f64) -> f64 {
        if 0.0 < c { a } else { b }
    }
}

impl Emit for Direct {
    type M = bool;
    fn abs(&mut self, a: f64) -> f64 {
        a.abs()
    }
    fn lt(&mut self, a: f64, b: f64) -> bool {
        a < b
    }
    fn le(&mut self, a: f64, b: f64) -> bool {
        a <= b
    }
    fn eq(&mut self, a: f64, b: f64) -> bool {
        a == b
    }
    fn and(&mut self, a: bool, b: bool) -> bool {
        a & b
    }
    fn or(&mut self, a: bool, b: bool) -> bool {
        a | b
    }
    fn not(&mut self, a: bool) -> bool {
        !a
    }
    fn select(&mut self, m: bool, a: f64, b: f64) -> f64 {
        if m {
            a
        } else {
            b
        }
    }
    fn mask_bits(&mut self, x: f64, and: u64, or: u64) -> f64 {
        f64::from_bits((x.to_bits() & and) | or)
    }
    fn pow2i(&mut self, k: f64) -> f64 {
        pow2i(k)
    }
    fn exponent_field(&mut self, x: f64) -> f64 {
        exponent_field(x)
    }
    fn lanes(&self) -> u32 {
        1
    }
    fn rare(&mut self, m: bool, r: f64, slow: &mut dyn FnMut(&mut Self) -> f64) -> f64 {
        if m {
            slow(self)
        } else {
            r
        }
    }
    fn lookup_pair(&mut self, table: &'static [[f64; 2]], x: f64) -> (f64, f64) {
        let [a, b] = table[table_index(x, table.len())];
        (a, b)
    }
    fn fallback(&mut self, m: bool, x: f64, r: f64, f: Builtin) -> f64 {
        match (m, f.libm1()) {
            (true, Some(libm)) => libm(x),
            _ => r,
        }
    }
}

const SIGN: u64 = 0x8000_0000_0000_0000;
const MANTISSA: u64 = 0x000f_ffff_ffff_ffff;
const EXP_ONE: u64 = 0x3ff0_0000_0000_0000;

// Small helpers over Emit, so the algorithms read like the formulas they are.

/// `c0 + x·(c1 + x·(c2 + …))` (Horner, each step one fused multiply-add).
fn horner<E: Emit>(e: &mut E, x: E::V, cs: &[f64]) -> E::V {
    let mut acc = e.konst(cs[cs.len() - 1]);
    for &c in cs[..cs.len() - 1].iter().rev() {
        let k = e.konst(c);
        acc = e.fma(acc, x, k);
    }
    acc
}

fn mulk<E: Emit>(e: &mut E, a: E::V, c: f64) -> E::V {
    let k = e.konst(c);
    e.mul(a, k)
}

fn addk<E: Emit>(e: &mut E, a: E::V, c: f64) -> E::V {
    let k = e.konst(c);
    e.add(a, k)
}

/// `c - a`.
fn ksub<E: Emit>(e: &mut E, c: f64, a: E::V) -> E::V {
    let k = e.konst(c);
    e.sub(k, a)
}

fn ltk<E: Emit>(e: &mut E, a: E::V, c: f64) -> E::M {
    let k = e.konst(c);
    e.lt(a, k)
}

fn eqk<E: Emit>(e: &mut E, a: E::V, c: f64) -> E::M {
    let k = e.konst(c);
    e.eq(a, k)
}

fn is_nan<E: Emit>(e: &mut E, a: E::V) -> E::M {
    let same = e.eq(a, a);
    e.not(same)
}

/// `m ? c : a`.
fn select_k<E: Emit>(e: &mut E, m: E::M, c: f64, a: E::V) -> E::V {
    let k = e.konst(c);
    e.select(m, k, a)
}

/// Whether the sign bit of `s` is set (also for −0 and NaN): ±1 with `s`'s sign, compared with 0.
fn sign_bit<E: Emit>(e: &mut E, s: E::V) -> E::M {
    let unit = e.mask_bits(s, SIGN, EXP_ONE);
    let zero = e.konst(0.0);
    e.lt(unit, zero)
}

/// The magnitude of `x` with the sign of `s`.
fn copysign<E: Emit>(e: &mut E, x: E::V, s: E::V) -> E::V {
    let mag = e.abs(x);
    let neg = e.neg(mag);
    let is_neg = sign_bit(e, s);
    e.select(is_neg, neg, mag)
}

/// `a == b` for two flags.
fn mask_eq<E: Emit>(e: &mut E, a: E::M, b: E::M) -> E::M {
    let both = e.and(a, b);
    let na = e.not(a);
    let nb = e.not(b);
    let neither = e.and(na, nb);
    e.or(both, neither)
}

/// Nearest integer (ties to even) of |x| < 2^51.
fn round_int<E: Emit>(e: &mut E, x: E::V) -> E::V {
    let t = addk(e, x, MAGIC);
    let m = e.konst(MAGIC);
    e.sub(t, m)
}

/// Whether `x` is an integer (every |x| ≥ 2^52 is).
fn is_int<E: Emit>(e: &mut E, x: E::V) -> E::M {
    let a = e.abs(x);
    let k = e.konst(TWO52);
    let big = e.le(k, a);
    let t = e.add(a, k);
    let r = e.sub(t, k);
    let exact = e.eq(r, a);
    e.or(big, exact)
}

// ---- exp ----

const LN2_HI: f64 = 6.93147180369123816490e-01; // 0x3fe62e42_fee00000: k·LN2_HI is exact for |k| < 2^21
const LN2_LO: f64 = 1.90821492927058770002e-10;
const INV_LN2: f64 = 1.44269504088896338700e+00;
/// `y·2^k` for an integer-valued k, rounding once (to nearest, ties to even), subnormal results included, where
/// (y, k) lies in either range its callers use: k in [−1100, 1100] and |y| in [2^-400, 2^400], or k in
/// [−2043, 2043] and |y| in [2^-961, 2^969] (and y = 0, ±∞ or NaN).
///
/// Two codings of the same bits. In 1 or 2 lanes, two scalings ([`scale2_normal`]), whose first product is
/// normal in those ranges wherever the result is not 0, so only the second rounds. But a result below 2^-1022
/// is then a multiplication with a subnormal result, which x86 cores run as a microcode assist (~100 cycles for
/// the whole vector), and Beckmann's exp underflows at 12 % of uniform random cosines: in vectors of 4 or more
/// lanes, where such a lane is then in most vectors, every lane takes [`scale2_exact`] (straight-line, no
/// subnormal arithmetic).
/// Measured on Beckmann's kernel (2026-12-05, 2²⁰ points): LLVM's 8 lanes 5.09 → 3.39 ns/element at uniform
/// cosines, 2.95 → 3.46 where nothing underflows; on Cranelift's 2 lanes the straight-line coding was up to
/// 1.5× slower, and a rare block for the tiny lanes 1.1–1.25×.
fn scale2<E: Emit>(e: &mut E, y: E::V, k: E::V) -> E::V {
    if e.lanes() >= 4 {
        scale2_exact(e, y, k)
    } else {
        scale2_normal(e, y, k)
    }
}

/// `y·2^k` as two scalings by 2^⌊k/2⌉ and the rest: exact unless the result is subnormal or overflows, and
/// then rounding once where y·2^⌊k/2⌉ is normal ([`scale2`]'s range); a smaller y can round twice into the
/// subnormals.
fn scale2_normal<E: Emit>(e: &mut E, y: E::V, k: E::V) -> E::V {
    let half = mulk(e, k, 0.5);
    let k1 = round_int(e, half);
    let k2 = e.sub(k, k1);
    let s1 = e.pow2i(k1);
    let s2 = e.pow2i(k2);
    let y1 = e.mul(y, s1);
    e.mul(y1, s2)
}

/// `y·2^k` rounding once for any normal `y` (and 0, ±∞, NaN; k in [−2043, 2043]), without arithmetic on a
/// subnormal or underflowing value.
///
/// A result of at least 2^-1022 (or a subnormal `y`, 0, ±inf, NaN) is [`scale2_normal`]. A smaller one comes
/// from the bits: y's significand m (±[1, 2)) times 2^(t + 52), t the result's biased exponent (< 1), is the
/// result in units of 2^-1075, below 2^53 in magnitude; adding ±2^53 rounds it to an even number of units
/// exactly as IEEE rounds the subnormal (to nearest, ties to even), and the sum's sign and mantissa bits are
/// the subnormal's encoding. A sum of ±2^54 (the rounding up to 2^-1022) has an odd exponent field where every
/// other sum has an even one, so its lowest exponent bit is the subnormal's carry into the exponent.
fn scale2_exact<E: Emit>(e: &mut E, y: E::V, k: E::V) -> E::V {
    let f = e.exponent_field(y);
    let t = e.add(f, k);
    let one = e.konst(1.0);
    let below = e.lt(t, one);
    let normal = e.le(one, f);
    let tiny = e.and(below, normal);
    // In tiny lanes the scalings use 1 − f instead of k, so none of their products is tiny (the lane's value
    // comes from the bits).
    let k_min = e.sub(one, f);
    let k = e.select(tiny, k_min, k);
    let scaled = scale2_normal(e, y, k);
    // Below t + 52 = −2 the result rounds to 0 either way. In other lanes the exponent is unbounded: pow2i
    // then wraps to ±0, a power of two or ±inf, never a subnormal, so these products stay cheap too.
    let m = e.mask_bits(y, SIGN | MANTISSA, EXP_ONE);
    let ts = addk(e, t, 52.0);
    let low = ltk(e, ts, -2.0);
    let ts = select_k(e, low, -2.0, ts);
    let p = e.pow2i(ts);
    let units = e.mul(m, p);
    let magic = e.mask_bits(y, SIGN, (2.0 * TWO52).to_bits());
    let u = e.add(units, magic);
    let sub = e.mask_bits(u, SIGN | 1 << 52 | MANTISSA, 0);
    e.select(tiny, sub, scaled)
}

/// `x` clamped to [lo, hi] by two compares; NaN passes through (both compares are false).
fn clamp_to<E: Emit>(e: &mut E, x: E::V, lo: f64, hi: f64) -> E::V {
    let l = e.konst(lo);
    let below = e.lt(x, l);
    let x = e.select(below, l, x);
    let h = e.konst(hi);
    let above = e.lt(h, x);
    e.select(above, h, x)
}

/// ln2/16 split so that k·`L2N_HI` is exact for |k| < 2^18 (35 significant bits), and the remainder.
const L2N_HI: f64 = 8.0 * 0.0054152123482253955;
const L2N_LO: f64 = 8.0 * -1.0082281460997769e-13;
const INV_L2N: f64 = 184.6649652337873 / 8.0; // 16/ln 2

/// e^(xh + xl) (xl a small correction to xh), < 0.52 ulp before subnormal rounding.
///
/// k = round(x·16/ln 2), j = k mod 16, x = k·ln2/16 + r with |r| ≤ ln2/32 (+ xl): e^x = 2^(k div 16)
/// ·2^(j/16)·e^r. 2^(j/16) is the table's `T_HI·(1 + T_TAIL)`, e^r − 1 a degree-7 Taylor polynomial
/// (truncation < 2^-59), and the result `T_HI + T_HI·(T_TAIL + (e^r − 1))` rounds once in an FMA, then
/// [`scale2_exp`] (exact unless the result overflows, correctly rounded in the subnormals). No division.
/// Sixteen rows rather than 128 and two more polynomial terms: on AVX-512 the rows are two registers, looked
/// up by permutation; 128 rows took two gathers per vector, a quarter of exp's time (BENCHMARKS.md).
fn exp_dd<E: Emit>(e: &mut E, xh: E::V, xl: E::V) -> E::V {
    let (y, q) = exp_parts(e, xh, xl, -760.0, 720.0);
    scale2_exp(e, y, q)
}

/// [`scale2`] of exp's `y` (in [0.97, 1.96], or NaN): in vectors of 4+ lanes, where [`scale2`] forms subnormal
/// results from the bits in every lane, one product `y·2^q` (exact for q in [−1021, 1023]: the result is normal)
/// unless some lane's q is outside, and then [`scale2`] for the whole vector in a rare block (the same bits).
/// exp and pow rarely underflow (x < −708), unlike the accuracy pass's scaled exponential of Beckmann or Ward,
/// which keeps [`scale2`]. In 1 or 2 lanes [`scale2`] is already two products.
fn scale2_exp<E: Emit>(e: &mut E, y: E::V, q: E::V) -> E::V {
    if e.lanes() < 4 {
        return scale2(e, y, q);
    }
    let low = ltk(e, q, -1021.0);
    let top = e.konst(1023.0);
    let high = e.lt(top, q);
    let out = e.or(low, high);
    let s = e.pow2i(q);
    let r = e.mul(y, s);
    e.rare(out, r, &mut |e| scale2(e, y, q))
}

/// [`exp_dd`] before its scaling: `(y, q)` with e^(xh + xl) = y·2^q, y in [0.97, 1.96] rounded once, xh
/// clamped to [lo, hi] (|lo|, |hi| ≤ 1416, so k·`L2N_HI` stays exact and q within [`scale2`]'s range).
fn exp_parts<E: Emit>(e: &mut E, xh: E::V, xl: E::V, lo: f64, hi: f64) -> (E::V, E::V) {
    let p = exp_parts_tail(e, xh, xl, lo, hi);
    (p.y, p.q)
}

/// [`exp_parts_tail`]'s result: e^(xh + xl) = y·2^q, y = fma(t_hi, tmp, t_hi) rounded once.
struct ExpParts<V> {
    y: V,
    q: V,
    t_hi: V,
    tmp: V,
    /// The operands of the roundings below `tmp`, for [`pow_lo`]: r = rh + rl, em1 = fma(r2, p, r) (e^r − 1),
    /// tmp = t_tail + em1.
    rh: V,
    rl: V,
    r: V,
    r2: V,
    p: V,
    em1: V,
    t_tail: V,
}

/// [`exp_parts`] with the operands of its roundings, from which [`pow_lo`] recovers them.
fn exp_parts_tail<E: Emit>(e: &mut E, xh: E::V, xl: E::V, lo: f64, hi: f64) -> ExpParts<E::V> {
    use super::math_tables::EXP_T;
    // Clamp so k stays small; a clamped (or NaN) lane drops xl, which is only meaningful beside its xh.
    let x = clamp_to(e, xh, lo, hi);
    let same = e.eq(x, xh);
    let zero = e.konst(0.0);
    let xl = e.select(same, xl, zero);
    let kx = mulk(e, x, INV_L2N);
    let k = round_int(e, kx);
    let kh = mulk(e, k, L2N_HI); // exact
    let rh = e.sub(x, kh); // exact: x and k·ln2/16 are within a factor 2 (or k = 0)
    let nl = e.konst(-L2N_LO);
    let rl = e.fma(k, nl, xl);
    let r = e.add(rh, rl);
    // k = 16·q + j with q = floor(k/16): k/16 − 15/32 lies within 0.5 of q.
    let k16 = mulk(e, k, 1.0 / 16.0);
    let qh = addk(e, k16, -15.0 / 32.0);
    let q = round_int(e, qh);
    // The row j = k − 16q = k mod 16: the lookup rounds kx itself (the addition `round_int` made) and keeps
    // the low 4 bits, so j costs no instruction.
    let (t_hi, t_tail) = e.lookup_pair(&EXP_T, kx);
    // (e^r − 1 − r)/r² as three independent pairs c₂ᵢ + c₂ᵢ₊₁·r, then Horner in r²: the operations of Horner's
    // scheme in r, a dependency chain of three instead of five.
    let r2 = e.mul(r, r);
    let [c0, c1, c2, c3, c4, c5] = [1.0 / 2.0, 1.0 / 6.0, 1.0 / 24.0, 1.0 / 120.0, 1.0 / 720.0, 1.0 / 5040.0].map(|c| e.konst(c));
    let p01 = e.fma(r, c1, c0);
    let p23 = e.fma(r, c3, c2);
    let p45 = e.fma(r, c5, c4);
    let hi = e.fma(r2, p45, p23);
    let p = e.fma(r2, hi, p01);
    let em1 = e.fma(r2, p, r);
    let tmp = e.add(t_tail, em1);
    let y = e.fma(t_hi, tmp, t_hi);
    ExpParts { y, q, t_hi, tmp, rh, rl, r, r2, p, em1, t_tail }
}

pub(crate) fn exp<E: Emit>(e: &mut E, x: E::V) -> E::V {
    let zero = e.konst(0.0);
    exp_dd(e, x, zero)
}

/// Fast e^x's polynomial times 2: 2·P(r) ≈ 2e^r with P(r) = 1 + r·G(r), G the degree-5 Chebyshev fit of
/// (e^r − 1)/r on |r| ≤ ln2/2 (relative error of P 5.1e-9; degree 4 gives 2.0e-7, within the bound too, but
/// a formula like F_kutlog's `acos(Q^(1/n))` amplifies it 40× past 1e-6). P(0) = 1 exactly, so e^0 = 1 and
/// pow(1, y) = 1 without a special case. The factor 2 (exact) lets the scaling be 2^(k−1), normal for every k
/// the clamp allows.
const EXP_FAST_2P: [f64; 7] = [
    2.0,
    2.0 * 1.0000000107727665,
    2.0 * 0.5000000013459222,
    2.0 * 0.16666505248452865,
    2.0 * 0.041666464991106766,
    2.0 * 0.008369149818125777,
    2.0 * 0.0013933642689829186,
];

/// Fast e^x: Cody–Waite reduction by two FMAs (r = x − k·ln2, |r| ≤ ln2/2), [`EXP_FAST_2P`], one scaling.
/// The clamp to [−708, 709.9] keeps k in [−1021, 1024], so 2^(k−1) is normal and no operation sees a subnormal
/// (an x86 microcode assist costs ~100 cycles per subnormal operand or result); above e^709.78 the final
/// product overflows to +inf by itself, NaN passes through the clamp, and below −708 the result is flushed to
/// 0 (an absolute error < 3.3e-308).
pub(crate) fn exp_fast<E: Emit>(e: &mut E, x: E::V) -> E::V {
    let below = ltk(e, x, -708.0);
    let (p2, k1) = exp_fast_parts(e, x, -708.0, 709.9);
    let s = e.pow2i(k1);
    let y = e.mul(p2, s);
    e.zero_where(below, y)
}

/// Fast exp before its scaling: `(y, q)` with e^x ≈ y·2^q, y = 2·P(r) in [1.4, 2.9], x clamped to [lo, hi]
/// (within ±1416, so q stays in [`scale2`]'s range).
fn exp_fast_parts<E: Emit>(e: &mut E, x: E::V, lo: f64, hi: f64) -> (E::V, E::V) {
    let xc = clamp_to(e, x, lo, hi);
    let kx = mulk(e, xc, INV_LN2);
    let k = round_int(e, kx);
    let nhi = e.konst(-LN2_HI);
    let hi = e.fma(k, nhi, xc); // exact: k·LN2_HI is, and xc is within a factor 2 of it (or k = 0)
    let nlo = e.konst(-LN2_LO);
    let r = e.fma(k, nlo, hi);
    let p2 = horner(e, r, &EXP_FAST_2P);
    (p2, addk(e, k, -1.0))
}

// ---- ln ----

const SQRT2: f64 = std::f64::consts::SQRT_2;
const LG: [f64; 7] = [
    6.666666666666735130e-01,
    3.999999999940941908e-01,
    2.857142874366239149e-01,
    2.222219843214978396e-01,
    1.818357216161805012e-01,
    1.531383769920937332e-01,
    1.479819860511658591e-01,
];

/// `x = 2^k·m` with m in [√2/2, √2] and f = m − 1 (exact), for finite x > 0 (subnormals scaled first).
fn reduce_log<E: Emit>(e: &mut E, x: E::V) -> (E::V, E::V) {
    let (k, m) = reduce_log_m(e, x);
    (k, addk(e, m, -1.0))
}

/// `(k, m)` with x = 2^k·m, m in [√2/2, √2].
fn reduce_log_m<E: Emit>(e: &mut E, x: E::V) -> (E::V, E::V) {
    let tiny = ltk(e, x, f64::MIN_POSITIVE);
    let scaled = mulk(e, x, 18014398509481984.0); // 2^54
    let xs = e.select(tiny, scaled, x);
    let bias = e.konst(1023.0 + 54.0);
    let bias0 = e.konst(1023.0);
    let bias = e.select(tiny, bias, bias0);
    let ef = e.exponent_field(xs);
    let k = e.sub(ef, bias);
    let m = e.mask_bits(xs, MANTISSA, EXP_ONE);
    let root2 = e.konst(SQRT2);
    let big = e.lt(root2, m);
    let mh = mulk(e, m, 0.5);
    let m = e.select(big, mh, m);
    let k1 = addk(e, k, 1.0);
    let k = e.select(big, k1, k);
    (k, m)
}

/// ln of the reduced argument's special classes: `r` where x is finite and > 0, else −inf / NaN / +inf / NaN.
fn log_specials<E: Emit>(e: &mut E, x: E::V, r: E::V) -> E::V {
    let zero = e.konst(0.0);
    let is_zero = e.eq(x, zero);
    let r = select_k(e, is_zero, f64::NEG_INFINITY, r);
    let neg = e.lt(x, zero);
    let r = select_k(e, neg, f64::NAN, r);
    let inf = eqk(e, x, f64::INFINITY);
    let r = select_k(e, inf, f64::INFINITY, r);
    let nan = is_nan(e, x);
    e.select(nan, x, r)
}

pub(crate) fn ln<E: Emit>(e: &mut E, x: E::V) -> E::V {
    let (k, f) = reduce_log(e, x);
    let two_f = addk(e, f, 2.0);
    let s = e.div(f, two_f);
    let z = e.mul(s, s);
    let w = e.mul(z, z);
    let t1 = horner(e, w, &[LG[1], LG[3], LG[5]]);
    let t1 = e.mul(w, t1);
    let t2 = horner(e, w, &[LG[0], LG[2], LG[4], LG[6]]);
    let t2 = e.mul(z, t2);
    let r = e.add(t2, t1);
    let ff = e.mul(f, f);
    let hfsq = mulk(e, ff, 0.5);
    // k·ln2_hi − ((hfsq − (s·(hfsq + R) + k·ln2_lo)) − f)
    let a = e.add(hfsq, r);
    let a = e.mul(s, a);
    let klo = mulk(e, k, LN2_LO);
    let a = e.add(a, klo);
    let a = e.sub(hfsq, a);
    let a = e.sub(a, f);
    let khi = mulk(e, k, LN2_HI);
    let res = e.sub(khi, a);
    log_specials(e, x, res)
}

/// Fast ln: the same reduction, ln m = 2·atanh(s) by its Taylor series to s^13 (|s| ≤ 0.172: < 1e-11 relative,
/// small enough that pow's exp(y·ln x) stays within 1e-6).
pub(crate) fn ln_fast<E: Emit>(e: &mut E, x: E::V) -> E::V {
    let (k, f) = reduce_log(e, x);
    let r = ln_fast_reduced(e, k, f);
    log_specials(e, x, r)
}

fn ln_fast_reduced<E: Emit>(e: &mut E, k: E::V, f: E::V) -> E::V {
    let two_f = addk(e, f, 2.0);
    let s = e.div(f, two_f);
    let z = e.mul(s, s);
    let p = horner(e, z, &[2.0 / 3.0, 2.0 / 5.0, 2.0 / 7.0, 2.0 / 9.0, 2.0 / 11.0, 2.0 / 13.0]);
    let zp = e.mul(z, p);
    let t = e.mul(s, zp);
    let two_s = e.add(s, s);
    let l = e.add(two_s, t);
    let kl = mulk(e, k, std::f64::consts::LN_2);
    e.add(kl, l)
}

/// ln(j/64) for j = 45..=91 (the breakpoints covering [√2/2, √2]), rounded (`HI`) and the remainder (`LO`).
const LN_J64_HI: [f64; 47] = [-0.3522205935893521, -0.33024168687057687, -0.3087354816496133, -0.2876820724517809, -0.26706278524904525, -0.24686007793152578, -0.22705745063534608, -0.2076393647782445, -0.18859116980755003, -0.16989903679539747, -0.15154989812720093, -0.13353139262452263, -0.1158318155251217, -0.09844007281325252, -0.0813456394539524, -0.06453852113757118, -0.048009219186360606, -0.0317486983145803, -0.015748356968139168, 0.0, 0.015504186535965254, 0.030771658666753687, 0.0458095360312942, 0.06062462181643484, 0.07522342123758753, 0.08961215868968714, 0.10379679368164356, 0.11778303565638346, 0.13157635778871926, 0.1451820098444979, 0.15860503017663857, 0.17185025692665923, 0.184922338494012, 0.19782574332991987, 0.21056476910734964, 0.22314355131420976, 0.2355660713127669, 0.24783616390458127, 0.25995752443692605, 0.27193371548364176, 0.2837681731306446, 0.2954642128938359, 0.3070250352949119, 0.3184537311185346, 0.329753286372468, 0.3409265869705932, 0.3519764231571782];
const LN_J64_LO: [f64; 47] = [-5.7233316949182485e-18, 1.0828321637483858e-17, 1.6199186085148102e-17, -2.607160616442564e-17, 7.32891532732017e-18, -1.361743371748368e-17, -9.551415762738488e-18, -1.2053243216686129e-17, 7.432164219196925e-18, 4.868008764439071e-19, -5.1669593684615594e-18, 3.664457663660085e-18, -4.338484369808096e-18, 4.439009633675136e-18, -5.07707635593117e-18, 6.470486661692933e-18, -1.4390903347292205e-18, -3.0382263084680858e-18, -1.0021578630528974e-18, 0.0, -3.278321022892429e-19, 1.0431732029005968e-18, 1.902959866474257e-18, 2.6424025938726934e-18, -5.930604196293241e-18, -5.4268129336647135e-18, 5.47772415726659e-18, -1.1971685747593677e-18, 1.1123000879729588e-17, 8.242418783022475e-18, 1.1257003872182592e-17, -6.0224538210113705e-18, 3.0236614153574064e-18, 1.2821194372980142e-17, -4.249405314729895e-18, -9.091270597324799e-18, -2.3943371495187355e-18, -1.2432209578702523e-17, 2.069806938978935e-17, 7.83319637697442e-19, -2.032665581126656e-17, -2.16461086040599e-17, -1.2319916200101964e-17, 2.7114779367326236e-17, 2.122020616196946e-18, 1.7467136443544747e-17, -1.2953893030191963e-17];
/// `LN_J64_HI` and `LN_J64_LO` as rows, for [`Emit::lookup_pair`] (padded to 64 rows).
static LN_J64: [[f64; 2]; 64] = super::math_tables::pairs(&LN_J64_HI, &LN_J64_LO);

/// ln x as a double-double `(hi, lo)`, relative error < 2^-68, for finite x > 0.
///
/// m (x = 2^k·m, m in [√2/2, √2]) is split at the nearest breakpoint b = j/64: ln m = ln b + 2·atanh(s) with
/// s = (m − b)/(m + b), |s| < 0.0056. Then ln b comes from a table in double-double, s is carried as
/// s_hi + s_lo, and the tail 2s³/3 + 2s⁵/5 + … (relative size < 1.1e-5, so its rounding is far below 2^-68)
/// in plain double. This accuracy is what pow needs: exp amplifies the absolute error of y·ln x, up to 745.
fn ln_dd<E: Emit>(e: &mut E, x: E::V) -> (E::V, E::V) {
    let (k, m) = reduce_log_m(e, x);
    let m64 = mulk(e, m, 64.0);
    let j = round_int(e, m64);
    let b = mulk(e, j, 1.0 / 64.0); // exact
    let num = e.sub(m, b); // exact (Sterbenz)
    let (den, den_lo) = two_sum(e, m, b);
    let s_hi = e.div(num, den);
    let (p, pe) = e.two_prod(s_hi, den);
    let r = e.sub(num, p);
    let r = e.sub(r, pe);
    let sd = e.mul(s_hi, den_lo);
    let r = e.sub(r, sd);
    let s_lo = e.div(r, den);
    let z = e.mul(s_hi, s_hi);
    let q = horner(e, z, &[2.0 / 3.0, 2.0 / 5.0, 2.0 / 7.0, 2.0 / 9.0]);
    let zq = e.mul(z, q);
    let t = e.mul(s_hi, zq);
    let idx = addk(e, j, -45.0);
    let (lb_hi, lb_lo) = e.lookup_pair(&LN_J64, idx);
    let khi = mulk(e, k, LN2_HI); // exact
    let (a, a_err) = two_sum(e, khi, lb_hi);
    let two_s = e.add(s_hi, s_hi);
    let (c, c_err) = two_sum(e, a, two_s);
    let two_slo = e.add(s_lo, s_lo);
    let klo = mulk(e, k, LN2_LO);
    let lo = e.add(two_slo, t);
    let lo = e.add(lo, klo);
    let lo = e.add(lo, lb_lo);
    let lo = e.add(lo, a_err);
    let lo = e.add(lo, c_err);
    fast_two_sum(e, c, lo)
}

// ---- pow ----

/// pow's special cases, as C99 and IEEE 754 define them, applied over `mag` = |x|^y computed for the general
/// case (finite nonzero |x|, finite y).
fn pow_specials<E: Emit>(e: &mut E, x: E::V, y: E::V, mag: E::V) -> E::V {
    let zero = e.konst(0.0);
    let one = e.konst(1.0);
    let inf = e.konst(f64::INFINITY);
    let ax = e.abs(x);
    let ay = e.abs(y);
    let y_neg = e.lt(y, zero);
    // |x| = 0 or inf: 0 or inf by the sign of y (and of log|x|).
    let ax_zero = e.eq(ax, zero);
    let ax_inf = e.eq(ax, inf);
    let edge = e.or(ax_zero, ax_inf);
    let big_result = mask_eq(e, ax_zero, y_neg); // 0^(−y) and inf^(+y) are inf
    let edge_val = e.select(big_result, inf, zero);
    let mag = e.select(edge, edge_val, mag);
    // y = ±inf: 1 at |x| = 1, else 0 or inf by whether |x| < 1 and y < 0 agree.
    let y_inf = e.eq(ay, inf);
    let ax_lt1 = e.lt(ax, one);
    let grows = mask_eq(e, ax_lt1, y_neg);
    let inf_val = e.select(grows, inf, zero);
    let ax_one = e.eq(ax, one);
    let inf_val = e.select(ax_one, one, inf_val);
    let mag = e.select(y_inf, inf_val, mag);
    // Negative x (sign bit set): odd integer y gives a negative result, a non-integer y NaN (finite x only).
    let y_int = is_int(e, y);
    let half_y = mulk(e, y, 0.5);
    let half_int = is_int(e, half_y);
    let not_half = e.not(half_int);
    let odd = e.and(y_int, not_half);
    let x_neg = sign_bit(e, x); // −0 and −inf too
    let flip = e.and(x_neg, odd);
    let negm = e.neg(mag);
    let mag = e.select(flip, negm, mag);
    let x_lt0 = e.lt(x, zero);
    let not_int = e.not(y_int);
    let bad = e.and(x_lt0, not_int);
    let not_inf = e.not(ax_inf);
    let bad = e.and(bad, not_inf);
    let y_fin = e.not(y_inf);
    let bad = e.and(bad, y_fin);
    let mag = select_k(e, bad, f64::NAN, mag);
    // NaN in either operand gives NaN, except pow(1, y) = 1 and pow(x, 0) = 1.
    let xn = is_nan(e, x);
    let yn = is_nan(e, y);
    let any_nan = e.or(xn, yn);
    let mag = select_k(e, any_nan, f64::NAN, mag);
    let x_one = e.eq(x, one);
    let y_zero = e.eq(y, zero);
    let unit = e.or(x_one, y_zero);
    e.select(unit, one, mag)
}

/// |y| from which e^(y·ln|x|) saturates for every |x| ≠ 1 (2^64·2^-53 > 745).
const Y_CAP: f64 = 18446744073709551616.0; // 2^64

/// |x| and y made safe for the general case: |x| finite and > 0 (else 2), y clamped to ±2^64 (any larger |y|
/// already saturates e^(y·ln|x|) for every |x| ≠ 1).
fn pow_operands<E: Emit>(e: &mut E, x: E::V, y: E::V) -> (E::V, E::V) {
    let ax = e.abs(x);
    let zero = e.konst(0.0);
    let pos = e.lt(zero, ax);
    let fin = ltk(e, ax, f64::INFINITY);
    let ok = e.and(pos, fin);
    let two = e.konst(2.0);
    let axs = e.select(ok, ax, two);
    // A clamp (two instructions in vector lanes: min/max); a NaN y stays NaN, for the special-case block.
    let ys = clamp_to(e, y, -Y_CAP, Y_CAP);
    (axs, ys)
}

/// y·ln|x| in double-double (`(hi, lo)`), x and y made safe by [`pow_operands`]: what pow exponentiates.
fn pow_exponent<E: Emit>(e: &mut E, x: E::V, y: E::V) -> (E::V, E::V) {
    let (ax, ys) = pow_operands(e, x, y);
    let (lh, ll) = ln_dd(e, ax);
    let (p, pe) = e.two_prod(ys, lh);
    let yl = e.mul(ys, ll);
    let pl = e.add(pe, yl);
    fast_two_sum(e, p, pl)
}

pub(crate) fn pow<E: Emit>(e: &mut E, x: E::V, y: E::V) -> E::V {
    let (ph, pl) = pow_exponent(e, x, y);
    let mag = exp_dd(e, ph, pl);
    pow_finish(e, x, y, mag)
}

/// pow's special cases, computed only when some lane has one: x not in (0, inf) or |y| not below 2^64 (NaN
/// included). Elsewhere [`pow_specials`] returns `mag` unchanged (x = 1 and y = 0 already give exactly 1).
/// pow(+0, y > 0) = +0 is selected inline: formulas like `max(t, 0)^a` have it in most lanes.
fn pow_finish<E: Emit>(e: &mut E, x: E::V, y: E::V, mag: E::V) -> E::V {
    let zero = e.konst(0.0);
    let pos = e.lt(zero, x);
    let fin = ltk(e, x, f64::INFINITY);
    let ay = e.abs(y);
    let small = ltk(e, ay, Y_CAP);
    let normal = e.and(pos, fin);
    let normal = e.and(normal, small);
    let x_zero = e.eq(x, zero);
    let x_neg = sign_bit(e, x);
    let x_plus = e.not(x_neg);
    let y_pos = e.lt(zero, y);
    let zero_pos = e.and(x_zero, x_plus);
    let zero_pos = e.and(zero_pos, y_pos);
    let mag = e.zero_where(zero_pos, mag);
    let ok = e.or(normal, zero_pos);
    let special = e.not(ok);
    e.rare(special, mag, &mut |e| pow_specials(e, x, y, mag))
}

pub(crate) fn pow_fast<E: Emit>(e: &mut E, x: E::V, y: E::V) -> E::V {
    let (ax, ys) = pow_operands(e, x, y);
    let (k, f) = reduce_log(e, ax);
    let l = ln_fast_reduced(e, k, f);
    let a = e.mul(ys, l);
    let mag = exp_fast(e, a);
    pow_finish(e, x, y, mag)
}

// ---- acos, asin ----

const PIO2_HI: f64 = 1.57079632679489655800e+00;
const PIO2_LO: f64 = 6.12323399573676603587e-17;
const PIO4_HI: f64 = 7.85398163397448278999e-01;
const PI: f64 = 3.14159265358979311600e+00;
const AS_P: [f64; 6] = [
    1.66666666666666657415e-01,
    -3.25565818622400915405e-01,
    2.01212532134862925881e-01,
    -4.00555345006794114027e-02,
    7.91534994289814532176e-04,
    3.47933107596021167570e-05,
];
const AS_Q: [f64; 5] = [
    1.0,
    -2.40339491173441421878e+00,
    2.02094576023350569471e+00,
    -6.88283971605453293030e-01,
    7.70381505559019352791e-02,
];

/// fdlibm's rational approximation R(z) = (asin(√z) − √z)/(√z)³·… : `z·P(z)/Q(z)`.
fn asin_r<E: Emit>(e: &mut E, z: E::V) -> E::V {
    let p = horner(e, z, &AS_P);
    let p = e.mul(z, p);
    let q = horner(e, z, &AS_Q);
    e.div(p, q)
}

/// `(z, s, r)` of the reductions shared by acos and asin: z = x² below |x| = 1/2, (1 − |x|)/2 above, s = √z.
fn asin_reduce<E: Emit>(e: &mut E, ax: E::V, small: E::M, x: E::V) -> (E::V, E::V, E::V) {
    let xx = e.mul(x, x);
    let w = ksub(e, 1.0, ax);
    let t = mulk(e, w, 0.5);
    let z = e.select(small, xx, t);
    let s = e.sqrt(z);
    let r = asin_r(e, z);
    (z, s, r)
}

/// `(df, c)` with df = s with its low 32 bits cleared and c = (z − df²)/(s + df), so df + c = √z to ~2^-80.
fn sqrt_split<E: Emit>(e: &mut E, z: E::V, s: E::V) -> (E::V, E::V) {
    let df = e.mask_bits(s, 0xffff_ffff_0000_0000, 0);
    let dd = e.mul(df, df);
    let n = e.sub(z, dd);
    let d = e.add(s, df);
    (df, e.div(n, d))
}

/// The branch results of the precise acos of an argument clamped to [−1, 1], and the pieces they add (shared with
/// [`acos_lo`], which recovers their roundings; inside one kernel the JIT computes them once).
struct AcosParts<V, M> {
    small: M,
    neg: M,
    /// |x| < 1/2: π/2 − (x − (pio2_lo − x·r)), with x·r.
    res_small: V,
    xr: V,
    /// x < −1/2: π − 2(s + (r·s − pio2_lo)).
    res_neg: V,
    /// |x| > 1/2: 2t, t = df + (r·s + c), df + c = s = √z to ~2^-80.
    res_pos: V,
    t: V,
    rs: V,
    df: V,
    c: V,
}

fn acos_parts<E: Emit>(e: &mut E, x: E::V) -> AcosParts<E::V, E::M> {
    let ax = e.abs(x);
    let small = ltk(e, ax, 0.5);
    let (z, s, r) = asin_reduce(e, ax, small, x);
    let xr = e.mul(x, r);
    let a = ksub(e, PIO2_LO, xr);
    let a = e.sub(x, a);
    let res_small = ksub(e, PIO2_HI, a);
    let rs = e.mul(r, s);
    let w = addk(e, rs, -PIO2_LO);
    let sw = e.add(s, w);
    let sw2 = e.add(sw, sw);
    let res_neg = ksub(e, PI, sw2);
    let (df, c) = sqrt_split(e, z, s);
    let w = e.add(rs, c);
    let t = e.add(df, w);
    let res_pos = e.add(t, t);
    let zero = e.konst(0.0);
    let neg = e.lt(x, zero);
    AcosParts { small, neg, res_small, xr, res_neg, res_pos, t, rs, df, c }
}

/// acos of the argument already clamped to [−1, 1] (NaN passes through).
fn acos_impl<E: Emit>(e: &mut E, x: E::V) -> E::V {
    let p = acos_parts(e, x);
    let big = e.select(p.neg, p.res_neg, p.res_pos);
    let res = e.select(p.small, p.res_small, big);
    // acos(1) = +0 (the general formula divides 0 by 0 there).
    let one = eqk(e, x, 1.0);
    e.zero_where(one, res)
}

/// asin of the argument already clamped to [−1, 1] (NaN passes through).
fn asin_impl<E: Emit>(e: &mut E, x: E::V, precise: bool) -> E::V {
    let ax = e.abs(x);
    let small = ltk(e, ax, 0.5);
    let (z, s, r) = asin_reduce(e, ax, small, x);
    // |x| < 1/2: x + x·r
    let xr = e.mul(x, r);
    let res_small = e.add(x, xr);
    // |x| ≥ 0.975: π/2 − (2(s + s·r) − pio2_lo)
    let sr = e.mul(s, r);
    let a = e.add(s, sr);
    let a = e.add(a, a);
    let a = addk(e, a, -PIO2_LO);
    let res_near1 = ksub(e, PIO2_HI, a);
    let res_mid = if precise {
        // π/4 − ((2s·r − (pio2_lo − 2c)) − (π/4 − 2df))
        let (df, c) = sqrt_split(e, z, s);
        let two_s = e.add(s, s);
        let p = e.mul(two_s, r);
        let c2 = e.add(c, c);
        let q = ksub(e, PIO2_LO, c2);
        let p = e.sub(p, q);
        let df2 = e.add(df, df);
        let q = ksub(e, PIO4_HI, df2);
        let pq = e.sub(p, q);
        ksub(e, PIO4_HI, pq)
    } else {
        res_near1
    };
    let near1 = ltk(e, ax, 0.975);
    let big = e.select(near1, res_mid, res_near1);
    let big = copysign(e, big, x);
    e.select(small, res_small, big)
}

pub(crate) fn acos<E: Emit>(e: &mut E, x: E::V, mode: Mode) -> E::V {
    let x = clamp_to(e, x, -1.0, 1.0);
    match mode {
        Mode::Precise => acos_impl(e, x),
        Mode::Fast => acos_fast(e, x),
    }
}

/// Abramowitz & Stegun 4.4.46: acos|x| = √(1 − |x|)·P(|x|) with a degree-7 P, |error| ≤ 2e-8 (relative
/// ≤ 1.6e-8 as |x| → 1, where P(1) ≈ √2); acos(−x) = π − acos(x). No division, one square root.
const ACOS_AS: [f64; 8] = [
    1.5707963050,
    -0.2145988016,
    0.0889789874,
    -0.0501743046,
    0.0308918810,
    -0.0170881256,
    0.0066700901,
    -0.0012624911,
];

fn acos_fast<E: Emit>(e: &mut E, x: E::V) -> E::V {
    let ax = e.abs(x);
    let p = horner(e, ax, &ACOS_AS);
    let w = ksub(e, 1.0, ax);
    let s = e.sqrt(w);
    let r = e.mul(s, p);
    let zero = e.konst(0.0);
    let neg = e.lt(x, zero);
    let flipped = ksub(e, PI, r);
    e.select(neg, flipped, r)
}

pub(crate) fn asin<E: Emit>(e: &mut E, x: E::V, mode: Mode) -> E::V {
    let x = clamp_to(e, x, -1.0, 1.0);
    asin_impl(e, x, mode == Mode::Precise)
}

// ---- atan ----

const ATAN_HI: [f64; 4] = [
    4.63647609000806093515e-01,
    7.85398163397448278999e-01,
    9.82793723247329054082e-01,
    1.57079632679489655800e+00,
];
const ATAN_LO: [f64; 4] = [
    2.26987774529616870924e-17,
    3.06161699786838301793e-17,
    1.39033110312309984516e-17,
    6.12323399573676603587e-17,
];
const AT_ODD: [f64; 6] = [
    3.33333333333329318027e-01,
    1.42857142725034663711e-01,
    9.09088713343650656196e-02,
    6.66107313738753120669e-02,
    4.97687799461593236017e-02,
    1.62858201153657823623e-02,
];
const AT_EVEN: [f64; 5] = [
    -1.99999999998764832476e-01,
    -1.11111104054623557880e-01,
    -7.69187620504482999495e-02,
    -5.83357013379057348645e-02,
    -3.65315727442169155270e-02,
];

/// atan (fdlibm): |x| reduced by one of five Möbius maps x' = (a·|x| − b)/(c + d·|x|), chosen by selects, then
/// atan|x| = hi − ((x'·S(x'²) − lo) − x').
pub(crate) fn atan<E: Emit>(e: &mut E, x: E::V) -> E::V {
    let ax = e.abs(x);
    // (bound, a, b, c, d, hi, lo) per interval, from the top: each select overrides the wider interval.
    let rows: [(f64, [f64; 4], f64, f64); 4] = [
        (2.4375, [1.0, 1.5, 1.0, 1.5], ATAN_HI[2], ATAN_LO[2]),
        (1.1875, [1.0, 1.0, 1.0, 1.0], ATAN_HI[1], ATAN_LO[1]),
        (0.6875, [2.0, 1.0, 2.0, 1.0], ATAN_HI[0], ATAN_LO[0]),
        (0.4375, [1.0, 0.0, 1.0, 0.0], 0.0, 0.0),
    ];
    // Above 2.4375: x' = −1/|x|, hi/lo = π/2.
    let mut k = [e.konst(0.0), e.konst(1.0), e.konst(0.0), e.konst(1.0)];
    let mut hi = e.konst(ATAN_HI[3]);
    let mut lo = e.konst(ATAN_LO[3]);
    for (bound, coef, h, l) in rows {
        let below = ltk(e, ax, bound);
        for (slot, c) in k.iter_mut().zip(coef) {
            let cv = e.konst(c);
            *slot = e.select(below, cv, *slot);
        }
        let hv = e.konst(h);
        hi = e.select(below, hv, hi);
        let lv = e.konst(l);
        lo = e.select(below, lv, lo);
    }
    let a = e.mul(k[0], ax);
    let num = e.sub(a, k[1]);
    let d = e.mul(k[3], ax);
    let den = e.add(k[2], d);
    let xr = e.div(num, den);
    let z = e.mul(xr, xr);
    let w = e.mul(z, z);
    let s1 = horner(e, w, &AT_ODD);
    let s1 = e.mul(z, s1);
    let s2 = horner(e, w, &AT_EVEN);
    let s2 = e.mul(w, s2);
    let s = e.add(s1, s2);
    let t = e.mul(xr, s);
    let t = e.sub(t, lo);
    let t = e.sub(t, xr);
    let res = e.sub(hi, t);
    // |x| ≥ 2^66 (and inf): ±π/2.
    let huge = ltk(e, ax, 7.378697629483820646e19);
    let huge = e.not(huge);
    let res = select_k(e, huge, ATAN_HI[3] + ATAN_LO[3], res);
    let res = copysign(e, res, x);
    let nan = is_nan(e, x);
    e.select(nan, x, res)
}

// ---- sin, cos, tan ----

const INV_PIO2: f64 = 6.36619772367581382433e-01;
const PIO2_1: f64 = 1.57079632673412561417e+00; // first 33 bits of π/2
const PIO2_2: f64 = 6.07710050630396597660e-11; // next 33 bits
const PIO2_3: f64 = 2.02226624871116645580e-21; // next 33 bits
const PIO2_3T: f64 = 8.47842766036889956997e-32; // π/2 − (PIO2_1 + PIO2_2 + PIO2_3)
/// Above this |x| (2^19·π/2) the three-part reduction could lose bits: those lanes call the C library.
const TRIG_MAX: f64 = 823549.6653456035;
const SIN_S: [f64; 6] = [
    -1.66666666666666324348e-01,
    8.33333333332248946124e-03,
    -1.98412698298579493134e-04,
    2.75573137070700676789e-06,
    -2.50507602534068634195e-08,
    1.58969099521155010221e-10,
];
const COS_C: [f64; 6] = [
    4.16666666666666019037e-02,
    -1.38888888888741095749e-03,
    2.48015872894767294178e-05,
    -2.75573143513906633035e-07,
    2.08757232129817482790e-09,
    -1.13596475577881948265e-11,
];

/// Per quadrant k mod 4 of sin's reduced argument: (sign, 1 where the value is the cosine kernel's):
/// sin(y + kπ/2) is sin y, cos y, −sin y, −cos y.
const SIN_QUADRANT: [[f64; 2]; 4] = [[1.0, 0.0], [1.0, 1.0], [-1.0, 0.0], [-1.0, 1.0]];

/// x = k·π/2 + (y0 + y1), |y0 + y1| ≤ ~π/4; returns (k, y0, y1), k an integer, |k| < 2^20. Exact products: the
/// three parts of π/2 have 33 bits each.
fn trig_reduce<E: Emit>(e: &mut E, x: E::V, precise: bool) -> (E::V, E::V, E::V) {
    let kx = mulk(e, x, INV_PIO2);
    let k = round_int(e, kx);
    let w1 = mulk(e, k, PIO2_1);
    let t1 = e.sub(x, w1); // exact
    let w2 = mulk(e, k, PIO2_2);
    let (y0, y1) = if precise {
        let nw2 = e.neg(w2);
        let (r2, e2) = two_sum(e, t1, nw2);
        let w3 = mulk(e, k, PIO2_3);
        let nw3 = e.neg(w3);
        let (r3, e3) = two_sum(e, r2, nw3);
        let w4 = mulk(e, k, PIO2_3T);
        let tail = e.add(e2, e3);
        let tail = e.sub(tail, w4);
        fast_two_sum(e, r3, tail)
    } else {
        let r = e.sub(t1, w2);
        (r, e.konst(0.0))
    };
    (k, y0, y1)
}

/// sin(x + y) for |x| ≤ π/4, y a tail (fdlibm's __kernel_sin).
fn kernel_sin<E: Emit>(e: &mut E, x: E::V, y: E::V, precise: bool) -> E::V {
    let z = e.mul(x, x);
    let v = e.mul(z, x);
    if precise {
        let r = horner(e, z, &SIN_S[1..]);
        // x − ((z·(y/2 − v·r) − y) − v·S1)
        let hy = mulk(e, y, 0.5);
        let vr = e.mul(v, r);
        let a = e.sub(hy, vr);
        let a = e.mul(z, a);
        let a = e.sub(a, y);
        let vs = mulk(e, v, SIN_S[0]);
        let a = e.sub(a, vs);
        e.sub(x, a)
    } else {
        let p = horner(e, z, &SIN_S[..4]);
        let vp = e.mul(v, p);
        e.add(x, vp)
    }
}

/// cos(x + y) for |x| ≤ π/4 (fdlibm's __kernel_cos).
fn kernel_cos<E: Emit>(e: &mut E, x: E::V, y: E::V, precise: bool) -> E::V {
    let z = e.mul(x, x);
    let cs: &[f64] = if precise { &COS_C } else { &COS_C[..4] };
    let r = horner(e, z, cs);
    let r = e.mul(z, r);
    // w + (((1 − w) − z/2) + (z·r − x·y)), w = 1 − z/2
    let hz = mulk(e, z, 0.5);
    let w = ksub(e, 1.0, hz);
    let a = ksub(e, 1.0, w);
    let a = e.sub(a, hz);
    let zr = e.mul(z, r);
    let xy = e.mul(x, y);
    let b = e.sub(zr, xy);
    let a = e.add(a, b);
    e.add(w, a)
}

/// Whether the integer `j` (|j| < 2^52) is odd: j/2 is then not an integer (NaN: odd).
fn is_odd<E: Emit>(e: &mut E, j: E::V) -> E::M {
    let h = mulk(e, j, 0.5);
    let r = round_int(e, h);
    let same = e.eq(r, h);
    e.not(same)
}

/// Lanes whose |x| is beyond the reduction (or inf, NaN): computed by the C library instead.
fn trig_far<E: Emit>(e: &mut E, x: E::V) -> E::M {
    let ax = e.abs(x);
    let lim = e.konst(TRIG_MAX);
    let near = e.le(ax, lim);
    e.not(near)
}

/// sin (`phase` = 0) or cos (1): the quadrant k + phase selects ±sin or ±cos of the reduced argument.
fn sin_cos<E: Emit>(e: &mut E, x: E::V, phase: f64, mode: Mode, f: Builtin) -> E::V {
    let precise = mode == Mode::Precise;
    let (k, y0, y1) = trig_reduce(e, x, precise);
    let s = kernel_sin(e, y0, y1, precise);
    let c = kernel_cos(e, y0, y1, precise);
    // The quadrant (k + phase) mod 4 picks the kernel and the sign from a four-row table (exact: k is an
    // integer, and a product by ±1 is a sign).
    let j = addk(e, k, phase);
    let (sign, cosine) = e.lookup_pair(&SIN_QUADRANT, j);
    let zero = e.konst(0.0);
    let pick = e.lt(zero, cosine);
    let v = e.select(pick, c, s);
    let res = e.mul(v, sign);
    // sin(±0) = ±0.
    let res = if phase == 0.0 {
        let is_zero = e.eq(x, zero);
        e.select(is_zero, x, res)
    } else {
        res
    };
    let far = trig_far(e, x);
    e.fallback(far, x, res, f)
}

pub(crate) fn sin<E: Emit>(e: &mut E, x: E::V, mode: Mode) -> E::V {
    sin_cos(e, x, 0.0, mode, Builtin::Sin)
}

pub(crate) fn cos<E: Emit>(e: &mut E, x: E::V, mode: Mode) -> E::V {
    sin_cos(e, x, 1.0, mode, Builtin::Cos)
}

/// Above this |x| [`sin_near`] is [`sin`]: up to it the polynomial's tail stays below 0.14 of the result.
pub(crate) const SIN_NEAR_MAX: f64 = 1.75;
/// −1/6 as a double-double: sin's first correction term carried exactly.
const SIN_S1_HI: f64 = -0.16666666666666666;
const SIN_S1_LO: f64 = -9.25185853854297e-18;
/// (−1)^k/(2k+1)! for k = 2..=11: sin's Taylor series after −x³/6 (truncation < 2^-63 relative for
/// |x| ≤ [`SIN_NEAR_MAX`]).
const SIN_TAYLOR: [f64; 10] = [
    0.008333333333333333,
    -0.0001984126984126984,
    2.7557319223985893e-06,
    -2.505210838544172e-08,
    1.6059043836821613e-10,
    -7.647163731819816e-13,
    2.8114572543455206e-15,
    -8.22063524662433e-18,
    1.9572941063391263e-20,
    -3.868170170630684e-23,
];
/// Fast mode: k = 1..=5 (truncation < 2.4e-7 relative for |x| ≤ [`SIN_NEAR_MAX`]).
const SIN_TAYLOR_FAST: [f64; 5] = [-0.16666666666666666, 0.008333333333333333, -0.0001984126984126984, 2.7557319223985893e-06, -2.505210838544172e-08];

/// sin(x) for an argument the simplifier's range analysis bounds by [`SIN_NEAR_MAX`]: no reduction, one
/// kernel. Lanes beyond the bound (and NaN, ±inf) are [`sin`]'s, in a rare block, so the function is sin with
/// the same bound everywhere; what it saves is the reduction by π/2 and the second kernel [`sin_cos`] needs
/// when a vector's lanes fall in different quadrants (half of sin's operations).
///
/// Precise: x + (−x³/6 + x⁵·R(x²)) with x³ = p + c exactly (two error-free products), −x³/6 in double-double,
/// the rest rounded: the tail's few roundings are on a term below 0.14 of the result and the sum x + hi is
/// error-free, so the result is within 1 ulp of the truth (measured: 3.8 % of arguments in [0, 1.75] 1 ulp off,
/// sin's own 2.0 %; the math library's tests hold it to sin's bound).
pub(crate) fn sin_near<E: Emit>(e: &mut E, x: E::V, mode: Mode) -> E::V {
    let ax = e.abs(x);
    let lim = e.konst(SIN_NEAR_MAX);
    let near = e.le(ax, lim);
    let far = e.not(near);
    let z = e.mul(x, x);
    let p = e.mul(x, z);
    let r = if mode == Mode::Precise {
        let nz = e.neg(z);
        let ez = e.fma(x, x, nz);
        let np = e.neg(p);
        let ep = e.fma(x, z, np);
        let c = e.fma(x, ez, ep);
        let s1 = e.konst(SIN_S1_HI);
        let bh = e.mul(p, s1);
        let nbh = e.neg(bh);
        let eb = e.fma(p, s1, nbh);
        let s1l = e.konst(SIN_S1_LO);
        let lo = e.fma(p, s1l, eb);
        let lo = e.fma(c, s1, lo);
        let rz = horner(e, z, &SIN_TAYLOR);
        let zr = e.mul(z, rz);
        let tail = e.fma(p, zr, lo);
        let (sh, sl) = fast_two_sum(e, x, bh);
        let t = e.add(sl, tail);
        e.add(sh, t)
    } else {
        let q = horner(e, z, &SIN_TAYLOR_FAST);
        e.fma(p, q, x)
    };
    // sin(±0) = ±0 (x + (−0·z·…) would turn −0 into +0).
    let zero = e.konst(0.0);
    let is_zero = e.eq(x, zero);
    let r = e.select(is_zero, x, r);
    e.rare_call(far, r, Builtin::SinNear, &[x], &mut |e| {
        let s = sin(e, x, mode);
        e.select(far, s, r)
    })
}

/// tan = sin/cos of the reduced argument (−cos/sin in odd quadrants). Fast mode keeps the precise reduction:
/// near a pole tan ≈ −1/y, so the reduced argument's absolute error becomes relative error in the result.
pub(crate) fn tan<E: Emit>(e: &mut E, x: E::V, mode: Mode) -> E::V {
    let precise = mode == Mode::Precise;
    let (k, y0, y1) = trig_reduce(e, x, true);
    let s = kernel_sin(e, y0, y1, precise);
    let c = kernel_cos(e, y0, y1, precise);
    let odd = is_odd(e, k);
    let even = e.not(odd);
    let t_even = e.div(s, c);
    let nc = e.neg(c);
    let t_odd = e.div(nc, s);
    let res = e.select(even, t_even, t_odd);
    // tan(±0) = ±0.
    let zero = e.konst(0.0);
    let is_zero = e.eq(x, zero);
    let res = e.select(is_zero, x, res);
    let far = trig_far(e, x);
    e.fallback(far, x, res, Builtin::Tan)
}

/// The exact builtins of [`Lowering::Logic`](super::Lowering::Logic): comparisons as 0/1 values, the select,
/// floor. Written in the same primitives as the rest of the library, so every backend runs one definition.
pub(crate) mod logic {
    use super::*;

    /// A comparison's flag as a number: 1 where `m` holds, else 0.
    pub(crate) fn flag<E: Emit>(e: &mut E, m: impl FnOnce(&mut E) -> E::M) -> E::V {
        let m = m(e);
        let one = e.konst(1.0);
        let zero = e.konst(0.0);
        e.select(m, one, zero)
    }

    /// `c != 0 ? a : b` (a NaN condition counts as true, as in C). Both values are computed; only the chosen
    /// one reaches the result, so an infinite or NaN untaken branch cannot poison it as a 0/1 blend would.
    pub(crate) fn select<E: Emit>(e: &mut E, c: E::V, a: E::V, b: E::V) -> E::V {
        let zero = e.konst(0.0);
        let off = e.eq(c, zero);
        e.select(off, b, a)
    }

    /// The largest integer ≤ x, exactly (−0 stays −0; NaN and ±inf pass through), without a rounding
    /// instruction: below 2^52, adding and subtracting 2^52 to |x| rounds it to the nearest integer, which is
    /// then stepped down (x ≥ 0) or up (x < 0, as a magnitude) when it overshot.
    pub(crate) fn floor<E: Emit>(e: &mut E, x: E::V) -> E::V {
        let a = e.abs(x);
        let big = e.konst(TWO52);
        let t0 = e.add(a, big);
        let t = e.sub(t0, big);
        let one = e.konst(1.0);
        let down = e.sub(t, one);
        let up = e.add(t, one);
        let over = e.lt(a, t);
        let under = e.lt(t, a);
        let pos = e.select(over, down, t);
        let mag = e.select(under, up, t);
        let neg = e.neg(mag);
        let negative = sign_bit(e, x);
        let r = e.select(negative, neg, pos);
        let small = e.lt(a, big);
        e.select(small, r, x)
    }
}

// ---- expmuldiv (the accuracy pass's scaled exponential; added after the library above, which it reuses) ----

/// `exp(a)·b/c` rounded as if the product had an unbounded exponent, then once to f64 (≤ 2 ulp; both modes).
///
/// Why: in `exp(a)·b/c` written out, e^a underflows (a < −708) or overflows before b/c rescales it, so a
/// Beckmann or Ward value near 1e-311 comes out as a denormal with few bits, or 0. The common case costs what
/// the product as written does plus a range test on b/c: e^a = y·2^q ([`exp_parts`] with a clamped to ±1416,
/// y in [0.97, 1.96]), s = y·(b/c) (two roundings), and [`scale2`] applies 2^q last (|q| ≤ 2043; exact unless
/// the result is subnormal, whose only rounding it then is). Where |b/c| lies in [2^-960, 2^967] that is the
/// answer for every a, the clamped ones included: a < −1416 gives 0, as the truth rounds, and a > 1416 ∞
/// (Beckmann's small-NH lanes, where e^a alone is 0, stay on this path). Other lanes (b or c tiny, huge, 0, ∞ or
/// NaN) take [`Emit::rare_call`]'s branch to [`exp_mul_div_scaled`], which the JIT calls out of line, so its
/// constants stay out of the common path. Cost: exp + a division, a multiplication and ~6 operations
/// (~1.15× the kernels that use it, measured 2026-12-01).
///
/// Special values follow `exp(a)*b/c`, except that a zero exponential (a < −745.2) times an infinite b/c, or
/// times 0/0 or ∞/∞, is 0: an infinite b/c stands for an overflowed finite factor, 0/0 and ∞/∞ for factors that
/// vanish or grow polynomially where e^a vanishes faster than any power (Cook–Torrance at NH = 0), and the
/// accuracy pass forms this builtin only from products whose exp factor is what vanishes there. A NaN a, b or c
/// gives NaN.
///
/// Fast mode takes e^a = y·2^q from fast exp's reduction and polynomial ([`exp_fast_parts`]: no table, no
/// double-double; ≤ 1e-8 relative) and keeps the rest, rare branch included: the same range in both modes.
pub(crate) fn exp_mul_div<E: Emit>(e: &mut E, a: E::V, b: E::V, c: E::V, mode: Mode) -> E::V {
    let (y, q) = if mode == Mode::Fast {
        exp_fast_parts(e, a, -1416.0, 1416.0)
    } else {
        let zero = e.konst(0.0);
        exp_parts(e, a, zero, -1416.0, 1416.0)
    };
    let bc = e.div(b, c);
    let s = e.mul(y, bc);
    let r = scale2(e, s, q);
    // One compare: |b/c|·2^960 ≥ 1 and |b/c|·2^-967 ≤ 1, as min(…, 2 − …) ≥ 1; the select is a min
    // instruction that returns its second operand on NaN, so a NaN b/c reaches the compare.
    let abc = e.abs(bc);
    let lo = mulk(e, abc, 2f64.powi(960));
    let hi = mulk(e, abc, 2f64.powi(-967));
    let u = ksub(e, 2.0, hi);
    let lt = e.lt(lo, u);
    let z = e.select(lt, lo, u);
    let one = e.konst(1.0);
    let ok = e.le(one, z);
    let bad = e.not(ok);
    e.rare_call(bad, r, Builtin::ExpMulDiv, &[a, b, c], &mut |e| {
        let t = exp_mul_div_scaled(e, a, b, c);
        e.select(bad, t, r)
    })
}

/// [`exp_mul_div`] with every power of two applied last: a = m·512·ln 2 + r (|m| ≤ 8, r exact as a
/// double-double), e^r by [`exp_dd`] (normal, < 0.51 ulp); b and c split into mantissa and exponent (denormals
/// scaled by 2^64 first); the mantissas and e^r multiply and divide (two roundings), and [`scale2`] applies
/// the summed exponent at the end — the only rounding a denormal or overflowing result sees.
fn exp_mul_div_scaled<E: Emit>(e: &mut E, a: E::V, b: E::V, c: E::V) -> E::V {
    // a = m·C + r, C = 512·ln 2 = C_HI + C_LO; m·C_HI exact (C_HI has 32 bits), a − m·C_HI exact (Sterbenz).
    const C_HI: f64 = 512.0 * LN2_HI;
    const C_LO: f64 = 512.0 * LN2_LO;
    let ac = clamp_to(e, a, -2900.0, 2900.0);
    let ma = mulk(e, ac, 1.0 / (512.0 * std::f64::consts::LN_2));
    let m = round_int(e, ma);
    let mc = mulk(e, m, C_HI);
    let rh = e.sub(ac, mc);
    let rl = mulk(e, m, -C_LO);
    let er = exp_dd(e, rh, rl);
    // Mantissa in ±[1, 2) and unbiased exponent of a finite nonzero x (denormals scaled by 2^64 first).
    let split = |e: &mut E, x: E::V| {
        let ax = e.abs(x);
        let tiny = e.konst(f64::MIN_POSITIVE);
        let sub = e.lt(ax, tiny);
        let up = mulk(e, x, 18446744073709551616.0);
        let xs = e.select(sub, up, x);
        let f = e.exponent_field(xs);
        let bias = e.konst(1023.0);
        let bias64 = e.konst(1023.0 + 64.0);
        let bias = e.select(sub, bias64, bias);
        let k = e.sub(f, bias);
        (e.mask_bits(xs, SIGN | MANTISSA, EXP_ONE), k)
    };
    let (mb, kb) = split(e, b);
    let (mcm, kc) = split(e, c);
    let q = e.div(mb, mcm);
    let p = e.mul(er, q);
    let (mp, kp) = split(e, p);
    let m512 = mulk(e, m, 512.0);
    let k = e.sub(kb, kc);
    let k = e.add(k, kp);
    let k = e.add(k, m512);
    let k = clamp_to(e, k, -1100.0, 1100.0);
    let r = scale2(e, mp, k);
    // b or c zero, infinite or NaN: exp(a)·(b/c), with 0·∞ = 0 where e^a is 0 (see above).
    let ab = e.abs(b);
    let acv = e.abs(c);
    let max = e.konst(f64::MAX);
    let fb = e.le(ab, max);
    let fc = e.le(acv, max);
    let zero = e.konst(0.0);
    let zb = e.eq(b, zero);
    let zc = e.eq(c, zero);
    let fin = e.and(fb, fc);
    let nz = e.or(zb, zc);
    let nz = e.not(nz);
    let normal = e.and(fin, nz);
    let nan = is_nan(e, a);
    let num = e.not(nan);
    let normal = e.and(normal, num);
    let bc = e.div(b, c);
    let big = ltk(e, ac, 709.8);
    let big = e.not(big);
    let f = select_k(e, big, f64::INFINITY, er);
    let low = ltk(e, a, -745.2);
    let f = e.zero_where(low, f);
    let f = e.select(nan, a, f);
    let s = e.mul(bc, f);
    // A zero exponential wins over any b/c not made of a NaN: an infinite one (see above), and 0/0 or ∞/∞,
    // which stand for factors vanishing (or growing) polynomially where e^a vanishes faster than any power
    // (Cook–Torrance at NH = 0, where m²·NH² = 0 makes a = −∞ and G·F/(NL·NV) is 0/0: the limit is 0).
    let b_ok = e.eq(b, b);
    let c_ok = e.eq(c, c);
    let bc_ok = e.and(b_ok, c_ok);
    let z = e.and(low, bc_ok);
    let s = e.zero_where(z, s);
    e.select(normal, r, s)
}

// ---- acoslo (the accuracy pass's tail of acos; added after the library above, which it reuses) ----

/// `acos(x) − acos_f64(x)`: the rounding error of the precise [`acos`] at x (the same clamp, reduction and
/// branches), so `acos(x) + acoslo(x)` is acos to within ~1/16 ulp instead of ≤ 1 (tests/it/cancel.rs). Fast
/// mode: 0 (its acos is 2e-8 off; the pass carries no tail there). In exact arithmetic (the truth) it is 0.
///
/// Why: exp(−n·acos(x)²/2) multiplies acos's relative error by 2·|exponent| (~40 for the Gaussian at n = 30);
/// the accuracy pass carries this tail into the exponent (`compensated-exp`).
///
/// Each branch recovers the error of its last, largest roundings from exact differences (Sterbenz) of the
/// rounded result and the pieces acos adds: |x| < ½: (π/2ʰ − r) − x is x·R − π/2ˡ up to those roundings, so
/// subtracting the rounded x·R and adding π/2ˡ leaves them; x > ½ (for |x|): r/2 = df + (s·R + c), so
/// ((df − r/2) + s·R) + c; x < −½: π − r and the |x| > ½ result share their pieces, so the tail is their exact
/// difference plus π's low part minus that result's tail. Left out, each ≤ ~1/50 ulp of the result: the
/// roundings of x·R and s·R (small next to the result) and √z's own (times R). The intermediates are acos's
/// own ([`acos_parts`]), so inside one kernel the JIT computes them once. Cost: ~12 additions, 2 selects
/// and a compare beside acos.
pub(crate) fn acos_lo<E: Emit>(e: &mut E, x: E::V, mode: Mode) -> E::V {
    if mode == Mode::Fast {
        return e.konst(0.0);
    }
    let x = clamp_to(e, x, -1.0, 1.0);
    let p = acos_parts(e, x);
    // |x| < ½: π/2ʰ − res_small = x − (π/2ˡ − x·r) up to the roundings (exact: Sterbenz).
    let d = ksub(e, PIO2_HI, p.res_small);
    let g = e.sub(d, x);
    let g = e.sub(g, p.xr);
    let lo_small = addk(e, g, PIO2_LO);
    // |x| > ½ (for |x|): df − t = −(r·s + c) up to t's rounding.
    let g = e.sub(p.df, p.t);
    let g = e.add(g, p.rs);
    let g = e.add(g, p.c);
    let lo_pos = e.add(g, g);
    // |x| = 1: z = 0 and the split divides 0 by 0; acos(1) = +0 exactly.
    let ax = e.abs(x);
    let at1 = eqk(e, ax, 1.0);
    let res_pos = e.zero_where(at1, p.res_pos);
    let lo_pos = e.zero_where(at1, lo_pos);
    // x < −½: π − res_neg = res_pos up to rounding; π = PI + 2·π/2ˡ.
    let d = ksub(e, PI, p.res_neg);
    let g = e.sub(d, res_pos);
    let g = addk(e, g, 2.0 * PIO2_LO);
    let lo_neg = e.sub(g, lo_pos);
    let big = e.select(p.neg, lo_neg, lo_pos);
    e.select(p.small, lo_small, big)
}

// ---- powlo (the accuracy pass's tail of pow; added after the library above, which it reuses) ----

/// Smallest |pow| whose tail [`pow_lo`] returns: ~2^53 above the smallest normal, so the tail is normal too.
const POW_LO_MIN: f64 = 2.0041683600089728e-292; // 2^-969

/// `pow(x, y) − pow_f64(x, y)`: the rounding error of the precise [`pow`] at (x, y), so `pow + powlo` is pow to
/// within ~1/100 ulp instead of ≤ 0.55 (tests/it/cancel.rs). pow computes y·ln x in double-double (2⁻⁶⁸) and
/// rounds once, in exp's final FMA; [`exp_parts_tail`] recovers that rounding. 0 where pow is a special case
/// (x ≤ 0, ∞ or NaN, |y| ≥ 2⁶⁴, pow(1, y), pow(x, 0)) or its value is not normal enough for a normal tail, and
/// in fast mode (its pow is 1e-8 off; the pass carries no tail there). In exact arithmetic (the truth) it is 0.
///
/// Why: acos(Q^(1/k)) with Q^(1/k) near 1 (F_kutlog) multiplies pow's relative error by up to ~20; a parameter-
/// only subtree computed in double-double (`compensated-params`) needs pow's tail to be worth doing. The same
/// instructions as pow up to exp's scaling, plus two; no special-case block.
pub(crate) fn pow_lo<E: Emit>(e: &mut E, x: E::V, y: E::V, mode: Mode) -> E::V {
    if mode == Mode::Fast {
        return e.konst(0.0);
    }
    let (ph, pl) = pow_exponent(e, x, y);
    let ExpParts { y: m, q, t_hi, tmp, rh, rl, r, r2, p, em1, t_tail } = exp_parts_tail(e, ph, pl, -760.0, 720.0);
    // m = T_HI + T_HI·tmp rounded once; T_HI − m is exact (Sterbenz: m in [0.97, 1.96], T_HI in [1, 2)), so
    // this is that rounding.
    let d = e.sub(t_hi, m);
    let m_lo = e.fma(t_hi, tmp, d);
    // And the roundings below tmp, each up to 2^-59 of m (|r| ≤ ln2/32): r = rh + rl, em1 = r + r²·p (r − em1
    // is exact, em1 being within 1.2 % of r), tmp = t_tail + em1, and the product t_tail·em1 exp leaves out.
    // What remains is ~1/100 ulp of m (the polynomial's truncation and the roundings of r², p and these terms).
    let e_r = two_sum_err(e, rh, rl, r);
    let rd = e.sub(r, em1);
    let e_em1 = e.fma(r2, p, rd);
    let e_tmp = two_sum_err(e, t_tail, em1, tmp);
    let cross = e.mul(t_tail, em1);
    let s = e.add(e_r, e_em1);
    let s = e.add(s, e_tmp);
    let s = e.add(s, cross);
    let m_lo = e.fma(t_hi, s, m_lo);
    let mag = scale2(e, m, q);
    let lo = scale2(e, m_lo, q);
    // Only for positive finite x, |y| < 2^64 and a value in [2^-969, ∞): elsewhere pow's value is exact, a
    // special case, or rounded again in the subnormals.
    let zero = e.konst(0.0);
    let pos = e.lt(zero, x);
    let fin = ltk(e, x, f64::INFINITY);
    let ay = e.abs(y);
    let small = ltk(e, ay, Y_CAP);
    let big = ltk(e, mag, POW_LO_MIN);
    let not_big = e.not(big);
    let ok = e.and(pos, fin);
    let ok = e.and(ok, small);
    let ok = e.and(ok, not_big);
    let ok_fin = ltk(e, mag, f64::INFINITY);
    let ok = e.and(ok, ok_fin);
    let bad = e.not(ok);
    e.zero_where(bad, lo)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::base::rng::Rng;

    /// y·2^k correctly rounded, from the integers: the significand shifted into units of the result's ulp
    /// (2^-1074 below 2^-1022), rounded to nearest with ties to even by hand.
    fn reference(y: f64, k: i64) -> f64 {
        if y == 0.0 || !y.is_finite() {
            return y; // ±0, ±∞ and NaN scale to themselves
        }
        let bits = y.to_bits();
        let (f, frac) = (((bits >> 52) & 0x7ff) as i64, bits & MANTISSA);
        // |y| = sig·2^(e − 1075) with sig an integer.
        let (sig, e) = if f == 0 { (frac, 1) } else { (frac | 1 << 52, f) };
        let e = e + k; // |y·2^k| = sig·2^(e − 1075): in units of 2^-1074, sig·2^(e − 1)
        let mag = if e >= 1 {
            // Exact (sig < 2^53) unless it overflows, which the last product rounds to ∞ as IEEE does.
            let p = e - 1023;
            sig as f64 / 2f64.powi(52) * 2f64.powi((p / 2) as i32) * 2f64.powi((p - p / 2) as i32)
        } else {
            // Units of 2^-1074: sig·2^(e − 1), shifted right by 1 − e bits with round-to-nearest-even.
            let shift = (1 - e) as u32;
            let q = if shift >= 64 { 0 } else { sig >> shift };
            let rem = if shift >= 64 { sig as u128 } else { (sig & ((1u64 << shift) - 1)) as u128 };
            let half = if shift >= 64 { u128::MAX } else { 1u128 << (shift - 1) };
            let q = if rem > half || (rem == half && q & 1 == 1) { q + 1 } else { q };
            f64::from_bits(q) // q ≤ 2^52: a subnormal, or 2^-1022 when it rounded up to 2^52
        };
        if y < 0.0 { -mag } else { mag }
    }

    #[test]
    fn scale2_rounds_once_like_ieee_including_subnormal_results() {
        let mut rng = Rng(0x5ca1e2);
        let mut cases: Vec<(f64, i64)> = Vec::new();
        // Random significands at exponents that put the result anywhere from overflow to far below 2^-1074.
        for i in 0..300_000 {
            let sig = 1.0 + rng.unit();
            // A third in each of scale2's ranges, a third anywhere (scale2_exact only).
            let (ey, k) = match i % 3 {
                0 => (rng.below(801) as i32 - 400, rng.below(2201) as i64 - 1100),
                1 => (rng.below(1931) as i32 - 961, rng.below(4087) as i64 - 2043),
                _ => (rng.below(2000) as i32 - 1000, rng.below(2201) as i64 - 1100),
            };
            let y = if rng.below(2) == 0 { sig } else { -sig } * 2f64.powi(ey);
            cases.push((y, k));
        }
        // Ties and near-ties at every subnormal exponent, the rounding up to 2^-1022, zeros and specials.
        for shift in 1..60i64 {
            for sig in [1u64 << 52, (1 << 52) | 1, (1 << 52) | (1 << 51), (3 << 51) | 1, (1 << 53) - 1] {
                let y = f64::from_bits((1023 << 52) | (sig & MANTISSA));
                cases.push((y, -1022 - shift));
                cases.push((-y, -1022 - shift + 1));
            }
        }
        // Double-rounding traps: y·2^k just below a tie between two subnormals, the lower one odd, so a first
        // rounding into the subnormals would make it a tie and round up.
        for k in (-2043..=-40i64).step_by(3) {
            for n in [(1u64 << 20) + 1, (1 << 40) + 3, 12345] {
                let v = (n as f64 + 0.5).next_down();
                let e = (-1074 - k) as i32;
                let y = v * 2f64.powi(e / 2) * 2f64.powi(e - e / 2);
                cases.push((y, k));
                cases.push((-y, k));
            }
        }
        cases.extend([(0.0, -1100), (-0.0, 5), (f64::INFINITY, -1100), (f64::NAN, 3), (f64::MIN_POSITIVE / 8.0, 3), (1.5, 1023), (1.0, 1024), (0.99, 1024)]);
        let mut tiny = 0;
        for (y, k) in cases {
            let want = reference(y, k);
            let check = |name: &str, got: f64| {
                assert!(got.to_bits() == want.to_bits() || (got.is_nan() && want.is_nan()), "{name}: {y:e}·2^{k}: {got:e} ({:#x}), want {want:e} ({:#x})", got.to_bits(), want.to_bits());
            };
            check("scale2_exact", scale2_exact(&mut Direct, y, k as f64));
            // The two-scalings coding, in scale2's ranges.
            let a = y.abs();
            let near = (2f64.powi(-400)..=2f64.powi(400)).contains(&a) && k.abs() <= 1100;
            let wide = (2f64.powi(-961)..2f64.powi(970)).contains(&a) && k.abs() <= 2043;
            if y == 0.0 || !y.is_finite() || near || wide {
                check("scale2_normal", scale2_normal(&mut Direct, y, k as f64));
            }
            tiny += usize::from(want != 0.0 && want.abs() < f64::MIN_POSITIVE);
        }
        assert!(tiny > 1000, "subnormal results tested: {tiny}");
    }
}
