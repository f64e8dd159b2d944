//! One derivative rule per builtin (and per arithmetic operation), written once over [`Build`] so the same
//! rule builds IR nodes (`simplify::derive`, forward accumulation over the arena) or runs on numbers (the unit
//! tests below, against central differences).
//!
//! Shape: a rule is a tangent (forward-mode) rule. Given the arguments `a`, the result `r` and the arguments'
//! tangents `da` (`None`: structurally zero, e.g. a constant or a parameter other than the one derived by), it
//! returns the result's tangent `dr = Σ ∂f/∂aᵢ · daᵢ` (`None` when every term is structurally zero). Writing the
//! whole tangent rather than the partials lets piecewise builtins (min, max, clamp, select, abs) pick the tangent
//! of the branch the value took with a `select`, so an infinite or NaN tangent on the branch not taken never
//! reaches the result (a partial of 0 times an infinite tangent would be NaN).
//!
//! NaN safety. A tangent is *wild* ([`Tangent::wild`]) when it may be ±∞ where the value is finite: the slope
//! of sqrt at 0, of ln at 0, of pow(x, y) in x at x = 0 with y < 1. Every product of a partial and a tangent
//! where either factor may be wild is taken as 0 when the other factor is 0 (0·∞ := 0, see [`scale`]): so
//! `d sqrt(x)` is +∞ at x = 0 only where x truly moves (dx ≠ 0), and 0 where it does not; `x·sqrt(x)` at 0
//! has derivative 0. Products of tame factors are plain multiplications (no guard, no cost).
//!
//! The choices at kinks (stated once, here; `docs/derivatives.md` repeats them for users):
//! - `abs'(0) = 0`;
//! - `min(a, b)`, `max(a, b)`: the tangent of the argument the value took; ties → the first argument;
//! - `clamp(x, lo, hi) = min(max(x, lo), hi)` by those two rules: inside-closed, ∂/∂x = 1 on lo ≤ x ≤ hi;
//! - `select(c, a, b)`: the taken branch's tangent; comparisons (`lt`, `le`, `eq`, `ne`) and `floor` have
//!   derivative 0 everywhere, and nothing flows through a condition;
//! - `acos`, `asin` at |x| ≥ 1 (where the argument clamp binds, and at ±1 itself): 0, never ∞·0 = NaN;
//! - `sqrt` at 0: +∞·dx where dx ≠ 0, else 0 (below 0 the value is NaN and so is the tangent);
//! - `ln` at 0: the same rule (−∞ is the value there);
//! - `pow(x, y)`: ∂/∂x = y·pow(x, y−1) (wild only when y may be < 1), ∂/∂y = pow(x, y)·ln x where x > 0 and
//!   0 where x ≤ 0 (x = 0 gives 0, not 0·(−∞) = NaN; for x < 0, pow is defined only at integer y, where it has
//!   no derivative in y);
//! - `acoslo`, `powlo` (the rounding errors of lobe's acos and pow, formed by the accuracy pass): 0 — the
//!   derivative of the function they correct is carried by the acos or pow term beside them;
//! - `expmuldiv(a, b, c) = exp(a)·b/c`: r·da + expmuldiv(a, db, c) − r·dc/c, every term without the
//!   intermediate under- or overflow the builtin avoids;
//! - `fma(a, b, c)`: b·da + a·db + dc.

use super::Builtin;

/// What a derivative rule builds with: constants, arithmetic, and calls of other builtins (as IR nodes, or
/// as numbers in tests).
pub trait Build {
    type V: Copy;
    fn konst(&mut self, v: f64) -> Self::V;
    /// The value of `v` when it is a constant (rules skip work a constant decides, e.g. pow's wildness).
    fn as_const(&self, v: Self::V) -> Option<f64>;
    fn add(&mut self, a: Self::V, b: Self::V) -> Self::V;
    fn sub(&mut self, a: Self::V, b: Self::V) -> Self::V;
    fn mul(&mut self, a: Self::V, b: Self::V) -> Self::V;
    fn div(&mut self, a: Self::V, b: Self::V) -> Self::V;
    fn neg(&mut self, a: Self::V) -> Self::V;
    fn call(&mut self, f: Builtin, args: &[Self::V]) -> Self::V;
}

