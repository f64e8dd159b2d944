//! The ground truth: any [`Formula`] evaluated in ~104-bit precision with an unbounded exponent, and again at up
//! to 4 800 bits where its own error bound says 104 are not enough.
//!
//! # Design
//! A value is an [`Xf`]: a double-double mantissa (`hi + lo`, `1 ≤ |hi| < 2`, |lo| ≤ ulp(hi)/2) times `2^e`
//! with a 64-bit exponent. Double-double gives ~104 bits (Dekker/Knuth two-sum and an FMA two-product); the
//! separate exponent means intermediates never overflow or underflow, which is the point: Beckmann at
//! NH = 10⁻¹⁰⁰ has NH⁴ = 10⁻⁴⁰⁰ and 1/NH⁴ = 10⁴⁰⁰, finite here, so the true value (0 after rounding) is found where
//! f64 computes ∞·0 = NaN. Chosen over an arbitrary-precision crate for cost: no allocation per operation, ~10⁶
//! evaluations per second of a catalogue formula in a release build, which is what measuring 10⁵ points per
//! formula and per rewrite candidate needs.
//!
//! 104 bits are not always enough: 1 − (1 − 2⁻¹⁰⁷⁵)⁵ is 0 in double-double (its tail cannot go below 2⁻¹⁰⁷⁴),
//! tan(acos(2.75·10⁻³⁰⁹)) is tan of π/2 rounded to 104 bits. So beside every node's value goes a bound on its
//! error (`bound`: first-order, the operations' own errors from error-free transformations of their steps, so
//! that short operands stay exact), and where the bound does not settle the root's f64 rounding (Ziv's test) the
//! formula is evaluated again with correctly rounded arithmetic at as many bits as the bound asks (`big`,
//! `dashu-float`), the double-double's good transcendentals reused in the first step; more while the bound is
//! not met, up to 4 800 bits ([`eval_settled`], [`eval_parts`]; the accuracy measurement's [`eval`] and
//! `Linear` keep the double-double alone, for cost). Angles from acos, asin and atan are held as q·π/2 + r where
//! trigonometric functions read them (`angle`), so that tan(acos(z)) for a tiny z is right in the double-double.
//!
//! The semantics are lobe's IR semantics (`ir.rs`, `builtins.rs`) with nothing rounded: IEEE special values
//! (0/0, ∞−∞, 0·∞ are NaN; x/0 is ±∞), `min`/`max`/`clamp` propagate NaN and order −0 below +0, `acos`/`asin`
//! clamp their argument to [−1, 1], `pow` follows C99 F.9.4.4 for its special cases. The builtins are computed
//! here from first principles, not through [`crate::builtins`]' functions, so the truth does not depend on how
//! lobe's math library is implemented:
//! - exp: x = k·ln2 + r, r/2¹⁰ by Taylor, then ten squarings (of `expm1`, to keep the low bits);
//! - ln: one Newton step on exp from libm's 53-bit guess (doubling it to ~104 bits), plus e·ln2;
//! - sin/cos/tan: reduction by π/2 in triple precision (|x| < 2⁴⁰), Payne–Hanek beyond (`reduce`), Taylor on
//!   [−π/4, π/4];
//! - atan: one Newton step from libm's guess; asin(x) = atan(x/√((1−x)(1+x))), acos(x) = 2·atan(√((1−x)/(1+x)));
//! - pow: binary powering for integer exponents up to 2¹⁶, exp(y·ln|x|) otherwise.
//!
//! Limits (documented, not hidden): `exp` of arguments beyond ±2⁶² saturates to ∞ / the smallest positive value
//! (2^(−2⁶⁰): outside any f64 by 10¹⁵ binades, but positive, so a pole times it stays a pole; the double-double
//! saturates from 2⁵², and its bound sends the arguments in between to the big evaluator); a value the bound does
//! not settle at 4 800 bits keeps the best evaluation's; the bound is first-order (a second-order term can exceed
//! it where a condition number changes within the error); rounding to a subnormal f64 rounds twice (≤ 1 ulp of
//! the subnormal).
//!
//! Cost: ~30–80 ns per node with its bound in a release build (exp/ln/trig ~0.3–1 µs): a catalogue formula is
//! 1–5 µs per point; an evaluation at hundreds of bits is 0.1–1 ms, at the points that need one.

// The double-double constants are written with every digit of their published values (QD library).
#![allow(clippy::excessive_precision)]

use crate::builtins::dd;
use crate::builtins::math::Direct;
use crate::builtins::Builtin;
use crate::ir::{BinOp, Formula, Node, NodeId, N_INPUTS};
use std::cmp::Ordering;
use std::ops::{Add, Div, Mul, Neg, Sub};

mod angle;
mod big;
mod bound;
mod linear;
mod reduce;
use bound::Target;
pub(crate) use linear::{Estimate, Linear, Scratch};

type Dd = dd::Dd<f64>;

/// π in three parts (QD library constants).
const PI3: [f64; 3] = [std::f64::consts::PI, 1.224646799147353207e-16, -2.994769809718339666e-33];
/// ln 2 as a double-double.
const LN2: Dd = (std::f64::consts::LN_2, 2.319046813846299558e-17);

/// x·2^k for any k, in steps that neither overflow nor underflow the scale factor.
#[inline]
fn ldexp(mut x: f64, mut k: i64) -> f64 {
    while k > 1000 {
        x *= pow2(1000);
        k -= 1000;
        if x.is_infinite() {
            return x;
        }
    }
    while k < -1000 {
        x *= pow2(-1000);
        k += 1000;
        if x == 0.0 {
            return x;
        }
    }
    x * pow2(k)
}
/// 2^k for |k| ≤ 1022: the math library's exact power of two (`powi` was a tenth of the truth's time).
#[inline]
fn pow2(k: i64) -> f64 {
    crate::builtins::math::pow2i(k as f64)
}
/// 1/i! for i = 0 … 33 in double-double (the Taylor terms of exp, sin and cos multiply by these instead of
/// dividing by i: a double-double division was half of the truth's time on trigonometric formulas).
fn inverse_factorials() -> &'static [Dd; 34] {
    static T: std::sync::OnceLock<[Dd; 34]> = std::sync::OnceLock::new();
    T.get_or_init(|| {
        let mut t = [(1.0, 0.0); 34];
        for i in 1..34 {
            t[i] = dd::div(&mut Direct, t[i - 1], (i as f64, 0.0));
        }
        t
    })
}
/// Exponent of a finite non-zero f64: |x| ∈ [2^k, 2^(k+1)).
fn exponent(x: f64) -> i64 {
    let b = (x.to_bits() >> 52) & 0x7ff;
    if b == 0 {
        // Subnormal: scale up exactly first.
        exponent(x * pow2(64)) - 64
    } else {
        b as i64 - 1023
    }
}

/// A real number as a double-double mantissa with a 64-bit binary exponent; see the module docs.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Xf {
    hi: f64,
    lo: f64,
    e: i64,
}

impl Xf {
    pub(crate) const ZERO: Xf = Xf { hi: 0.0, lo: 0.0, e: 0 };
    pub const ONE: Xf = Xf { hi: 1.0, lo: 0.0, e: 0 };
    pub(crate) const NAN: Xf = Xf { hi: f64::NAN, lo: 0.0, e: 0 };

