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