/// A tangent (the derivative of a value with respect to the one variable derived by) and whether it may be
/// ±∞ where the value is finite (module doc).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Tangent<V> {
    pub v: V,
    pub wild: bool,
}

impl<V> Tangent<V> {
    pub fn tame(v: V) -> Tangent<V> {
        Tangent { v, wild: false }
    }
}

type T<B> = Option<Tangent<<B as Build>::V>>;

/// `p · t` for a partial `p` (`p_wild`: may be ±∞ where the value is finite), with 0·∞ := 0 where either
/// factor may be infinite.
pub fn scale<B: Build>(b: &mut B, p: B::V, p_wild: bool, t: Tangent<B::V>) -> Tangent<B::V> {
    let prod = b.mul(p, t.v);
    let zero = b.konst(0.0);
    let mut v = prod;
    if t.wild {
        // p = 0: the product is 0 even where t is infinite.
        let nz = b.call(Builtin::Ne, &[p, zero]);
        v = b.call(Builtin::Select, &[nz, v, zero]);
    }
    if p_wild {
        let nz = b.call(Builtin::Ne, &[t.v, zero]);
        v = b.call(Builtin::Select, &[nz, v, zero]);
    }
    Tangent { v, wild: t.wild || p_wild }
}

/// `x + y` of optional tangents.
pub fn sum<B: Build>(b: &mut B, x: T<B>, y: T<B>) -> T<B> {
    match (x, y) {
        (None, t) | (t, None) => t,
        (Some(x), Some(y)) => Some(Tangent { v: b.add(x.v, y.v), wild: x.wild || y.wild }),
    }
}

fn scale_opt<B: Build>(b: &mut B, p: B::V, p_wild: bool, t: T<B>) -> T<B> {
    t.map(|t| scale(b, p, p_wild, t))
}

/// The tangent of the branch `c` takes (`c` non-zero: `x`, else `y`); `None` when both are zero.
fn pick<B: Build>(b: &mut B, c: B::V, x: T<B>, y: T<B>) -> T<B> {
    if x.is_none() && y.is_none() {
        return None;
    }
    let zero = b.konst(0.0);
    let (xv, yv) = (x.map_or(zero, |t| t.v), y.map_or(zero, |t| t.v));
    let wild = x.is_some_and(|t| t.wild) || y.is_some_and(|t| t.wild);
    Some(Tangent { v: b.call(Builtin::Select, &[c, xv, yv]), wild })
}

/// −a.
pub fn neg<B: Build>(b: &mut B, da: T<B>) -> T<B> {
    da.map(|t| Tangent { v: b.neg(t.v), wild: t.wild })
}

/// a + b.
pub fn add<B: Build>(b: &mut B, da: T<B>, db: T<B>) -> T<B> {
    sum(b, da, db)
}

/// a − b.
pub fn sub<B: Build>(b: &mut B, da: T<B>, db: T<B>) -> T<B> {
    let nb = neg(b, db);
    sum(b, da, nb)
}

/// a·b: b·da + a·db.
pub fn mul<B: Build>(b: &mut B, x: B::V, y: B::V, dx: T<B>, dy: T<B>) -> T<B> {
    let t1 = scale_opt(b, y, false, dx);
    let t2 = scale_opt(b, x, false, dy);
    sum(b, t1, t2)
}

/// r = a/b: (da − r·db)/b. A divisor that is not a non-zero constant may be 0 (a pole: r = ±∞ and the
/// tangent ±∞), which a later division can turn back into a finite value (x/(c/0) = 0): so the quotient and
/// the tangent count as wild there, r·db is 0 where db is, and a zero numerator gives a zero tangent (not 0/0).
pub fn div<B: Build>(b: &mut B, y: B::V, r: B::V, dx: T<B>, dy: T<B>) -> T<B> {
    let pole = b.as_const(y).is_none_or(|c| c == 0.0);
    let rdy = scale_opt(b, r, pole, dy);
    let num = sub(b, dx, rdy)?;
    let q = b.div(num.v, y);
    if !pole {
        return Some(Tangent { v: q, wild: num.wild });
    }
    let zero = b.konst(0.0);
    let nz = b.call(Builtin::Ne, &[num.v, zero]);
    Some(Tangent { v: b.call(Builtin::Select, &[nz, q, zero]), wild: true })
}

