//! Double-double arithmetic, written once over [`Arith`] (every [`super::math::Emit`] is one): the same code
//! runs on plain `f64` ([`Direct`]: the truth evaluator), inside the math library's builtins (interpreted and
//! JIT-compiled), and as IR nodes (the accuracy pass builds its 2Sum, Fast2Sum and 2Prod terms through the IR
//! emitter `simplify::emit`). A double-double is a pair `(hi, lo)` whose unevaluated sum is the value.
//!
//! The error-free transformations come in two forms: `two_sum(a, b)` returns `(s, err)`, and `two_sum_err(a,
//! b, s)` only the error of an `s = a + b` the caller already has (an IR rewrite whose sum node exists).
//! Everything here is IEEE arithmetic in a fixed order, so a value is the same bits on every emitter.
//!
//! [`Direct`]: super::math::Direct

/// The IEEE arithmetic subset of [`Emit`](super::math::Emit): what every emitter has, including one that builds IR nodes (which
/// has no bit-level operations). Double-double arithmetic (this module) and the shading frame's input
/// formulas are written over it; every [`Emit`](super::math::Emit) is an `Arith` with the same operations.
pub trait Arith {
    type V: Copy;
    fn konst(&mut self, c: f64) -> Self::V;
    fn add(&mut self, a: Self::V, b: Self::V) -> Self::V;
    fn sub(&mut self, a: Self::V, b: Self::V) -> Self::V;
    fn mul(&mut self, a: Self::V, b: Self::V) -> Self::V;
    fn div(&mut self, a: Self::V, b: Self::V) -> Self::V;
    fn neg(&mut self, a: Self::V) -> Self::V;
    fn sqrt(&mut self, a: Self::V) -> Self::V;
    /// `a·b + c` rounded once.
    fn fma(&mut self, a: Self::V, b: Self::V, c: Self::V) -> Self::V;
    /// `c > 0 ? a : b` (`b` for a NaN `c`); both values are computed.
    fn positive_select(&mut self, c: Self::V, a: Self::V, b: Self::V) -> Self::V;
    /// The value of `v` when the emitter knows it before run time (an IR constant); `None` by default. Lets
    /// [`partial`] arithmetic skip a product by 1 and scale by a power of two exactly.
    fn known(&self, _v: Self::V) -> Option<f64> {
        None
    }
    /// `a·b` as `(p, err)`, exactly (`err = fma(a, b, −p)`; a target without a hardware FMA may use Dekker's product instead, the same exact value).
    fn two_prod(&mut self, a: Self::V, b: Self::V) -> (Self::V, Self::V)
    where
        Self: Sized,
    {
        let p = self.mul(a, b);
        (p, two_prod_err(self, a, b, p))
    }
}



/// `a + b` as an unevaluated sum `(s, err)`, exactly (Knuth's 2Sum, no magnitude condition).
pub(crate) fn two_sum<E: Arith>(e: &mut E, a: E::V, b: E::V) -> (E::V, E::V) {
    let s = e.add(a, b);
    (s, two_sum_err(e, a, b, s))
}

/// The exact error `a + b − s` of `s = fl(a + b)`, whatever the magnitudes (Knuth's 2Sum: five operations).
pub(crate) fn two_sum_err<E: Arith>(e: &mut E, a: E::V, b: E::V, s: E::V) -> E::V {
    let bb = e.sub(s, a);
    let ab = e.sub(s, bb);
    let da = e.sub(a, ab);
    let db = e.sub(b, bb);
    e.add(da, db)
}

/// `a + b` exactly when |a| ≥ |b| (Dekker's Fast2Sum), as `(s, err)`; also the renormalisation of a
/// double-double whose parts may overlap.
pub(crate) fn fast_two_sum<E: Arith>(e: &mut E, a: E::V, b: E::V) -> (E::V, E::V) {
    let s = e.add(a, b);
    (s, fast_two_sum_err(e, a, b, s))
}

/// The exact error `a + b − s` of `s = fl(a + b)` when |a| ≥ |b| (two operations).
pub(crate) fn fast_two_sum_err<E: Arith>(e: &mut E, a: E::V, b: E::V, s: E::V) -> E::V {
    let t = e.sub(s, a);
    e.sub(b, t)
}

/// The exact error `a·b − p` of `p = fl(a·b)` by one fused multiply-add (for products that do not underflow).
/// [`Arith::two_prod`] is this unless the target lacks an FMA, where it may use [`dekker_two_prod`].
pub(crate) fn two_prod_err<E: Arith>(e: &mut E, a: E::V, b: E::V, p: E::V) -> E::V {
    let np = e.neg(p);
    e.fma(a, b, np)
}