    /// `(hi + lo)·2^e`, normalised.
    #[inline]
    fn make(d: Dd, e: i64) -> Xf {
        if d.1 == 0.0 && (d.0 == 0.0 || !d.0.is_finite()) {
            return Xf::special(d.0);
        }
        let (hi, lo) = dd::fast_two_sum(&mut Direct, d.0, d.1);
        if hi == 0.0 || !hi.is_finite() {
            return Xf { hi, lo: 0.0, e: 0 };
        }
        let bits = hi.to_bits();
        let field = ((bits >> 52) & 0x7ff) as i64;
        if field != 0 {
            // A normal head: its exponent field set to 0 is the exact hi·2^-k; lo·2^-k is one exact product
            // (what the general path computes, without its loops).
            let k = field - 1023;
            let hi = f64::from_bits((bits & !(0x7ffu64 << 52)) | (1023u64 << 52));
            let lo = if k.abs() <= 1000 { lo * f64::from_bits(((1023 - k) as u64) << 52) } else { ldexp(lo, -k) };
            return Xf { hi, lo, e: e.saturating_add(k) };
        }
        let k = exponent(hi);
        Xf { hi: ldexp(hi, -k), lo: ldexp(lo, -k), e: e.saturating_add(k) }
    }
    /// A special value (±0, ±∞, NaN), exactly as the f64.
    fn special(v: f64) -> Xf {
        Xf { hi: v, lo: 0.0, e: 0 }
    }
    /// (hi, lo, e): the value is (hi + lo)·2^e; a special value (±0, ±∞, NaN) is hi with e = 0.
    pub fn parts(self) -> (f64, f64, i64) {
        (self.hi, self.lo, self.e)
    }
    pub fn from_f64(v: f64) -> Xf {
        Xf::make((v, 0.0), 0)
    }
    fn is_special(self) -> bool {
        self.hi == 0.0 || !self.hi.is_finite()
    }
    pub(crate) fn is_nan(self) -> bool {
        self.hi.is_nan()
    }
    pub(crate) fn is_zero(self) -> bool {
        self.hi == 0.0
    }
    fn sign_negative(self) -> bool {
        self.hi.is_sign_negative()
    }
    /// Rounded to the nearest f64 (twice-rounded when the result is subnormal; module docs).
    pub fn to_f64(self) -> f64 {
        if self.is_special() {
            return self.hi;
        }
        ldexp(self.hi + self.lo, self.e)
    }
    /// The mantissa scaled into a plain double-double; only for |value| < 2^1000.
    fn to_dd(self) -> Dd {
        if self.is_special() {
            return (self.hi, 0.0);
        }
        (ldexp(self.hi, self.e), ldexp(self.lo, self.e))
    }
    fn from_dd(d: Dd) -> Xf {
        Xf::make(d, 0)
    }

    #[inline]
    fn xneg(self) -> Xf {
        Xf { hi: -self.hi, lo: -self.lo, e: self.e }
    }
    pub(crate) fn abs(self) -> Xf {
        if self.sign_negative() {
            self.neg()
        } else {
            self
        }
    }

    #[inline]
    fn xadd(self, b: Xf) -> Xf {
        let a = self;
        if a.is_special() || b.is_special() {
            if a.is_zero() && !b.is_special() {
                return b;
            }
            if b.is_zero() && !a.is_special() {
                return a;
            }
            // Both special, or one infinite/NaN: the f64 rule decides (a finite operand's size is irrelevant).
            return Xf::special(a.hi + b.hi);
        }
        // Aligned to the larger exponent, a much smaller operand becomes the low part (any f64 below half an ulp
        // of the high part is one): 1 + 10⁻⁴³ is held exactly, so (c − 1) + 1 at c = 10⁻⁴³ is c, not 0. Only below
        // the smallest subnormal of the scale does it vanish.
        let d = a.e.saturating_sub(b.e);
        if d > 1100 {
            return a;
        }
        if d < -1100 {
            return b;
        }
        if d >= 0 {
            Xf::make(dd::add(&mut Direct, (a.hi, a.lo), (ldexp(b.hi, -d), ldexp(b.lo, -d))), a.e)
        } else {
            Xf::make(dd::add(&mut Direct, (ldexp(a.hi, d), ldexp(a.lo, d)), (b.hi, b.lo)), b.e)
        }
    }
    #[inline]
    fn xsub(self, b: Xf) -> Xf {
        self.add(b.neg())
    }
    #[inline]
    fn xmul(self, b: Xf) -> Xf {
        if self.is_special() || b.is_special() {
            // A finite non-zero operand acts as ±1: the result is ±0, ±∞ or NaN, as in f64.
            return Xf::special(self.hi.signum_or_special() * b.hi.signum_or_special());
        }
        Xf::make(dd::mul(&mut Direct, (self.hi, self.lo), (b.hi, b.lo)), self.e.saturating_add(b.e))
    }
    #[inline]
    fn xdiv(self, b: Xf) -> Xf {
        if self.is_special() || b.is_special() {
            return Xf::special(self.hi.signum_or_special() / b.hi.signum_or_special());
        }
        Xf::make(dd::div(&mut Direct, (self.hi, self.lo), (b.hi, b.lo)), self.e.saturating_sub(b.e))
    }
    pub(crate) fn sqrt(self) -> Xf {
        if self.is_special() || self.hi < 0.0 {
            return Xf::special(self.hi.sqrt());
        }
        let (m, e) = if self.e % 2 != 0 { ((2.0 * self.hi, 2.0 * self.lo), self.e - 1) } else { ((self.hi, self.lo), self.e) };
        Xf::make(dd::sqrt(&mut Direct, m), e / 2)
    }

    /// Total order on non-NaN values, −0 = +0 (as IEEE comparison); `None` with a NaN.
    pub(crate) fn partial_cmp(self, b: Xf) -> Option<Ordering> {
        if self.is_nan() || b.is_nan() {
            return None;
        }
        let d = self.sub(b);
        if d.is_zero() {
            Some(Ordering::Equal)
        } else if d.sign_negative() {
            Some(Ordering::Less)
        } else {
            Some(Ordering::Greater)
        }
    }
    /// IEEE 754-2019 minimum (NaN-propagating, −0 < +0), as [`crate::builtins::fmin`].
    pub fn min(self, b: Xf) -> Xf {
        match self.partial_cmp(b) {
            None => Xf::NAN,
            Some(Ordering::Less) => self,
            Some(Ordering::Greater) => b,
            Some(Ordering::Equal) => {
                if self.sign_negative() {
                    self
                } else {
                    b
                }
            }
        }
    }
    /// IEEE 754-2019 maximum (NaN-propagating, +0 > −0).
    pub fn max(self, b: Xf) -> Xf {
        match self.partial_cmp(b) {
            None => Xf::NAN,
            Some(Ordering::Greater) => self,
            Some(Ordering::Less) => b,
            Some(Ordering::Equal) => {
                if self.sign_negative() {
                    b
                } else {
                    self
                }
            }
        }
    }