/// The tangent of `f(args) = r` given the arguments' tangents `d` (module doc; the kink choices are listed
/// there). `args` and `d` have exactly `f.arity()` entries.
pub fn tangent<B: Build>(f: Builtin, b: &mut B, args: &[B::V], r: B::V, d: &[T<B>]) -> T<B> {
    if d.iter().all(Option::is_none) {
        return None;
    }
    let x = args[0];
    let dx = d[0];
    match f {
        Builtin::Pow => {
            let y = args[1];
            let tx = match dx {
                None => None,
                Some(t) => {
                    let one = b.konst(1.0);
                    let ym1 = b.sub(y, one);
                    let pw = b.call(Builtin::Pow, &[x, ym1]);
                    let p = b.mul(y, pw);
                    // y ≥ 1 (a constant) keeps y·x^(y−1) finite at x = 0.
                    let wild = b.as_const(y).is_none_or(|c| c < 1.0);
                    Some(scale(b, p, wild, t))
                }
            };
            let ty = match d[1] {
                None => None,
                Some(t) => {
                    let zero = b.konst(0.0);
                    let ln = b.call(Builtin::Ln, &[x]);
                    let rl = b.mul(r, ln);
                    let pos = b.call(Builtin::Lt, &[zero, x]);
                    let p = b.call(Builtin::Select, &[pos, rl, zero]);
                    Some(scale(b, p, false, t))
                }
            };
            sum(b, tx, ty)
        }
        Builtin::Cos => {
            let s = b.call(Builtin::Sin, &[x]);
            let p = b.neg(s);
            scale_opt(b, p, false, dx)
        }
        Builtin::Sin | Builtin::SinNear => {
            let p = b.call(Builtin::Cos, &[x]);
            scale_opt(b, p, false, dx)
        }
        Builtin::Tan => {
            // 1 + tan²x
            let one = b.konst(1.0);
            let r2 = b.mul(r, r);
            let p = b.add(one, r2);
            scale_opt(b, p, false, dx)
        }
        Builtin::Acos | Builtin::Asin => {
            // ∓1/sqrt((1 − x)(1 + x)) inside (−1, 1), 0 where the clamp binds and at ±1.
            let one = b.konst(1.0);
            let zero = b.konst(0.0);
            let a = b.sub(one, x);
            let c = b.add(one, x);
            let q = b.mul(a, c);
            let s = b.call(Builtin::Sqrt, &[q]);
            let num = b.konst(if f == Builtin::Acos { -1.0 } else { 1.0 });
            let p = b.div(num, s);
            let ax = b.call(Builtin::Abs, &[x]);
            let inside = b.call(Builtin::Lt, &[ax, one]);
            let p = b.call(Builtin::Select, &[inside, p, zero]);
            scale_opt(b, p, false, dx)
        }
        Builtin::Atan => {
            let one = b.konst(1.0);
            let x2 = b.mul(x, x);
            let q = b.add(one, x2);
            let p = b.div(one, q);
            scale_opt(b, p, false, dx)
        }
        Builtin::Exp => scale_opt(b, r, false, dx),
        Builtin::Ln => {
            let one = b.konst(1.0);
            let p = b.div(one, x);
            scale_opt(b, p, true, dx)
        }
        Builtin::Sqrt => {
            let half = b.konst(0.5);
            let p = b.div(half, r);
            scale_opt(b, p, true, dx)
        }
        Builtin::Abs => {
            // sign(x), with abs'(0) = 0: lt(0, x) − lt(x, 0).
            let zero = b.konst(0.0);
            let pos = b.call(Builtin::Lt, &[zero, x]);
            let negv = b.call(Builtin::Lt, &[x, zero]);
            let p = b.sub(pos, negv);
            scale_opt(b, p, false, dx)
        }
        Builtin::Min => {
            // The value is a where a ≤ b (ties → the first argument).
            let c = b.call(Builtin::Le, &[x, args[1]]);
            pick(b, c, dx, d[1])
        }
        Builtin::Max => {
            let c = b.call(Builtin::Le, &[args[1], x]);
            pick(b, c, dx, d[1])
        }
        Builtin::Clamp => {
            // min(max(x, lo), hi) by the max and min rules.
            let (lo, hi) = (args[1], args[2]);
            let m = b.call(Builtin::Max, &[x, lo]);
            let dm = tangent(Builtin::Max, b, &[x, lo], m, &[dx, d[1]]);
            tangent(Builtin::Min, b, &[m, hi], r, &[dm, d[2]])
        }
        Builtin::Floor | Builtin::Lt | Builtin::Le | Builtin::Eq | Builtin::Ne => None,
        Builtin::Select => {
            let zero = b.konst(0.0);
            let c = b.call(Builtin::Ne, &[x, zero]);
            pick(b, c, d[1], d[2])
        }
        Builtin::Fma => {
            let t1 = scale_opt(b, args[1], false, dx);
            let t2 = scale_opt(b, x, false, d[1]);
            let t = sum(b, t1, t2);
            sum(b, t, d[2])
        }
        Builtin::ExpMulDiv => {
            // ∂a = r, ∂b = exp(a)/c = expmuldiv(a, 1, c), ∂c = −r/c.
            let c = args[2];
            let ta = scale_opt(b, r, false, dx);
            let tb = match d[1] {
                None => None,
                Some(t) => {
                    let one = b.konst(1.0);
                    let p = b.call(Builtin::ExpMulDiv, &[x, one, c]);
                    Some(scale(b, p, false, t))
                }
            };
            let tc = match d[2] {
                None => None,
                Some(t) => {
                    let rc = b.div(r, c);
                    let p = b.neg(rc);
                    Some(scale(b, p, false, t))
                }
            };
            let t = sum(b, ta, tb);
            sum(b, t, tc)
        }
        Builtin::AcosLo | Builtin::PowLo => None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::base::rng::Rng;

    /// Numbers: a rule run on f64 values, for the finite-difference checks.
    struct Num;

    impl Build for Num {
        type V = f64;
        fn konst(&mut self, v: f64) -> f64 {
            v
        }
        fn as_const(&self, _: f64) -> Option<f64> {
            None
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
        fn call(&mut self, f: Builtin, args: &[f64]) -> f64 {
            f.eval(args)
        }
    }

    /// ∂f/∂a_k at `args` by the rule (unit tangent in slot k).
    fn rule(f: Builtin, args: &[f64], k: usize) -> f64 {
        let r = f.eval(args);
        let d: Vec<Option<Tangent<f64>>> = (0..args.len()).map(|i| (i == k).then_some(Tangent::tame(1.0))).collect();
        tangent(f, &mut Num, args, r, &d).map_or(0.0, |t| t.v)
    }

    /// Central difference in slot k, step h·max(1, |a_k|).
    fn central(f: Builtin, args: &[f64], k: usize) -> f64 {
        let h = 1e-6 * args[k].abs().max(1.0);
        let (mut p, mut m) = (args.to_vec(), args.to_vec());
        p[k] += h;
        m[k] -= h;
        (f.eval(&p) - f.eval(&m)) / (p[k] - m[k])
    }

    /// Random arguments well inside each builtin's smooth region.
    fn point(f: Builtin, g: &mut Rng) -> Vec<f64> {
        let mut u = |lo: f64, hi: f64| lo + (hi - lo) * g.unit();
        match f {
            Builtin::Pow | Builtin::PowLo => vec![u(0.1, 3.0), u(-2.5, 2.5)],
            Builtin::Acos | Builtin::Asin | Builtin::AcosLo => vec![u(-0.95, 0.95)],
            Builtin::Tan => vec![u(-1.3, 1.3)],
            Builtin::SinNear => vec![u(-1.7, 1.7)],
            Builtin::Ln | Builtin::Sqrt => vec![u(0.05, 10.0)],
            Builtin::Exp => vec![u(-20.0, 20.0)],
            Builtin::ExpMulDiv => vec![u(-700.0, -600.0), u(-3.0, 3.0), u(0.5, 4.0)],
            Builtin::Clamp => {
                let lo = u(-1.0, 0.0);
                vec![u(-2.0, 2.0), lo, lo + u(0.5, 2.0)]
            }
            Builtin::Floor => vec![u(-5.0, 5.0)],
            Builtin::Select => vec![if u(0.0, 1.0) < 0.5 { 0.0 } else { u(0.5, 2.0) }, u(-3.0, 3.0), u(-3.0, 3.0)],
            _ => (0..f.arity()).map(|_| u(-3.0, 3.0)).collect(),
        }
    }

    /// Whether the central difference at `args` in slot k straddles a kink (a point the test skips).
    fn near_kink(f: Builtin, a: &[f64], k: usize) -> bool {
        let h = 1e-4 * a.iter().fold(1.0f64, |m, x| m.max(x.abs()));
        let close = |x: f64, y: f64| (x - y).abs() < h;
        match f {
            Builtin::Abs => close(a[0], 0.0),
            Builtin::Min | Builtin::Max | Builtin::Lt | Builtin::Le | Builtin::Eq | Builtin::Ne => close(a[0], a[1]),
            Builtin::Clamp => close(a[0], a[1]) || close(a[0], a[2]),
            Builtin::Floor => close(a[0], a[0].round()),
            // The condition's derivative is 0 except across c = 0.
            Builtin::Select => k == 0 && a[0] == 0.0,
            _ => false,
        }
    }

    #[test]
    fn every_rule_matches_central_differences() {
        let mut g = Rng(48);
        for f in Builtin::ALL {
            let mut checked = 0;
            for _ in 0..200 {
                let args = point(f, &mut g);
                for k in 0..f.arity() {
                    if near_kink(f, &args, k) {
                        continue;
                    }
                    let want = central(f, &args, k);
                    let got = rule(f, &args, k);
                    assert!(got.is_finite(), "{f}{args:?} ∂{k}: {got}");
                    // The difference's truncation (h² · f''') and rounding (ulp/h) errors, relative to the
                    // derivative's scale.
                    let scale = want.abs().max(f.eval(&args).abs() * 1e-3).max(1e-12);
                    let tol = if matches!(f, Builtin::AcosLo | Builtin::PowLo) { 1e-8 } else { 1e-6 * scale };
                    assert!((got - want).abs() <= tol, "{f}{args:?} ∂{k}: rule {got}, central {want}");
                    checked += 1;
                }
            }
            assert!(checked >= 90 * f.arity(), "{f}: only {checked} checks");
        }
    }

    #[test]
    fn kinks_take_the_documented_values() {
        let one = |f: Builtin, a: &[f64], k: usize| rule(f, a, k);
        assert_eq!(one(Builtin::Abs, &[0.0], 0), 0.0);
        assert_eq!(one(Builtin::Abs, &[-2.0], 0), -1.0);
        // Ties go to the first argument.
        assert_eq!((one(Builtin::Min, &[1.0, 1.0], 0), one(Builtin::Min, &[1.0, 1.0], 1)), (1.0, 0.0));
        assert_eq!((one(Builtin::Max, &[1.0, 1.0], 0), one(Builtin::Max, &[1.0, 1.0], 1)), (1.0, 0.0));
        // clamp is inside-closed.
        for x in [0.0, 0.5, 1.0] {
            assert_eq!(one(Builtin::Clamp, &[x, 0.0, 1.0], 0), 1.0, "clamp at {x}");
        }
        assert_eq!(one(Builtin::Clamp, &[1.5, 0.0, 1.0], 0), 0.0);
        assert_eq!(one(Builtin::Clamp, &[1.5, 0.0, 1.0], 2), 1.0);
        assert_eq!(one(Builtin::Clamp, &[-1.5, 0.0, 1.0], 1), 1.0);
        // acos and asin at and beyond ±1: 0, not ∞ or NaN.
        for x in [1.0, -1.0, 1.5, -3.0] {
            assert_eq!(one(Builtin::Acos, &[x], 0), 0.0, "acos'({x})");
            assert_eq!(one(Builtin::Asin, &[x], 0), 0.0, "asin'({x})");
        }
        // sqrt at 0: +∞ where the argument moves, 0 where it does not.
        assert_eq!(one(Builtin::Sqrt, &[0.0], 0), f64::INFINITY);
        let r = Builtin::Sqrt.eval(&[0.0]);
        let still = tangent(Builtin::Sqrt, &mut Num, &[0.0], r, &[Some(Tangent::tame(0.0))]).unwrap();
        assert_eq!((still.v, still.wild), (0.0, true));
        // pow at x = 0: ∂y is 0 (not 0·ln 0 = NaN); ∂x is y·0^(y−1).
        assert_eq!(one(Builtin::Pow, &[0.0, 2.5], 1), 0.0);
        assert_eq!(one(Builtin::Pow, &[0.0, 2.5], 0), 0.0);
        assert_eq!(one(Builtin::Pow, &[0.0, 1.0], 0), 1.0);
        assert_eq!(one(Builtin::Pow, &[-2.0, 3.0], 1), 0.0);
        // select: the taken branch only, even when the other's tangent is NaN.
        let r = Builtin::Select.eval(&[1.0, 2.0, 3.0]);
        let d = [None, Some(Tangent::tame(5.0)), Some(Tangent::tame(f64::NAN))];
        assert_eq!(tangent(Builtin::Select, &mut Num, &[1.0, 2.0, 3.0], r, &d).unwrap().v, 5.0);
        for f in [Builtin::Floor, Builtin::Lt, Builtin::Le, Builtin::Eq, Builtin::Ne] {
            let a = vec![0.3; f.arity()];
            assert_eq!(one(f, &a, 0), 0.0, "{f}");
        }
    }

    #[test]
    fn a_zero_partial_times_an_infinite_tangent_is_zero() {
        // x·sqrt(x) at 0: the product rule's x·d(sqrt x) is 0·∞, taken as 0.
        let s = Builtin::Sqrt.eval(&[0.0]);
        let ds = tangent(Builtin::Sqrt, &mut Num, &[0.0], s, &[Some(Tangent::tame(1.0))]);
        let d = mul(&mut Num, 0.0, s, Some(Tangent::tame(1.0)), ds).unwrap();
        assert_eq!(d.v, 0.0);
        // x/(c/u) at u = 0 where u does not move (a clamp holds it): c/u = −∞, the value −0, the derivative 0.
        let u = 0.0;
        let w = -7.5 / u;
        let dw = div(&mut Num, u, w, None, Some(Tangent::tame(0.0)));
        assert_eq!(dw.map(|t| t.v), Some(0.0));
        let d = div(&mut Num, w, 0.3 / w, Some(Tangent::tame(1.0)), dw).unwrap();
        assert_eq!(d.v, 0.0);
        // t/(v/0) with v moving: the inner tangent is ∞, times the quotient 0 is 0.
        let dw = div(&mut Num, u, 1.0 / u, Some(Tangent::tame(1.0)), Some(Tangent::tame(0.0))).unwrap();
        assert_eq!((dw.v, dw.wild), (f64::INFINITY, true));
        let r = 0.3 / (1.0 / u);
        assert_eq!(div(&mut Num, 1.0 / u, r, None, Some(dw)).unwrap().v, 0.0);
        // exp(sqrt x) at 0 moves infinitely fast: +∞, not NaN.
        let e = Builtin::Exp.eval(&[s]);
        assert_eq!(tangent(Builtin::Exp, &mut Num, &[s], e, &[ds]).unwrap().v, f64::INFINITY);
    }
}