/// Veltkamp's split: `a = hi + lo` with 26-bit halves (|a| < 2^996).
pub(crate) fn split<E: Arith>(e: &mut E, a: E::V) -> (E::V, E::V) {
    let k = e.konst(134217729.0);
    let c = e.mul(a, k);
    let d = e.sub(c, a);
    let hi = e.sub(c, d);
    (hi, e.sub(a, hi))
}

/// `a·b` as `(p, err)` exactly (Dekker's product, no FMA), for operands whose product does not underflow.
pub(crate) fn dekker_two_prod<E: Arith>(e: &mut E, a: E::V, b: E::V) -> (E::V, E::V) {
    let p = e.mul(a, b);
    let (ah, al) = split(e, a);
    let (bh, bl) = split(e, b);
    let hh = e.mul(ah, bh);
    let t = e.sub(hh, p);
    let hl = e.mul(ah, bl);
    let t = e.add(t, hl);
    let lh = e.mul(al, bh);
    let t = e.add(t, lh);
    let ll = e.mul(al, bl);
    (p, e.add(t, ll))
}

/// A double-double value.
pub(crate) type Dd<V> = (V, V);

/// `a + b` (the accurate sum: both parts by 2Sum, renormalised twice; QD's `ieee_add`).
pub(crate) fn add<E: Arith>(e: &mut E, a: Dd<E::V>, b: Dd<E::V>) -> Dd<E::V> {
    let (s1, s2) = two_sum(e, a.0, b.0);
    let (t1, t2) = two_sum(e, a.1, b.1);
    let s2 = e.add(s2, t1);
    let (s1, s2) = fast_two_sum(e, s1, s2);
    let s2 = e.add(s2, t2);
    fast_two_sum(e, s1, s2)
}

/// `−a`.
pub(crate) fn neg<E: Arith>(e: &mut E, a: Dd<E::V>) -> Dd<E::V> {
    (e.neg(a.0), e.neg(a.1))
}

/// `a·b`: the heads' exact product plus the cross terms (the tails' product is below the precision).
pub(crate) fn mul<E: Arith>(e: &mut E, a: Dd<E::V>, b: Dd<E::V>) -> Dd<E::V> {
    let (p, err) = e.two_prod(a.0, b.0);
    let x = e.mul(a.0, b.1);
    let y = e.mul(a.1, b.0);
    let cross = e.add(x, y);
    let lo = e.add(err, cross);
    fast_two_sum(e, p, lo)
}

/// `a/b`: three quotient digits, each from the exact remainder of the previous ones.
pub(crate) fn div<E: Arith>(e: &mut E, a: Dd<E::V>, b: Dd<E::V>) -> Dd<E::V> {
    let zero = e.konst(0.0);
    let q1 = e.div(a.0, b.0);
    let m = mul(e, (q1, zero), b);
    let m = neg(e, m);
    let r = add(e, a, m);
    let q2 = e.div(r.0, b.0);
    let m = mul(e, (q2, zero), b);
    let m = neg(e, m);
    let r = add(e, r, m);
    let q3 = e.div(r.0, b.0);
    let q = fast_two_sum(e, q1, q2);
    add(e, q, (q3, zero))
}

/// `√a` for a > 0: libm's root corrected by one Newton step on the exact remainder.
pub(crate) fn sqrt<E: Arith>(e: &mut E, a: Dd<E::V>) -> Dd<E::V> {
    let s = e.sqrt(a.0);
    let (p, err) = e.two_prod(s, s);
    let r = e.sub(a.0, p);
    let r = e.sub(r, err);
    let r = e.add(r, a.1);
    let two = e.konst(2.0);
    let two_s = e.mul(two, s);
    let lo = e.div(r, two_s);
    fast_two_sum(e, s, lo)
}

/// Double-doubles whose low part may be absent (an exact head): the accuracy pass's coefficient arithmetic on IR
/// nodes, where a missing part saves the nodes that would carry a zero. Cheaper than the accurate operations
/// above (one 2Sum or 2Prod per operation, the low parts added in plainly, then one Fast2Sum renormalisation):
/// what parameter-only coefficients need, where the low parts are already ~2⁻⁵³ of the heads.
pub(crate) mod partial {
    use super::{fast_two_sum, two_sum_err, Arith};

    /// `hi + lo` (`lo: None` when `hi` is exact).
    #[derive(Clone, Copy, Debug, PartialEq, Eq)]
    pub(crate) struct Dd<V> {
        pub(crate) hi: V,
        pub(crate) lo: Option<V>,
    }

    impl<V> Dd<V> {
        /// An exact value.
        pub(crate) fn exact(hi: V) -> Dd<V> {
            Dd { hi, lo: None }
        }
    }