    pub fn exp(self) -> Xf {
        if self.is_special() {
            return if self.is_zero() { Xf::ONE } else { Xf::special(self.hi.exp()) };
        }
        if self.e >= 52 {
            // Beyond every exponent an Xf holds. Below, the exponential is still positive: the smallest positive
            // Xf stands for it, so ∞·e^(−10¹⁵⁴) is ∞ (Ward at NL = 0 beside a vanishing exp), while any finite
            // product of it rounds to +0. Above, +∞.
            return if self.sign_negative() { Xf { hi: 1.0, lo: 0.0, e: -(1i64 << 60) } } else { Xf::special(f64::INFINITY) };
        }
        let x = self.to_dd();
        let k = (x.0 / LN2.0).round();
        let r = dd::add(&mut Direct, x, dd::neg(&mut Direct, dd::mul(&mut Direct, (k, 0.0), LN2)));
        // expm1 of r/2^10 by Taylor, then (1 + y)² − 1 = y(2 + y) ten times.
        let s = (ldexp(r.0, -10), ldexp(r.1, -10));
        let mut power = s;
        let mut y = s;
        for inv in &inverse_factorials()[2..13] {
            power = dd::mul(&mut Direct, power, s);
            let term = dd::mul(&mut Direct, power, *inv);
            y = dd::add(&mut Direct, y, term);
            if term.0.abs() < 1e-36 {
                break;
            }
        }
        for _ in 0..10 {
            y = dd::mul(&mut Direct, y, dd::add(&mut Direct, (2.0, 0.0), y));
        }
        Xf::make(dd::add(&mut Direct, (1.0, 0.0), y), k as i64)
    }

    pub fn ln(self) -> Xf {
        if self.is_special() || self.hi < 0.0 {
            return Xf::special(self.hi.ln());
        }
        // Near 1, where ln x is small, the general path's last steps (m·e^(−y) − 1, and ln m + e·ln 2 for x just
        // below 1) cancel, leaving 2⁻¹⁰⁶ absolute error: ln(1 − 2⁻⁵³) came out 1e-16 relative off (mpmath). There
        // ln x = 2·atanh(t), t = (x − 1)/(x + 1), with x − 1 exact, by its series in t² (|t| < 1/31).
        if (self.e == 0 && self.hi < 1.0625) || (self.e == -1 && self.hi > 1.875) {
            let t = self.sub(Xf::ONE).div(self.add(Xf::ONE));
            let t2 = t.mul(t);
            let (mut sum, mut power) = (t, t);
            for k in 1..40 {
                power = power.mul(t2);
                let term = power.div(Xf::from_f64((2 * k + 1) as f64));
                sum = sum.add(term);
                if term.is_zero() || term.e < sum.e - 112 {
                    break;
                }
            }
            return sum.add(sum);
        }
        // ln(m·2^e) = ln m + e·ln2, m ∈ [1, 2); Newton on exp: y ← y + m·e^(−y) − 1.
        let m = Xf { e: 0, ..self };
        let y0 = Xf::from_f64(self.hi.ln());
        let y1 = y0.add(m.mul(y0.neg().exp())).sub(Xf::ONE);
        let e = Xf::from_dd(dd::mul(&mut Direct, (self.e as f64, 0.0), LN2));
        y1.add(e)
    }

    pub fn pow(self, y: Xf) -> Xf {
        let (xf, yf) = (self.to_f64(), y.to_f64());
        if y.is_zero() {
            return Xf::ONE;
        }
        if self.partial_cmp(Xf::ONE) == Some(Ordering::Equal) {
            return Xf::ONE;
        }
        if self.is_special() || y.is_special() {
            // C99's special cases decided by libm on the rounded values (size beyond the sign and zero-ness
            // matters only against ±1 and ±∞, where rounding to f64 does not change the case).
            return Xf::from_f64(xf.powf(yf));
        }
        let is_int = y.e >= 53 || yf.fract() == 0.0;
        let odd = is_int && y.e < 53 && (yf % 2.0).abs() == 1.0;
        if self.sign_negative() && !is_int {
            return Xf::NAN;
        }
        let ax = self.abs();
        let r = if is_int && yf.abs() <= 65536.0 {
            let mut k = yf.abs() as u64;
            let (mut acc, mut base) = (Xf::ONE, ax);
            while k > 0 {
                if k & 1 == 1 {
                    acc = acc.mul(base);
                }
                base = base.mul(base);
                k >>= 1;
            }
            if yf < 0.0 {
                Xf::ONE.div(acc)
            } else {
                acc
            }
        } else {
            y.mul(ax.ln()).exp()
        };
        if self.sign_negative() && odd {
            r.neg()
        } else {
            r
        }
    }

    /// (sin x, cos x).
    pub fn sin_cos(self) -> (Xf, Xf) {
        if self.is_special() {
            return (Xf::special(self.hi.sin()), Xf::special(self.hi.cos()));
        }
        if self.e < -60 {
            // sin x = x − x³/6, cos x = 1 − x²/2 to far below 2^-104 relative.
            let x2 = self.mul(self);
            return (self.sub(x2.mul(self).div(Xf::from_f64(6.0))), Xf::ONE.sub(x2.div(Xf::from_f64(2.0))));
        }
        let x = self.to_dd();
        let (k, r) = if self.e < 40 {
            let k = (x.0 / (PI3[0] / 2.0)).round();
            // r = x − k·π/2 with π/2 in three parts (k < 2^41, so k·p exact-ish in dd).
            let mut r = x;
            for p in PI3 {
                r = dd::add(&mut Direct, r, dd::neg(&mut Direct, dd::mul(&mut Direct, (k, 0.0), (p / 2.0, 0.0))));
            }
            (k, r)
        } else {
            // Past 2⁴⁰ the quadrant count outgrows the three parts: Payne–Hanek (past its table, no value).
            match reduce::reduce(self) {
                Some((k, r)) => (k as f64, r),
                None => return (Xf::NAN, Xf::NAN),
            }
        };
        let r2 = dd::mul(&mut Direct, r, r);
        // |r| ≤ π/4: the terms r^i/i! fall below 1e-40 (far below 2^-106 of the sums) by i = 33.
        let inv = inverse_factorials();
        let (mut s, mut c) = (r, (1.0, 0.0));
        let mut even = (1.0, 0.0);
        for i in 1..17 {
            even = dd::mul(&mut Direct, even, r2);
            let odd = dd::mul(&mut Direct, even, r);
            let (tc, ts) = (dd::mul(&mut Direct, even, inv[2 * i]), dd::mul(&mut Direct, odd, inv[2 * i + 1]));
            let (tc, ts) = if i % 2 == 1 { (dd::neg(&mut Direct, tc), dd::neg(&mut Direct, ts)) } else { (tc, ts) };
            s = dd::add(&mut Direct, s, ts);
            c = dd::add(&mut Direct, c, tc);
            if ts.0.abs() < 1e-40 && tc.0.abs() < 1e-40 {
                break;
            }
        }
        let (s, c) = (Xf::from_dd(s), Xf::from_dd(c));
        match (k as i64).rem_euclid(4) {
            0 => (s, c),
            1 => (c, s.neg()),
            2 => (s.neg(), c.neg()),
            _ => (c.neg(), s),
        }
    }

