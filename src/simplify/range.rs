//! Interval (range) analysis over the IR, for the rewrites that are exact only on part of the domain.
//!
//! A [`Range`] bounds the non-NaN values a node can take (`lo..=hi`, ±0 both counted as 0), says whether NaN is
//! possible and whether −0 is possible (the sign of zero decides `x + 0 → x` and `max(x, 0) → x`).
//!
//! Soundness: `+ − × ÷` and `sqrt` are correctly rounded and rounding to nearest is monotone, so the rounded
//! results of the corner operands bound every rounded result in the box: no outward rounding is needed. The
//! libm functions (exp, ln, pow, trig) are not guaranteed monotone or correctly rounded, so their bounds are
//! widened by [`LIBM_SLACK`] ulps and clipped to the function's mathematical range.

use crate::builtins::Builtin;
use std::f64::consts::{FRAC_PI_2, PI};

/// Ulps by which bounds computed through a libm function are widened (glibc documents < 1–2 ulp).
pub(crate) const LIBM_SLACK: u32 = 4;

/// Bounds on the values a node can take; see the module docs.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct Range {
    /// Smallest non-NaN value (may be −inf).
    pub lo: f64,
    /// Largest non-NaN value (may be +inf).
    pub hi: f64,
    /// NaN is possible.
    pub nan: bool,
    /// −0 is possible.
    pub negz: bool,
}

fn down(mut v: f64, n: u32) -> f64 {
    for _ in 0..n {
        if v.is_finite() {
            v = v.next_down();
        }
    }
    v
}

fn up(mut v: f64, n: u32) -> f64 {
    for _ in 0..n {
        if v.is_finite() {
            v = v.next_up();
        }
    }
    v
}

impl Range {
    /// Anything, NaN included.
    pub(crate) const TOP: Range = Range { lo: f64::NEG_INFINITY, hi: f64::INFINITY, nan: true, negz: true };

    pub(crate) fn new(lo: f64, hi: f64, nan: bool, negz: bool) -> Range {
        if lo.is_nan() || hi.is_nan() || lo > hi {
            return Range::TOP;
        }
        // Normalise −0 bounds to +0 so comparisons are plain.
        Range { lo: lo + 0.0, hi: hi + 0.0, nan, negz }
    }

    pub(crate) fn constant(v: f64) -> Range {
        if v.is_nan() {
            // NaN only; TOP is sound (and a NaN constant is rare enough not to matter).
            return Range::TOP;
        }
        Range::new(v, v, false, v == 0.0 && v.is_sign_negative())
    }

    /// Every non-NaN value has a clear sign bit (≥ +0).
    pub(crate) fn nonneg(self) -> bool {
        self.lo >= 0.0 && !self.negz
    }
    /// No NaN and no infinity.
    pub(crate) fn finite(self) -> bool {
        !self.nan && self.lo.is_finite() && self.hi.is_finite()
    }
    pub(crate) fn contains_zero(self) -> bool {
        self.lo <= 0.0 && self.hi >= 0.0
    }
    /// Zero is impossible (neither sign).
    pub(crate) fn excludes_zero(self) -> bool {
        !self.contains_zero()
    }
    pub(crate) fn within(self, lo: f64, hi: f64) -> bool {
        self.lo >= lo && self.hi <= hi
    }

    /// `x·x` of one value: never below +0 ((−0)² = +0), NaN only from NaN (inf² = inf). The corners of `x·y`
    /// would allow lo·hi < 0 for a range containing zero.
    pub(crate) fn square(self) -> Range {
        let (a, b) = (self.lo * self.lo, self.hi * self.hi);
        let lo = if self.contains_zero() { 0.0 } else { a.min(b) };
        Range::new(lo, a.max(b), self.nan, false)
    }

    fn widened(lo: f64, hi: f64, nan: bool, negz: bool) -> Range {
        Range::new(down(lo, LIBM_SLACK), up(hi, LIBM_SLACK), nan, negz)
    }