    fn add_opt<E: Arith>(e: &mut E, a: Option<E::V>, b: Option<E::V>) -> Option<E::V> {
        match (a, b) {
            (Some(a), Some(b)) => Some(e.add(a, b)),
            (a, b) => a.or(b),
        }
    }

    /// `hi + lo` renormalised (Fast2Sum: |hi| ≥ |lo| up to the coefficient arithmetic's own cancellations,
    /// where the sum is exact anyway).
    pub(crate) fn norm<E: Arith>(e: &mut E, hi: E::V, lo: Option<E::V>) -> Dd<E::V> {
        let Some(lo) = lo else { return Dd::exact(hi) };
        let (hi, lo) = fast_two_sum(e, hi, lo);
        Dd { hi, lo: Some(lo) }
    }

    pub(crate) fn neg<E: Arith>(e: &mut E, a: Dd<E::V>) -> Dd<E::V> {
        Dd { hi: e.neg(a.hi), lo: a.lo.map(|l| e.neg(l)) }
    }

    /// `a + b`: the heads' 2Sum, its error and the low parts added, renormalised.
    pub(crate) fn add<E: Arith>(e: &mut E, a: Dd<E::V>, b: Dd<E::V>) -> Dd<E::V> {
        let s = e.add(a.hi, b.hi);
        let err = two_sum_err(e, a.hi, b.hi, s);
        let lo = add_opt(e, a.lo, b.lo);
        let lo = add_opt(e, Some(err), lo);
        norm(e, s, lo)
    }

    fn is_one<E: Arith>(e: &E, a: Dd<E::V>) -> bool {
        a.lo.is_none() && e.known(a.hi) == Some(1.0)
    }

    /// `a·b`: the heads' 2Prod and the cross terms by fma; by an exact 1 nothing, by an exact power of two the
    /// parts scaled (exact: no underflow in a parameter's coefficient).
    pub(crate) fn mul<E: Arith>(e: &mut E, a: Dd<E::V>, b: Dd<E::V>) -> Dd<E::V> {
        if is_one(e, a) {
            return b;
        }
        if is_one(e, b) {
            return a;
        }
        let pow2 = |e: &E, x: Dd<E::V>| x.lo.is_none() && e.known(x.hi).is_some_and(|c| c != 0.0 && c.abs().log2().fract() == 0.0);
        if pow2(e, a) || pow2(e, b) {
            let (a, b) = if pow2(e, b) { (a, b) } else { (b, a) };
            let hi = e.mul(a.hi, b.hi);
            return Dd { hi, lo: a.lo.map(|l| e.mul(l, b.hi)) };
        }
        let (p, mut err) = e.two_prod(a.hi, b.hi);
        if let Some(bl) = b.lo {
            err = e.fma(a.hi, bl, err);
        }
        if let Some(al) = a.lo {
            err = e.fma(al, b.hi, err);
        }
        norm(e, p, Some(err))
    }

    /// `a/b`: the quotient's exact remainder (fma) and the operands' low parts, over `b`.
    pub(crate) fn div<E: Arith>(e: &mut E, a: Dd<E::V>, b: Dd<E::V>) -> Dd<E::V> {
        if is_one(e, b) {
            return a;
        }
        let q = e.div(a.hi, b.hi);
        let nq = e.neg(q);
        let mut r = e.fma(nq, b.hi, a.hi);
        if let Some(al) = a.lo {
            r = e.add(r, al);
        }
        if let Some(bl) = b.lo {
            r = e.fma(nq, bl, r);
        }
        let lo = e.div(r, b.hi);
        norm(e, q, Some(lo))
    }

    #[cfg(test)]
    mod tests {
        use super::*;
        use crate::builtins::math::Direct;

        /// On plain f64 the partial operations carry what the heads lose: 1/3·3 and 0.1 + 0.2 within 2⁻¹⁰⁰.
        #[test]
        fn partial_double_doubles_carry_the_rounding() {
            let e = &mut Direct;
            let third = div(e, Dd::exact(1.0), Dd::exact(3.0));
            let one = mul(e, third, Dd::exact(3.0));
            assert_eq!(one.hi, 1.0);
            assert!(one.lo.unwrap().abs() < 2f64.powi(-100), "{one:?}");
            let s = add(e, Dd::exact(0.1), Dd::exact(0.2));
            // 0.1 + 0.2 in f64 is 0.30000000000000004; the exact sum of the two doubles is below it by 2.8e-17.
            assert_eq!(s.hi, 0.30000000000000004);
            assert!((s.lo.unwrap() + 2.7755575615628914e-17).abs() < 1e-32, "{s:?}");
            assert_eq!(neg(e, s).hi, -s.hi);
        }
    }
}