    pub fn atan(self) -> Xf {
        if self.is_special() {
            return Xf::special(self.hi.atan());
        }
        if self.e < -40 {
            // atan x = x − x³/3 (next term x⁵/5 is below 2^-200 relative).
            return self.sub(self.mul(self).mul(self).div(Xf::from_f64(3.0)));
        }
        if self.e > 8 {
            // atan x = ±π/2 − atan(1/x): near ±π/2 the Newton step below loses bits (cos y is tiny there).
            let half_pi = Xf::from_dd(dd::mul(&mut Direct, (PI3[0], PI3[1]), (0.5, 0.0)));
            let h = if self.sign_negative() { half_pi.neg() } else { half_pi };
            return h.sub(Xf::ONE.div(self).atan());
        }
        // Newton on tan y = x: y ← y + c·(x·c − s), s, c = sin y, cos y.
        let y0 = Xf::from_f64(self.to_f64().atan());
        let (s, c) = y0.sin_cos();
        y0.add(c.mul(self.mul(c).sub(s)))
    }

    /// The IR's asin: argument clamped to [−1, 1] (NaN stays NaN).
    pub fn asin(self) -> Xf {
        let x = self.max(Xf::ONE.neg()).min(Xf::ONE);
        let d = Xf::ONE.sub(x).mul(Xf::ONE.add(x)).sqrt();
        if d.is_zero() {
            let h = Xf::from_dd(dd::mul(&mut Direct, (PI3[0], PI3[1]), (0.5, 0.0)));
            return if x.sign_negative() { h.neg() } else { h };
        }
        x.div(d).atan()
    }

    /// The IR's acos: argument clamped to [−1, 1] (NaN stays NaN).
    pub fn acos(self) -> Xf {
        let x = self.max(Xf::ONE.neg()).min(Xf::ONE);
        let den = Xf::ONE.add(x);
        if den.is_zero() {
            return Xf::from_dd((PI3[0], PI3[1]));
        }
        let t = Xf::ONE.sub(x).div(den).sqrt().atan();
        t.add(t)
    }
}

impl std::ops::Neg for Xf {
    type Output = Xf;
    #[inline]
    fn neg(self) -> Xf {
        self.xneg()
    }
}
impl std::ops::Add for Xf {
    type Output = Xf;
    #[inline]
    fn add(self, b: Xf) -> Xf {
        self.xadd(b)
    }
}
impl std::ops::Sub for Xf {
    type Output = Xf;
    #[inline]
    fn sub(self, b: Xf) -> Xf {
        self.xsub(b)
    }
}
impl std::ops::Mul for Xf {
    type Output = Xf;
    #[inline]
    fn mul(self, b: Xf) -> Xf {
        self.xmul(b)
    }
}
impl std::ops::Div for Xf {
    type Output = Xf;
    #[inline]
    fn div(self, b: Xf) -> Xf {
        self.xdiv(b)
    }
}

/// Sign as ±1 for finite non-zero values, the value itself for ±0, ±∞ and NaN.
trait SignumOrSpecial {
    fn signum_or_special(self) -> f64;
}
impl SignumOrSpecial for f64 {
    fn signum_or_special(self) -> f64 {
        if self == 0.0 || !self.is_finite() {
            self
        } else {
            self.signum()
        }
    }
}

#[inline]
fn call(f: Builtin, a: &[Xf]) -> Xf {
    match f {
        Builtin::Pow => a[0].pow(a[1]),
        Builtin::Cos => a[0].sin_cos().1,
        Builtin::Sin | Builtin::SinNear => a[0].sin_cos().0,
        Builtin::Tan => {
            let (s, c) = a[0].sin_cos();
            s.div(c)
        }
        Builtin::Acos => a[0].acos(),
        Builtin::Asin => a[0].asin(),
        Builtin::Atan => a[0].atan(),
        Builtin::Exp => a[0].exp(),
        Builtin::Ln => a[0].ln(),
        Builtin::Sqrt => a[0].sqrt(),
        Builtin::Abs => a[0].abs(),
        Builtin::Min => a[0].min(a[1]),
        Builtin::Max => a[0].max(a[1]),
        Builtin::Clamp => a[0].max(a[1]).min(a[2]),
        Builtin::Fma => a[0] * a[1] + a[2],
        Builtin::ExpMulDiv => (a[0].exp() * a[1]).div(a[2]),
        // A rounding error: 0 in exact arithmetic, like fma(a, b, −a·b).
        Builtin::AcosLo | Builtin::PowLo => Xf::from_f64(0.0),
        // Discontinuous functions decide on the operands rounded to f64, so the truth falls on the same side of
        // a step as the kernel does (an error measured across a step would be the step, not rounding).
        Builtin::Floor => Xf::from_f64(a[0].to_f64().floor()),
        Builtin::Lt | Builtin::Le | Builtin::Eq | Builtin::Ne => {
            Xf::from_f64(f.eval(&[a[0].to_f64(), a[1].to_f64()]))
        }
        Builtin::Select => {
            if a[0].to_f64() != 0.0 {
                a[1]
            } else {
                a[2]
            }
        }
    }
}

/// The formula's exact value at inputs `x` and parameters `params` (a missing parameter is NaN, as in the
/// interpreter), before rounding.
pub(crate) fn eval_x(f: &Formula, x: &[f64; N_INPUTS], params: &[f64]) -> Xf {
    eval_xs(f, &x.map(Xf::from_f64), params)
}

/// [`eval_x`] at inputs that need not be f64 (an input 2⁻⁸¹⁹² away from an edge, [`limit`]): the double-double's
/// value, not settled ([`eval_settled`] settles it).
fn eval_xs(f: &Formula, x: &[Xf; N_INPUTS], params: &[f64]) -> Xf {
    let v = values(f, x, params);
    v[v.len() - 1]
}

/// The double-double's value of every node up to the root, in order.
fn values(f: &Formula, x: &[Xf; N_INPUTS], params: &[f64]) -> Vec<Xf> {
    let n = f.root.index() + 1;
    let mut v: Vec<Xf> = Vec::with_capacity(n);
    for id in f.ir.ids().take(n) {
        let r = node_value(f, id, &v, x, params);
        v.push(r);
    }
    v
}

/// [`eval_xs`], settled for `target`: the double-double's value with its error bound, evaluated again at a
/// higher precision where the bound does not settle it ([`settle`]).
fn eval_xs_for(f: &Formula, x: &[Xf; N_INPUTS], params: &[f64], target: Target) -> Xf {
    let v = values(f, x, params);
    let lr = bounds(f, &v);
    settle(f, x, params, &v, &lr, target)
}

/// The double-double's error bound at every node (log₂, in its units; [`bound`]) from every node's value.
fn bounds(f: &Formula, v: &[Xf]) -> Vec<f64> {
    let n = f.root.index() + 1;
    let mut lr: Vec<f64> = Vec::with_capacity(n);
    for id in f.ir.ids().take(n) {
        let r = bound::node(f, id, v, &lr, None, bound::XF_UNIT);
        lr.push(r);
    }
    lr
}

/// The most bits [`settle`] evaluates with: 1 − 2⁻¹⁰⁷⁵ needs 1 076, π/2 − 5·10⁻³²⁴ about 1 130; a value that
/// needs more keeps the best one found.
const MAX_PRECISION: usize = 4800;