    /// Bounds from the four corner values of a monotone-in-each-argument operation.
    fn corners(vals: [f64; 4], nan: bool, negz: bool) -> Range {
        if vals.iter().any(|v| v.is_nan()) {
            return Range { nan: true, ..Range::TOP };
        }
        let lo = vals.iter().copied().fold(f64::INFINITY, f64::min);
        let hi = vals.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        Range::new(lo, hi, nan, negz)
    }

    fn neg_(self) -> Range {
        Range::new(-self.hi, -self.lo, self.nan, self.contains_zero())
    }

    fn add_(self, b: Range) -> Range {
        let a = self;
        let inf_minus_inf = (a.hi == f64::INFINITY && b.lo == f64::NEG_INFINITY)
            || (a.lo == f64::NEG_INFINITY && b.hi == f64::INFINITY);
        // In round-to-nearest, a + b is −0 only when both are −0.
        let negz = a.negz && b.negz;
        let r = Range::corners([a.lo + b.lo, a.hi + b.hi, a.lo + b.lo, a.hi + b.hi], a.nan || b.nan || inf_minus_inf, negz);
        if r.lo > r.hi {
            Range::TOP
        } else {
            r
        }
    }

    fn sub_(self, b: Range) -> Range {
        // a − b is exactly a + (−b), including the sign of zero (−0 − +0 = −0 + −0 = −0).
        self.add_(b.neg_())
    }

    /// −0 possible for a product or quotient: unless both factors have clear sign bits, any zero result may be −0.
    fn sign_negz(a: Range, b: Range, r: Range) -> bool {
        !(a.nonneg() && b.nonneg()) && r.contains_zero()
    }

    fn mul_(self, b: Range) -> Range {
        let a = self;
        let zero_inf = (a.contains_zero() && (b.lo.is_infinite() || b.hi.is_infinite()))
            || (b.contains_zero() && (a.lo.is_infinite() || a.hi.is_infinite()));
        let nan = a.nan || b.nan || zero_inf;
        let r = Range::corners([a.lo * b.lo, a.lo * b.hi, a.hi * b.lo, a.hi * b.hi], nan, true);
        if r == Range::TOP || (r.nan && r.lo == f64::NEG_INFINITY && r.hi == f64::INFINITY) {
            // A 0·inf corner: keep the sign knowledge if both are non-negative.
            if a.nonneg() && b.nonneg() {
                return Range::new(0.0, f64::INFINITY, true, false);
            }
            return Range::TOP;
        }
        Range { negz: Range::sign_negz(a, b, r), ..r }
    }

    fn div_(self, b: Range) -> Range {
        let a = self;
        let nan = a.nan
            || b.nan
            || (a.contains_zero() && b.contains_zero())
            || ((a.lo.is_infinite() || a.hi.is_infinite()) && (b.lo.is_infinite() || b.hi.is_infinite()));
        if b.contains_zero() {
            if a.nonneg() && b.nonneg() {
                return Range::new(0.0, f64::INFINITY, nan, false);
            }
            return Range { nan, ..Range::TOP };
        }
        let r = Range::corners([a.lo / b.lo, a.lo / b.hi, a.hi / b.lo, a.hi / b.hi], nan, true);
        if r.lo == f64::NEG_INFINITY && r.hi == f64::INFINITY {
            return Range { nan, ..Range::TOP };
        }
        Range { negz: Range::sign_negz(a, b, r), ..r }
    }

    pub(crate) fn min(self, b: Range) -> Range {
        Range::new(self.lo.min(b.lo), self.hi.min(b.hi), self.nan || b.nan, self.negz || b.negz)
    }

    pub(crate) fn max(self, b: Range) -> Range {
        let a = self;
        // IEEE maximum returns −0 only when one is −0 and the other is −0 or below.
        let negz = (a.negz && (b.negz || b.lo < 0.0)) || (b.negz && (a.negz || a.lo < 0.0));
        Range::new(a.lo.max(b.lo), a.hi.max(b.hi), a.nan || b.nan, negz)
    }