/// The truth's value (the root of the double-double's values `v`, with bounds `lr`) if that settles it for
/// `target`, else the root of [`escalate`]'s evaluation.
fn settle(f: &Formula, x: &[Xf; N_INPUTS], params: &[f64], v: &[Xf], lr: &[f64], target: Target) -> Xf {
    let n = f.root.index() + 1;
    if bound::sure(v[n - 1], lr[n - 1], bound::XF_UNIT, target) {
        return v[n - 1];
    }
    escalate(f, x, params, (v, lr), target).unwrap_or(v[n - 1])
}

/// The formula evaluated again ([`big`]) at as many bits as the double-double's bound at the root asks for (at
/// most 4× as many per step), more while the bound is not met (twice as many where it is unknown), up to
/// [`MAX_PRECISION`]: the root's value from the first evaluation that settles it for `target`, or from the last
/// one; `None` when the arithmetic refuses (an exponent out of its range). The double-double's values and
/// bounds `xf` are reused where they are good to 2⁻⁹⁰ at a transcendental function (its cost at hundreds of
/// bits), their bound carried over.
fn escalate(f: &Formula, x: &[Xf; N_INPUTS], params: &[f64], xf: (&[Xf], &[f64]), target: Target) -> Option<Xf> {
    // Enough bits for the bound to fall ~96 below the value, as far as the bound at this precision tells, but at
    // most 4× the bits: a bound that comes from an operand rounded at this precision (1 − 2⁻³⁵⁰ is 1 at 192 bits)
    // vanishes once the precision holds it, long before the bound's own estimate.
    let wanted = |lr: f64, now: usize| -> usize {
        let guess = if lr.is_finite() { (lr + 100.0).ceil().max(0.0) as usize } else { 2 * now };
        guess.clamp(now + 64, 4 * now).next_multiple_of(64)
    };
    let n = f.root.index() + 1;
    let mut best = None;
    // A sum of operands more than 100 binades apart (1 − 2⁻⁴⁷⁰; 1 − 2⁻¹⁰⁷⁵, which the double-double cannot align)
    // is exact only with as many bits as the span: the first step takes them (spans past 1 200 binades are sums
    // with a value far below every f64, where the smaller operand does not matter).
    let span = f
        .ir
        .ids()
        .take(n)
        .filter_map(|id| match *f.ir.node(id) {
            Node::Binary(BinOp::Add | BinOp::Sub, a, b) => {
                let (ea, eb) = (xf.0[a.index()], xf.0[b.index()]);
                let d = (ea.e - eb.e).unsigned_abs() as usize;
                (!ea.is_special() && !eb.is_special() && d > 100 && d < 1200).then_some(d + 128)
            }
            _ => None,
        })
        .max()
        .unwrap_or(0);
    let mut p = wanted(xf.1[n - 1], 128).max(192).max(span.min(MAX_PRECISION).next_multiple_of(64));
    // The first step reuses the double-double's good transcendentals; where that does not settle the value, their
    // 2⁻⁹⁰ may be what is missing, and the later steps compute everything.
    let mut reuse = true;
    loop {
        let p_now = p.min(MAX_PRECISION);
        let Some((root, lr)) = big::eval(f, x, params, p_now, xf, reuse) else { return best };
        reuse = false;
        if bound::sure(root, lr, -(p_now as f64 - 2.0), target) || p_now == MAX_PRECISION {
            return Some(root);
        }
        best = Some(root);
        p = wanted(lr, p_now);
    }
}

/// Per input and per parameter, the nodes up to the root that read it, in evaluation order: what moving that
/// input or parameter evaluates again ([`eval_moves_with`]); built once per formula.
pub(crate) struct Readers {
    by_input: [Vec<NodeId>; N_INPUTS],
    /// Per parameter the formula reads (index, its readers).
    by_param: Vec<(usize, Vec<NodeId>)>,
    /// The inputs the formula reads.
    pub used: crate::ir::InputSet,
}

impl Readers {
    pub fn new(f: &Formula) -> Readers {
        let n = f.root.index() + 1;
        let reads = f.ir.input_sets();
        let by_input = std::array::from_fn(|i| {
            let input = crate::ir::Input::ALL[i];
            f.ir.ids().take(n).filter(|id| reads[id.index()].contains(input)).collect()
        });
        let by_param = f
            .ir
            .used_params(f.root)
            .into_iter()
            .map(|p| {
                // Whether each node reads parameter p, in arena order (operands come first).
                let mut r: Vec<bool> = Vec::with_capacity(n);
                for id in f.ir.ids().take(n) {
                    let node = f.ir.node(id);
                    let mut reads = matches!(node, Node::Param(q) if *q == p);
                    node.for_each_arg(|a| reads |= r[a.index()]);
                    r.push(reads);
                }
                (usize::from(p), f.ir.ids().take(n).filter(|id| r[id.index()]).collect())
            })
            .collect();
        Readers { by_input, by_param, used: f.used_inputs() }
    }

    /// The parameters the formula reads (indices into its parameter list).
    pub fn params(&self) -> impl Iterator<Item = usize> + '_ {
        self.by_param.iter().map(|(p, _)| *p)
    }
}

/// What a condition estimate moves: an input (by index) or a parameter (by index) to a new value.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) enum Move {
    Input(usize, f64),
    Param(usize, f64),
}

/// The exact values of `f` at `x` with one input or parameter moved at a time, for each of `moves` (rounded to
/// f64), as [`eval`] gives them; only the nodes that read the moved one are evaluated again (a
/// finite-difference condition number moves each read input and parameter both ways: most of a BRDF's nodes
/// read one or two), from the formula's [`Readers`] built beforehand (they depend on the formula, not the point).
pub(crate) fn eval_moves_with(f: &Formula, readers: &Readers, x: &[f64; N_INPUTS], params: &[f64], moves: &[Move]) -> Vec<f64> {
    let base = values(f, &x.map(Xf::from_f64), params);
    eval_moves_from(f, readers, &base, x, params, moves)
}

/// [`eval_moves_with`] from the exact values of every node at the point, computed beforehand (as
/// [`Linear::eval`] leaves them in its [`Scratch`]).
pub(crate) fn eval_moves_from(f: &Formula, readers: &Readers, base: &[Xf], x: &[f64; N_INPUTS], params: &[f64], moves: &[Move]) -> Vec<f64> {
    let n = f.root.index() + 1;
    let xs = x.map(Xf::from_f64);
    let mut v = base.to_vec();
    let no_nodes = Vec::new();
    moves
        .iter()
        .map(|&m| {
            let mut moved = xs;
            let mut moved_params = std::borrow::Cow::Borrowed(params);
            let nodes = match m {
                Move::Input(i, w) => {
                    moved[i] = Xf::from_f64(w);
                    &readers.by_input[i]
                }
                Move::Param(p, w) => {
                    if let Some(slot) = moved_params.to_mut().get_mut(p) {
                        *slot = w;
                    }
                    readers.by_param.iter().find(|(q, _)| *q == p).map_or(&no_nodes, |(_, ids)| ids)
                }
            };
            for &id in nodes {
                v[id.index()] = node_value(f, id, &v, &moved, &moved_params);
            }
            let r = v[n - 1].to_f64();
            for &id in nodes {
                v[id.index()] = base[id.index()];
            }
            r
        })
        .collect()
}

/// The exact value of node `id` given the values `v` of the nodes before it.
#[inline(always)]
fn node_value(f: &Formula, id: NodeId, v: &[Xf], x: &[Xf; N_INPUTS], params: &[f64]) -> Xf {
    match *f.ir.node(id) {
        Node::Const(b) => Xf::from_f64(f64::from_bits(b)),
        Node::Input(i) => x[i.index()],
        // Formulas have no data columns (front ends never produce them).
        Node::Column(_) => Xf::from_f64(f64::NAN),
        Node::Param(p) => Xf::from_f64(params.get(p as usize).copied().unwrap_or(f64::NAN)),
        Node::Neg(a) => v[a.index()].neg(),
        Node::Binary(op, a, b) => {
            let (a, b) = (v[a.index()], v[b.index()]);
            match op {
                BinOp::Add => a.add(b),
                BinOp::Sub => a.sub(b),
                BinOp::Mul => a.mul(b),
                BinOp::Div => a.div(b),
            }
        }
        Node::Call(b, args) => {
            // A trigonometric function of an angle held as q·π/2 + r (angle.rs) is computed from r.
            if let Some(g) = angle::trig_argument(f, id, v, None) {
                if let Some((s, c)) = g.sin_cos() {
                    return match b {
                        Builtin::Cos => c,
                        Builtin::Tan => s.div(c),
                        _ => s,
                    };
                }
            }
            let xs = [v[args[0].index()], v[args[1].index()], v[args[2].index()]];
            call(b, &xs[..b.arity()])
        }
    }
}

/// The exact value as an unevaluated sum `(hi + lo)·2^e` (special values as `hi`): what a check against another
/// arbitrary-precision evaluator reads.
pub fn eval_parts(f: &Formula, x: &[f64; N_INPUTS], params: &[f64]) -> (f64, f64, i64) {
    eval_xs_for(f, &x.map(Xf::from_f64), params, Target::Parts).parts()
}

/// One builtin's value on f64 arguments as the truth computes it, as [`eval_parts`] gives it (NaN for a wrong
/// number of arguments).
pub fn call_parts(b: Builtin, args: &[f64]) -> (f64, f64, i64) {
    if args.len() != b.arity() {
        return Xf::NAN.parts();
    }
    let xs: Vec<Xf> = args.iter().map(|&a| Xf::from_f64(a)).collect();
    call(b, &xs).parts()
}

/// The double-double truth rounded to f64 once: what a perfect kernel returns, except where 104 bits are not
/// enough ([`eval_settled`] knows where; the accuracy measurement uses this one, for cost).
pub fn eval(f: &Formula, x: &[f64; N_INPUTS], params: &[f64]) -> f64 {
    eval_x(f, x, params).to_f64()
}

/// The true value rounded to f64 once, settled: evaluated again at up to 4 800 bits where the double-double's
/// error bound does not settle its rounding (module docs): what the CLI's eval prints as the truth.
pub fn eval_settled(f: &Formula, x: &[f64; N_INPUTS], params: &[f64]) -> f64 {
    eval_xs_for(f, &x.map(Xf::from_f64), params, Target::Rounded).to_f64()
}

/// Distances 2⁻ᵏ from an edge at 0 (any k: the exponent is unbounded) and from ±1 (k ≤ 100: 1 − 2⁻ᵏ must fit the
/// double-double mantissa); an approach converges when the values at all of them round to the same f64.
const FROM_ZERO: [i64; 3] = [2048, 4096, 8192];
const FROM_ONE: [i64; 3] = [72, 88, 100];