    /// Range of a builtin call (`args` has `f.arity()` ranges; `konst` holds argument constants if known).
    pub(crate) fn call(f: Builtin, args: &[Range], konst: &[Option<f64>]) -> Range {
        let a = args[0];
        let inf = a.lo.is_infinite() || a.hi.is_infinite();
        match f {
            Builtin::Sqrt => {
                if a.hi < 0.0 {
                    return Range { nan: true, ..Range::TOP };
                }
                Range::new(a.lo.max(0.0).sqrt(), a.hi.sqrt(), a.nan || a.lo < 0.0, a.negz)
            }
            Builtin::Abs => {
                let (m, big) = if a.contains_zero() { (0.0, (-a.lo).max(a.hi)) } else { (a.lo.abs().min(a.hi.abs()), a.lo.abs().max(a.hi.abs())) };
                Range::new(m, big, a.nan, false)
            }
            Builtin::Exp => {
                let r = Range::widened(a.lo.exp(), a.hi.exp(), a.nan, false);
                Range::new(r.lo.max(0.0), r.hi, a.nan, false)
            }
            Builtin::Ln => {
                if a.hi < 0.0 {
                    return Range { nan: true, ..Range::TOP };
                }
                Range::widened(a.lo.max(0.0).ln(), a.hi.ln(), a.nan || a.lo < 0.0, false)
            }
            // cos is decreasing on [0, π], sin increasing on [−π/2, π/2]; elsewhere only [−1, 1] is known.
            Builtin::Cos if a.lo >= 0.0 && a.hi <= PI => {
                let r = Range::widened(a.hi.cos(), a.lo.cos(), a.nan, false);
                Range::new(r.lo.max(-1.0), r.hi.min(1.0), a.nan, false)
            }
            Builtin::Sin | Builtin::SinNear if a.lo >= -FRAC_PI_2 && a.hi <= FRAC_PI_2 => {
                let r = Range::widened(a.lo.sin(), a.hi.sin(), a.nan, true);
                Range::new(r.lo.max(-1.0), r.hi.min(1.0), a.nan, a.negz)
            }
            Builtin::Cos | Builtin::Sin | Builtin::SinNear => Range::new(-1.0, 1.0, a.nan || inf, true),
            Builtin::Tan => Range { nan: a.nan || inf, ..Range::TOP },
            Builtin::Acos => {
                // The builtin clamps its argument to [−1, 1]; acos is decreasing.
                let (l, h) = (a.lo.clamp(-1.0, 1.0), a.hi.clamp(-1.0, 1.0));
                let r = Range::widened(h.acos(), l.acos(), a.nan, false);
                Range::new(r.lo.max(0.0), r.hi.min(up(PI, 1)), a.nan, false)
            }
            Builtin::Asin => {
                let (l, h) = (a.lo.clamp(-1.0, 1.0), a.hi.clamp(-1.0, 1.0));
                let r = Range::widened(l.asin(), h.asin(), a.nan, true);
                Range::new(r.lo.max(-up(FRAC_PI_2, 1)), r.hi.min(up(FRAC_PI_2, 1)), a.nan, a.contains_zero())
            }
            Builtin::Atan => {
                let r = Range::widened(a.lo.atan(), a.hi.atan(), a.nan, true);
                Range::new(r.lo.max(-up(FRAC_PI_2, 1)), r.hi.min(up(FRAC_PI_2, 1)), a.nan, a.contains_zero())
            }
            Builtin::Min => a.min(args[1]),
            Builtin::Max => a.max(args[1]),
            Builtin::Clamp => a.max(args[1]).min(args[2]),
            // The exact product lies within the rounded products' range widened by an ulp; a negative product
            // below the denormals plus a zero c rounds once, to −0 (a rounded product and + 0 would give +0).
            Builtin::Fma => {
                let m = a.mul_(args[1]);
                let r = Range::widened(m.lo, m.hi, m.nan, m.negz).add_(args[2]);
                Range { negz: r.negz || m.negz || (m.lo < 0.0 && args[2].contains_zero()), ..r }
            }
            // Within acos's own error of ≤ 2 ulp of a value ≤ π: |tail| < 2⁻⁵⁰.
            Builtin::AcosLo => Range::new(-8.9e-16, 8.9e-16, a.nan, true),
            // Within pow's own error (≤ 0.55 ulp, < 2⁻⁵²·|pow|); 0 wherever pow is a special case or NaN.
            Builtin::PowLo => {
                let p = Range::pow(a, args[1], konst.get(1).copied().flatten());
                let m = p.lo.abs().max(p.hi.abs()) * 2.3e-16;
                if m.is_finite() { Range::new(-m, m, false, true) } else { Range { nan: false, ..Range::TOP } }
            }
            // e^a·b/c for b ≥ 0, c > 0, from the exponent sum a + ln b − ln c (libm's ln and exp are far within
            // the 1e-9 relative slack); anything else is unknown.
            Builtin::ExpMulDiv => {
                let (b, c) = (args[1], args[2]);
                if !(b.lo >= 0.0 && c.lo > 0.0) {
                    return Range::TOP;
                }
                let (l, h) = (a.lo + b.lo.ln() - c.hi.ln(), a.hi + b.hi.ln() - c.lo.ln());
                // e^a is 0 below a ≈ −745.2 and the builtin takes 0·∞ there as 0 (an infinite b stands for an
                // overflowed finite factor), which the exponent sum with ln ∞ does not see.
                let vanishing = a.lo < -745.2 && b.hi == f64::INFINITY;
                let lo = if l > -700.0 && !vanishing { l.exp() * (1.0 - 1e-9) } else { 0.0 };
                let hi = if h < 700.0 { h.exp() * (1.0 + 1e-9) } else { f64::INFINITY };
                // e^a overflows to ∞ past a ≈ 709.78, and ∞·0 is NaN, as in exp(a)*b/c written out.
                let overflow_times_zero = a.hi > 709.0 && b.contains_zero();
                let nan = a.nan || b.nan || c.nan || overflow_times_zero || b.hi == f64::INFINITY || c.hi == f64::INFINITY;
                Range::new(lo, hi, nan, b.negz)
            }
            Builtin::Floor => Range::new(a.lo.floor(), a.hi.floor(), a.nan, a.negz),
            Builtin::Lt | Builtin::Le | Builtin::Eq | Builtin::Ne => Range::new(0.0, 1.0, false, false),
            Builtin::Select => {
                let (b, c) = (args[1], args[2]);
                let union = Range::new(b.lo.min(c.lo), b.hi.max(c.hi), b.nan || c.nan, b.negz || c.negz);
                match konst[0] {
                    Some(k) if k != 0.0 => b,
                    Some(_) => c,
                    None if !a.contains_zero() => b,
                    None => union,
                }
            }
            Builtin::Pow => Range::pow(a, args[1], konst.get(1).copied().flatten()),
        }
    }

    fn pow(a: Range, b: Range, k: Option<f64>) -> Range {
        let nan_args = a.nan || b.nan;
        if let Some(k) = k {
            if k == 0.0 {
                // pow(x, 0) = 1 for every x, NaN included (C99 F.9.4.4).
                return Range::constant(1.0);
            }
            if k.fract() == 0.0 && k.abs() <= 1e6 {
                let even = (k / 2.0).fract() == 0.0;
                // |x|^k is monotone in |x| on each side of zero; bound it from the extreme magnitudes.
                let (mlo, mhi) = if a.contains_zero() {
                    (0.0, (-a.lo).max(a.hi))
                } else {
                    (a.lo.abs().min(a.hi.abs()), a.lo.abs().max(a.hi.abs()))
                };
                let (plo, phi) = if k > 0.0 { (mlo.powf(k), mhi.powf(k)) } else { (mhi.powf(k), mlo.powf(k)) };
                if even || a.nonneg() {
                    // Non-negative: widen the upper bound only (widening 0 down would lose the sign).
                    let w = Range::widened(plo, phi, nan_args, false);
                    return Range::new(w.lo.max(0.0), w.hi, nan_args, false);
                }
                return Range::widened(-phi, phi, nan_args, true);
            }
        }
        if a.nonneg() {
            // pow of a non-negative base is ≥ +0 (or NaN from a NaN exponent); ≤ 1 when base ≤ 1 and y ≥ 0.
            let hi = if a.hi <= 1.0 && b.lo >= 0.0 { 1.0 } else { f64::INFINITY };
            return Range::new(0.0, hi, nan_args, false);
        }
        // A negative base with a non-integer exponent is NaN.
        Range::TOP
    }
}