/// The formula's one-sided limit at a point where an input sits exactly on an edge (0, or ±1 for a cosine or
/// a direction component), for points where the exact value is not finite (0/0 or ∞·0: Cook–Torrance's
/// `G/(NL·NV)` at NL = 0, Beckmann's `exp(−1/NH²)/NH⁴` at NH = 0).
///
/// Each read input on an edge is moved into the domain by 2⁻ᵏ for growing k (k up to 8192 at 0, 100 at ±1; a
/// direction component at 0 from both sides), the others kept, and the exact values rounded to f64. An approach
/// *converges* when they are all the same f64 ([`FROM_ZERO`], [`FROM_ONE`]). The limit is accepted when some approach
/// converges to a finite value and every approach that converges (to anything, ∞ included) agrees with it;
/// approaches that stay NaN or keep changing (a logarithm's slow growth) neither count nor veto.
///
/// What this proves and what it samples: the values are exact (no rounding before the last), so a converged
/// sequence is the formula's value rounded to f64 at those points; that it stays so for all smaller distances
/// is *sampled* (a formula whose value moves again below 2⁻⁸¹⁹², or whose limit along another path differs, is
/// accepted wrongly), which for BRDF terms (powers, exponentials of powers, quotients of them) does not happen.
/// Cost: up to 3 evaluations per edge input and side, only where [`eval`] is not finite.
pub fn limit(f: &Formula, x: &[f64; N_INPUTS], params: &[f64]) -> Option<f64> {
    let used = f.used_inputs();
    let base = x.map(Xf::from_f64);
    let mut found: Option<f64> = None;
    let mut vetoed = false;
    let mut approach = |i: usize, at: Xf, side: f64, steps: &[i64]| {
        let at_k = |k: i64| {
            let mut xs = base;
            xs[i] = at + Xf { hi: side, lo: 0.0, e: -k };
            eval_xs(f, &xs, params).to_f64()
        };
        // Nearest first: a NaN there ends the approach after one evaluation. -0 and +0 are the same limit.
        let last = at_k(steps[steps.len() - 1]);
        if last.is_nan() || steps[..steps.len() - 1].iter().any(|&k| at_k(k) != last) {
            return;
        }
        match found {
            _ if !last.is_finite() => vetoed = true,
            Some(l) if l != last => vetoed = true,
            _ => found = Some(last),
        }
    };
    for inp in used.iter() {
        let i = inp.index();
        let signed = crate::ir::Input::DIRECTIONS.contains(&inp);
        match x[i] {
            0.0 => {
                approach(i, Xf::ZERO, 1.0, &FROM_ZERO);
                if signed {
                    approach(i, Xf::ZERO, -1.0, &FROM_ZERO);
                }
            }
            1.0 => approach(i, Xf::ONE, -1.0, &FROM_ONE),
            -1.0 if signed => approach(i, Xf::ONE.neg(), 1.0, &FROM_ONE),
            _ => {}
        }
    }
    found.filter(|_| !vetoed)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::ir::Input;

    /// Moving one input or the parameter at a time with the other nodes shared gives what evaluating from
    /// scratch gives, on a formula whose nodes read different inputs (and a select, an exp, a parameter).
    #[test]
    fn moved_inputs_share_the_nodes_that_do_not_read_them() {
        let f = crate::front::parse("m.brdf", "param m = 0.3 in 0.01..1\nlet d = exp((NH^2 - 1)/(m*m*NH^2))\nNL <= 0 ? 0 : d*VH/(NL*NV + m) + NV^3").unwrap();
        let mut r = crate::base::rng::Rng(9);
        for _ in 0..300 {
            let mut x = [0.5; N_INPUTS];
            for v in x.iter_mut() {
                *v = r.unit() * 2.0 - 0.5;
            }
            let p = [0.01 + r.unit()];
            let mut moves: Vec<Move> = (0..N_INPUTS).flat_map(|i| [Move::Input(i, x[i].next_up()), Move::Input(i, -x[i])]).collect();
            moves.extend([Move::Param(0, p[0].next_up()), Move::Param(0, 0.5 * p[0])]);
            let got = eval_moves_with(&f, &Readers::new(&f), &x, &p, &moves);
            for (&m, g) in moves.iter().zip(got) {
                let (mut y, mut q) = (x, p);
                match m {
                    Move::Input(i, w) => y[i] = w,
                    Move::Param(i, w) => q[i] = w,
                }
                assert_eq!(g.to_bits(), eval(&f, &y, &q).to_bits(), "{m:?}, x = {x:?}");
            }
        }
    }

    /// Where 104 bits are not enough the bound sees it and a second evaluation settles it; where they are, the
    /// double-double's value stands (random points, the same f64 with and without the second evaluation).
    #[test]
    fn values_beyond_104_bits_are_settled() {
        let one = |src: &str, x: [f64; N_INPUTS]| eval_settled(&crate::front::parse("h.brdf", src).unwrap(), &x, &[]);
        let mut x = [0.5; N_INPUTS];
        // 1 − (1 − 2⁻¹⁰⁷⁵)⁵ = 5·2⁻¹⁰⁷⁵ − 10·2⁻²¹⁵⁰ + …: just below 2.5 subnormal steps, so 2 of them (it was 0).
        x[Input::NL.index()] = 5e-324;
        assert_eq!(one("1 - pow(1 - NL/2, 5)", x), 2.0 * 5e-324);
        // The same scaled into the normal range: 10³⁰⁰·2.5·2⁻¹⁰⁷⁴, rounded once.
        assert_eq!(one("(1 - pow(1 - NL/2, 5))*1e300", x), (1e300 * 2.5) * 5e-324);
        // tan(acos(z)) = 1/z − z/3 − …: the correctly rounded 1/z (it was ±2¹⁰⁴ at such z); the double-double
        // alone has it too, through the angle held as π/2 + r.
        for z in [1e-300, 2.75e-309, 1e-200, 3e-30] {
            x[Input::NL.index()] = z;
            assert_eq!(one("tan(acos(NL))", x), 1.0 / z, "z = {z}");
            assert_eq!(one("tan((acos(NL) + acos(NL))/2)", x), 1.0 / z, "z = {z}");
            assert_eq!(eval(&crate::front::parse("h.brdf", "tan(acos(NL))").unwrap(), &x, &[]), 1.0 / z, "z = {z}");
        }
        // At random points the double-double mostly settles itself; a second evaluation changes nothing there.
        let f = crate::front::parse("r.brdf", "let a = acos(NL)
let b = acos(NV)
(1 - pow(1 - NH/2, 5))*tan((a + b)/2) + exp(-VR/(NH*NH))/(VH + 1e-3)").unwrap();
        let mut r = crate::base::rng::Rng(0x5EED);
        for _ in 0..2000 {
            for v in x.iter_mut().take(5) {
                *v = r.unit().powi(1 + (r.unit() * 8.0) as i32);
            }
            let xs = x.map(Xf::from_f64);
            let n = f.root.index() + 1;
            let mut v = Vec::with_capacity(n);
            for id in f.ir.ids().take(n) {
                let r = node_value(&f, id, &v, &xs, &[]);
                v.push(r);
            }
            let lr = bounds(&f, &v);
            if bound::sure(v[n - 1], lr[n - 1], bound::XF_UNIT, Target::Rounded) {
                let big = big::eval(&f, &xs, &[], 640, (&v, &lr), false).unwrap().0;
                assert_eq!(v[n - 1].to_f64().to_bits(), big.to_f64().to_bits(), "x = {x:?}");
            }
        }
    }

    fn dd(x: Xf) -> Dd {
        (ldexp(x.hi, x.e), ldexp(x.lo, x.e))
    }
    /// |a − b| ≤ tol·|b| with b a double-double reference.
    fn close(a: Xf, b: Dd, tol: f64) -> bool {
        let d = dd::add(&mut Direct, dd(a), dd::neg(&mut Direct, b));
        (d.0.abs()) <= tol * b.0.abs()
    }

    #[test]
    fn constants_to_double_double_precision() {
        // e, π/4, ln 2, √2 and sin 1, cos 1 from the QD library / 34-digit tables.
        let e = (std::f64::consts::E, 1.445646891729250158e-16);
        assert!(close(Xf::ONE.exp(), e, 1e-31), "{:?}", Xf::ONE.exp());
        let pi4 = (std::f64::consts::FRAC_PI_4, 3.061616997868383018e-17);
        assert!(close(Xf::ONE.atan(), pi4, 1e-31), "{:?}", Xf::ONE.atan());
        assert!(close(Xf::from_f64(2.0).ln(), LN2, 1e-31));
        let sqrt2 = (std::f64::consts::SQRT_2, -9.667293313452913451e-17);
        assert!(close(Xf::from_f64(2.0).sqrt(), sqrt2, 1e-31));
        // sin and cos as double-doubles (mpmath at 300 bits), at arguments that reduce to every quadrant.
        let table = [
            (1.0, (0.8414709848078965, 1.776845092935536e-18), (0.5403023058681398, -4.760954612604417e-17)),
            (0.7, (0.644217687237691, 2.8740567927338755e-18), (0.7648421872844885, -4.013780434022238e-17)),
            (2.9, (0.23924932921398243, -1.1267666643498124e-17), (-0.9709581651495905, 4.579633153232696e-17)),
            (-0.3, (-0.29552020666133955, -1.8315357276792536e-17), (0.955336489125606, 4.1935600297907467e-17)),
            (1e-05, (9.999999999833334e-06, 6.182336062862823e-22), (0.99999999995, 4.137435208440879e-18)),
            (100.5, (-0.030959966783271346, 8.320928549434447e-19), (0.9995206253283515, -5.012512561737467e-17)),
        ];
        for (v, sin, cos) in table {
            let (s, c) = Xf::from_f64(v).sin_cos();
            assert!(close(s, sin, 1e-30), "sin {v}: {s:?}");
            assert!(close(c, cos, 1e-30), "cos {v}: {c:?}");
        }
        // Identities at double-double precision.
        for v in [0.1, 0.7, 1.3, 2.9, 10.0, 100.5] {
            let x = Xf::from_f64(v);
            let (s, c) = x.sin_cos();
            assert!(close(s.mul(s).add(c.mul(c)), (1.0, 0.0), 1e-30), "{v}");
            assert!(close(x.ln().exp(), (v, 0.0), 1e-30), "{v}");
            let t = Xf::from_f64(v / 101.0);
            assert!(close(t.asin().sin_cos().0, (v / 101.0, 0.0), 1e-30), "{v}");
            // cos near π/2 turns acos's absolute error (~2^-105) into a relative one of 2^-105/t.
            assert!(close(t.acos().sin_cos().1, (v / 101.0, 0.0), 1e-30 * 101.0 / v), "{v}");
        }
        assert_eq!(Xf::from_f64(-1.0).acos().to_f64(), std::f64::consts::PI);
        assert_eq!(Xf::from_f64(1.0 + 1e-15).acos().to_f64(), 0.0);
    }

    #[test]
    fn agrees_with_libm_to_one_ulp() {
        let mut s = 0x9e3779b97f4a7c15u64;
        for _ in 0..2000 {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            let u = (s >> 11) as f64 / (1u64 << 53) as f64;
            let x = Xf::from_f64(u);
            let ulp = |a: f64, b: f64| (a.to_bits() as i64 - b.to_bits() as i64).abs();
            assert!(ulp(x.exp().to_f64(), u.exp()) <= 1, "exp {u}");
            assert!(ulp(x.ln().to_f64(), u.ln()) <= 1, "ln {u}");
            assert!(ulp(x.acos().to_f64(), u.acos()) <= 1, "acos {u}");
            assert!(ulp(x.asin().to_f64(), u.asin()) <= 1, "asin {u}");
            assert!(ulp(x.atan().to_f64(), u.atan()) <= 1, "atan {u}");
            assert!(ulp(x.sin_cos().0.to_f64(), u.sin()) <= 1, "sin {u}");
            let y = Xf::from_f64(-300.0 * u);
            assert!(ulp(y.exp().to_f64(), (-300.0 * u).exp()) <= 1, "exp {}", -300.0 * u);
            assert!(ulp(x.pow(Xf::from_f64(7.5)).to_f64(), u.powf(7.5)) <= 1, "pow {u}");
        }
    }

    #[test]
    fn no_overflow_or_underflow_in_between() {
        let t = Xf::from_f64(1e-100);
        let t4 = t.mul(t).mul(t).mul(t);
        assert_eq!(t4.to_f64(), 0.0);
        assert_eq!(Xf::ONE.div(t4).mul(t4).to_f64(), 1.0);
        // exp(−1/t²) underflows past any f64 but is still > 0 here; times 1/t⁴ it is 0 after rounding.
        let e = Xf::ONE.div(t.mul(t)).neg().exp();
        assert_eq!(Xf::ONE.div(t4).mul(e).to_f64(), 0.0);
        // Ward's 1/sqrt(NL·NV) at 1.6e-162.
        let a = Xf::from_f64(1.6e-162);
        let w = Xf::ONE.div(a.mul(a).sqrt()).to_f64();
        assert!((w - 1.0 / 1.6e-162).abs() <= 1e-15 * w, "{w}");
        // Specials follow IEEE.
        assert!(Xf::ZERO.div(Xf::ZERO).is_nan());
        assert!(Xf::from_f64(f64::INFINITY).mul(Xf::ZERO).is_nan());
        assert_eq!(Xf::ONE.div(Xf::ZERO).to_f64(), f64::INFINITY);
        assert!(Xf::NAN.min(Xf::ONE).is_nan());
        assert!(Xf::ZERO.min(Xf::from_f64(-0.0)).to_f64().is_sign_negative());
        assert_eq!(Xf::from_f64(-8.0).pow(Xf::from_f64(3.0)).to_f64(), -512.0);
        assert!(Xf::from_f64(-8.0).pow(Xf::from_f64(0.5)).is_nan());
        assert_eq!(Xf::ZERO.pow(Xf::from_f64(-2.0)).to_f64(), f64::INFINITY);
    }

    #[test]
    fn blinn_power_is_exactly_rounded() {
        // (1 − 2^-10)^1000 = exp(1000·ln(1 − 2^-10)) = 0.37626... ; binary powering vs exp·ln agree.
        let x = Xf::from_f64(1.0 - 2f64.powi(-10));
        let a = x.pow(Xf::from_f64(1000.0));
        let b = Xf::from_f64(1000.0).mul(x.ln()).exp();
        assert!(close(a, dd(b), 1e-28));
        assert!(((a.to_f64() - 0.3765) / 0.3765).abs() < 1e-3, "{}", a.to_f64());
    }

    /// Limits at an input exactly on its edge: found where the written form is 0/0 or ∞·0 (Cook–Torrance's
    /// G/(NL·NV) at NL = 0; Beckmann at NH = 0, limit 0; x·ln x at 0), and refused where the value grows without
    /// bound (a pole, ln) or where the approaches along two inputs disagree.
    #[test]
    fn limits_at_edge_inputs() {
        let parse = |body: &str| crate::front::parse("t.brdf", &format!("param m = 0.3 in 0.01..1\n@domain raw\n{body}")).unwrap();
        let x = |nl: f64, nv: f64, nh: f64, vh: f64| crate::from_cosines([nl, nv, nh, nh, vh]);
        let p = [50.0, 0.3];
        let ct = parse("min(1, min(2*NH*NV/VH, 2*NH*NL/VH)) / (NL*NV)");
        let at = x(0.0, 0.25, 0.9, 0.5);
        assert!(eval(&ct, &at, &p).is_nan());
        // The limit: 2·NH/(VH·NV) = 14.4, as the value at NL = 10⁻³⁰⁰ rounds.
        assert_eq!(limit(&ct, &at, &p), Some(eval(&ct, &x(1e-300, 0.25, 0.9, 0.5), &p)));
        assert_eq!(limit(&ct, &at, &p), Some(14.4));
        // Along NL and along NV both 0: still 0/0 on each approach, so no limit.
        assert_eq!(limit(&ct, &x(0.0, 0.0, 0.9, 0.5), &p), None);
        let beckmann = parse("exp((NH^2 - 1)/(m^2*NH^2)) / (m^2*NH^4)");
        assert!(eval(&beckmann, &x(0.5, 0.5, 0.0, 0.5), &p).is_nan());
        assert_eq!(limit(&beckmann, &x(0.5, 0.5, 0.0, 0.5), &p), Some(0.0));
        let xlnx = parse("NL*ln(NL)");
        assert_eq!(limit(&xlnx, &x(0.0, 0.5, 0.5, 0.5), &p), Some(0.0));
        // A pole and a logarithm: no finite limit.
        assert_eq!(limit(&parse("NL/NL/NL"), &x(0.0, 0.5, 0.5, 0.5), &p), None);
        assert_eq!(limit(&parse("ln(NL)*NL/NL"), &x(0.0, 0.5, 0.5, 0.5), &p), None);
        // From 1: (1 − NH²)/(1 − NH) → 2.
        assert_eq!(limit(&parse("(1 - NH*NH)/(1 - NH)"), &x(0.5, 0.5, 1.0, 0.5), &p), Some(2.0));
        // Two inputs on an edge: along NL, NV/NV stays 0/0 (no veto); along NV the value is 1: accepted.
        assert_eq!(limit(&parse("(NL + 1)*NV/NV"), &x(0.0, 0.0, 0.5, 0.5), &p), Some(1.0));
        // A finite limit along one input and an infinite one along another: refused.
        assert_eq!(limit(&parse("NV/NV + 1/NL*(NV/NV)"), &x(0.0, 0.0, 0.5, 0.5), &p), None);
    }
}