impl std::ops::Neg for Range {
    type Output = Range;
    fn neg(self) -> Range {
        self.neg_()
    }
}

macro_rules! binop {
    ($tr:ident, $f:ident, $imp:ident) => {
        impl std::ops::$tr for Range {
            type Output = Range;
            fn $f(self, b: Range) -> Range {
                self.$imp(b)
            }
        }
    };
}
binop!(Add, add, add_);
binop!(Sub, sub, sub_);
binop!(Mul, mul, mul_);
binop!(Div, div, div_);

#[cfg(test)]
mod tests {
    use super::*;

    fn unit() -> Range {
        Range::new(0.0, 1.0, false, false)
    }

    /// Every rounded result of `op` on sampled members of `a` and `b` lies in the computed range.
    fn check_sound(a: Range, b: Range, op: impl Fn(f64, f64) -> f64, r: Range) {
        let samples = |x: Range| {
            let mut v = vec![x.lo, x.hi, (x.lo + x.hi) / 2.0, x.lo.next_up(), x.hi.next_down()];
            if x.contains_zero() {
                v.push(0.0);
                if x.negz {
                    v.push(-0.0)
                }
            }
            v.retain(|t| *t >= x.lo && *t <= x.hi);
            v
        };
        for x in samples(a) {
            for y in samples(b) {
                let z = op(x, y);
                if z.is_nan() {
                    assert!(r.nan, "{x} {y} gives NaN, range {r:?}");
                } else {
                    assert!(z >= r.lo && z <= r.hi, "{x} {y} -> {z} outside {r:?}");
                    if z == 0.0 && z.is_sign_negative() {
                        assert!(r.negz, "{x} {y} -> -0 but range says no -0: {r:?}");
                    }
                }
            }
        }
    }

    #[test]
    fn arithmetic_is_sound_on_samples() {
        let rs = [
            unit(),
            Range::new(-2.0, 3.0, false, true),
            Range::new(1e-300, 1e300, false, false),
            Range::new(-5.0, -0.5, false, false),
            Range::new(0.0, f64::INFINITY, false, false),
            Range::constant(-0.0),
            Range::new(0.0, PI, false, false),
            Range::new(-FRAC_PI_2, 0.3, false, true),
        ];
        for a in rs {
            for b in rs {
                check_sound(a, b, |x, y| x + y, a + b);
                check_sound(a, b, |x, y| x - y, a - b);
                check_sound(a, b, |x, y| x * y, a * b);
                check_sound(a, a, |x, _| x * x, a.square());
                check_sound(a, b, |x, y| x / y, a / b);
                check_sound(a, b, crate::builtins::fmax, a.max(b));
                check_sound(a, b, crate::builtins::fmin, a.min(b));
                for k in [-3.0, -2.0, 0.0, 0.5, 2.0, 3.0, 7.5] {
                    let r = Range::call(Builtin::Pow, &[a, Range::constant(k)], &[None, Some(k)]);
                    check_sound(a, Range::constant(k), |x, y| x.powf(y), r);
                }
                for f in [Builtin::Sqrt, Builtin::Abs, Builtin::Exp, Builtin::Ln, Builtin::Acos, Builtin::Atan, Builtin::Cos, Builtin::Sin, Builtin::Asin] {
                    let r = Range::call(f, &[a], &[None]);
                    check_sound(a, a, |x, _| f.eval(&[x]), r);
                }
            }
        }
    }

    #[test]
    fn a_square_is_never_negative() {
        // The product's corners allow −2·3 = −6; x·x of one value does not.
        let r = Range::new(-2.0, 3.0, false, true).square();
        assert_eq!((r.lo, r.hi, r.negz), (0.0, 9.0, false));
        assert!(r.nonneg());
        assert_eq!(Range::new(-5.0, -0.5, false, false).square(), Range::new(0.25, 25.0, false, false));
    }

    #[test]
    fn clamp_to_unit_is_unit_without_negative_zero() {
        let x = Range::TOP;
        let r = Range::call(Builtin::Clamp, &[Range { nan: false, ..x }, Range::constant(0.0), Range::constant(1.0)], &[None; 3]);
        assert_eq!(r, unit());
        assert!(r.nonneg());
    }

    use proptest::prelude::*;

    fn value() -> impl Strategy<Value = f64> {
        prop_oneof![
            3 => -4.0..4.0f64,
            1 => prop::sample::select(vec![0.0, -0.0, 1.0, -1.0, f64::INFINITY, f64::NEG_INFINITY, 1e-310, 1e300, PI]),
            1 => any::<f64>().prop_filter("not NaN", |v| !v.is_nan()),
        ]
    }

    /// A range and a member of it: an interval from two values, a member between them (or an end point).
    fn member() -> impl Strategy<Value = (Range, f64)> {
        (value(), value(), 0.0..=1.0f64, any::<bool>(), 0..4u8).prop_map(|(a, b, t, nan, pick)| {
            let (lo, hi) = if a <= b { (a, b) } else { (b, a) };
            let mut x = match pick {
                0 => lo,
                1 => hi,
                _ => lo + (hi - lo) * t,
            };
            if !(x >= lo && x <= hi) {
                x = lo;
            }
            let negz = x == 0.0 && x.is_sign_negative() || lo == 0.0 && lo.is_sign_negative() || hi == 0.0 && hi.is_sign_negative();
            let x = if nan && pick == 3 { f64::NAN } else { x };
            (Range::new(lo, hi, nan, negz), x)
        })
    }

    fn inside(r: Range, z: f64) -> bool {
        if z.is_nan() {
            return r.nan;
        }
        z >= r.lo && z <= r.hi && !(z == 0.0 && z.is_sign_negative() && !r.negz)
    }

    proptest! {
        #![proptest_config(ProptestConfig { cases: 3000, ..ProptestConfig::default() })]
        #[test]
        fn ranges_contain_every_result((ra, x) in member(), (rb, y) in member(), (rc, z) in member()) {
            prop_assert!(inside(ra, x) && inside(rb, y));
            prop_assert!(inside(-ra, -x));
            prop_assert!(inside(ra + rb, x + y), "{x} + {y}: {:?}", ra + rb);
            prop_assert!(inside(ra - rb, x - y), "{x} - {y}: {:?}", ra - rb);
            prop_assert!(inside(ra * rb, x * y), "{x} * {y}: {:?}", ra * rb);
            prop_assert!(inside(ra / rb, x / y), "{x} / {y}: {:?}", ra / rb);
            for f in Builtin::ALL {
                let args = [x, y, z];
                let rs = [ra, rb, rc];
                let k = f.arity();
                let konst: Vec<Option<f64>> = (0..k).map(|i| (i == 1 && rb.lo == rb.hi && !rb.nan && !y.is_nan()).then_some(y)).collect();
                let r = Range::call(f, &rs[..k], &konst);
                let v = f.eval(&args[..k]);
                prop_assert!(inside(r, v), "{}({:?}) = {v} outside {r:?} from {:?}", f.name(), &args[..k], &rs[..k]);
            }
        }

        #[test]
        fn pow_ranges_with_constant_exponents(
            (ra, x) in member(),
            k in prop::sample::select(vec![-1025.0, -268.0, -3.0, -2.0, -1.0, -0.5, 0.0, -0.0, 0.5, 1.0, 2.0, 3.0, 7.0, 16.0, 268.0, 1e7, 2.5]),
        ) {
            let r = Range::call(Builtin::Pow, &[ra, Range::constant(k)], &[None, Some(k)]);
            let v = x.powf(k);
            prop_assert!(inside(r, v), "pow({x}, {k}) = {v} outside {r:?} from {ra:?}");
        }
    }
}
