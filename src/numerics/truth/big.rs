//! The truth at a chosen precision: the formula evaluated again with `dashu-float`'s correctly rounded arithmetic
//! and transcendentals at p bits, where the double-double's bound ([`super::bound`]) says its value is not
//! settled. The same semantics as the double-double truth (`super::call`): IEEE special values, clamped
//! `acos`/`asin`, C99's `pow`, steps decided on f64s; special values (±0, ±∞, NaN) are carried as f64s beside the
//! finite nonzero numbers, and a function of a special value is the double-double's (exact: 1, 0, ±∞, NaN, π/2).
//!
//! The exponent of a dashu number is an `isize`: values beyond 2^(±2⁶²) are out of reach, and an exponential of an
//! argument beyond ±2⁶² keeps the double-double's saturation (the truth's module docs; the double-double saturates
//! from ±2⁵², and its bound sends the arguments in between here). An operation dashu refuses
//! (an infinite input it does not take, a result past its exponent range) ends the evaluation with no value: the
//! caller keeps the double-double's.

use super::bound;
use super::Xf;
use crate::builtins::Builtin;
use crate::ir::{BinOp, Formula, Node, N_INPUTS};
use dashu_float::math::cache::ConstCache;
use dashu_float::round::{mode::HalfEven, Rounded};
use dashu_float::{Context, FBig, Repr};
use dashu_int::IBig;
use dashu_base::{BitTest, UnsignedAbs};
use std::cell::RefCell;
use std::cmp::Ordering;
use std::ops::Mul;

type F = FBig<HalfEven, 2>;

thread_local! {
    /// π and ln 2 at the precisions asked so far, per thread.
    static CONSTS: RefCell<ConstCache> = const { RefCell::new(ConstCache::new()) };
}

/// A value: a special one (±0, ±∞, NaN) as the f64, or a finite nonzero number.
#[derive(Clone, Debug)]
enum V {
    S(f64),
    N(Repr<2>),
}

/// (sign·mantissa, exponent) of a finite nonzero f64: the value is m·2^e exactly.
fn decode(x: f64) -> (i64, i64) {
    let bits = x.to_bits();
    let field = ((bits >> 52) & 0x7ff) as i64;
    let frac = (bits & ((1u64 << 52) - 1)) as i64;
    let (m, e) = if field == 0 { (frac, -1074) } else { (frac | (1i64 << 52), field - 1075) };
    (if x < 0.0 { -m } else { m }, e)
}

fn from_xf(x: Xf) -> V {
    let (hi, lo, e) = x.parts();
    if hi == 0.0 || !hi.is_finite() {
        return V::S(hi);
    }
    let (mh, eh) = decode(hi);
    if lo == 0.0 {
        return V::N(Repr::new(IBig::from(mh), (eh + e) as isize));
    }
    let (ml, el) = decode(lo);
    // hi + lo = (mh·2^(eh − el) + ml)·2^el; lo is below hi, so eh ≥ el.
    let sig = (IBig::from(mh) << (eh - el) as usize) + IBig::from(ml);
    V::N(Repr::new(sig, (el + e) as isize))
}

/// Rounded to the nearest 106-bit number, as an [`Xf`].
fn to_xf(v: &V) -> Xf {
    match v {
        V::S(s) => Xf::from_f64(*s),
        V::N(r) => {
            let r = match F::from_repr_const(r.clone()).with_precision(106) {
                Rounded::Exact(x) | Rounded::Inexact(x, _) => x.into_repr(),
            };
            let sig = r.significand();
            let negative = sig < &IBig::ZERO;
            let mag = u128::try_from(sig.unsigned_abs()).expect("106 bits fit a u128");
            let (q, rem) = ((mag >> 53) as f64, (mag & ((1u128 << 53) - 1)) as f64);
            let (q, rem) = if negative { (-q, -rem) } else { (q, rem) };
            Xf::make((q * 9007199254740992.0, rem), r.exponent() as i64)
        }
    }
}

fn to_f64(v: &V) -> f64 {
    to_xf(v).to_f64()
}

/// The sign of a value as ±1 (a finite nonzero one) or the special value itself: what IEEE arithmetic with a
/// special operand depends on.
fn signum(v: &V) -> f64 {
    match v {
        V::S(s) => *s,
        V::N(r) => {
            if r.significand() < &IBig::ZERO {
                -1.0
            } else {
                1.0
            }
        }
    }
}

/// The arithmetic at one precision.
struct Eval {
    ctx: Context<HalfEven>,
}

/// A dashu result as a value and its exactness; `None` when dashu refuses.
fn done(r: Result<Rounded<F>, dashu_float::math::FpError>) -> Option<(V, bool)> {
    let (x, exact) = match r.ok()? {
        Rounded::Exact(x) => (x, true),
        Rounded::Inexact(x, _) => (x, false),
    };
    let repr = x.into_repr();
    if repr.is_infinite() {
        return None;
    }
    if repr.significand() == &IBig::ZERO {
        // dashu's zero: an exact cancellation (+0, as IEEE) or an underflow past its exponent.
        return if exact { Some((V::S(0.0), true)) } else { None };
    }
    Some((V::N(repr), exact))
}

impl Eval {
    fn add(&self, a: &V, b: &V) -> Option<(V, bool)> {
        match (a, b) {
            (V::N(x), V::N(y)) => done(self.ctx.add(x, y)),
            (V::S(z), other) | (other, V::S(z)) if *z == 0.0 && matches!(other, V::N(_)) => Some((other.clone(), true)),
            _ => Some((V::S(signum(a) + signum(b)), true)),
        }
    }
    fn neg(a: &V) -> V {
        match a {
            V::S(s) => V::S(-s),
            V::N(r) => V::N(-r.clone()),
        }
    }
    fn mul(&self, a: &V, b: &V) -> Option<(V, bool)> {
        match (a, b) {
            (V::N(x), V::N(y)) => done(self.ctx.mul(x, y)),
            _ => Some((V::S(signum(a) * signum(b)), true)),
        }
    }
    fn div(&self, a: &V, b: &V) -> Option<(V, bool)> {
        match (a, b) {
            (V::N(x), V::N(y)) => done(self.ctx.div(x, y)),
            _ => Some((V::S(signum(a) / signum(b)), true)),
        }
    }
    fn cmp(a: &V, b: &V) -> Option<Ordering> {
        match (a, b) {
            (V::N(x), V::N(y)) => Some(F::from_repr_const(x.clone()).cmp(&F::from_repr_const(y.clone()))),
            (V::S(s), V::S(t)) => s.partial_cmp(t),
            (V::S(s), n) => s.partial_cmp(&(signum(n) * f64::MIN_POSITIVE)),
            (n, V::S(s)) => (signum(n) * f64::MIN_POSITIVE).partial_cmp(s),
        }
    }
    /// The IR's min/max: NaN propagates, −0 orders below +0.
    fn min_max(a: &V, b: &V, max: bool) -> V {
        match Eval::cmp(a, b) {
            None => V::S(f64::NAN),
            Some(Ordering::Equal) => {
                let a_neg = signum(a).is_sign_negative();
                if a_neg != max {
                    a.clone()
                } else {
                    b.clone()
                }
            }
            Some(o) => {
                if (o == Ordering::Less) != max {
                    a.clone()
                } else {
                    b.clone()
                }
            }
        }
    }
    fn with_consts<T>(&self, g: impl FnOnce(&Context<HalfEven>, &mut ConstCache) -> T) -> T {
        CONSTS.with(|c| g(&self.ctx, &mut c.borrow_mut()))
    }
    fn half_pi(&self) -> Option<(V, bool)> {
        let pi = self.with_consts(|ctx, c| ctx.pi::<2>(Some(c)));
        let (x, _) = done(Ok(pi))?;
        let V::N(r) = x else { return None };
        Some((V::N(Repr::new(r.significand().clone(), r.exponent() - 1)), false))
    }
    fn pi(&self) -> Option<(V, bool)> {
        done(Ok(self.with_consts(|ctx, c| ctx.pi::<2>(Some(c)))))
    }

    /// One builtin, with the double-double's semantics.
    fn call(&self, b: Builtin, a: &[V]) -> Option<(V, bool)> {
        let special = a.iter().any(|x| matches!(x, V::S(_)));
        let via_xf = || {
            let xs: Vec<Xf> = a.iter().map(to_xf).collect();
            Some((from_xf(super::call(b, &xs)), true))
        };
        let one = || V::N(Repr::new(IBig::from(1), 0));
        match b {
            Builtin::Min => Some((Eval::min_max(&a[0], &a[1], false), true)),
            Builtin::Max => Some((Eval::min_max(&a[0], &a[1], true), true)),
            Builtin::Clamp => Some((Eval::min_max(&Eval::min_max(&a[0], &a[1], true), &a[2], false), true)),
            Builtin::Abs => Some((Eval::abs(&a[0]), true)),
            Builtin::Fma => {
                let (p, e1) = self.mul(&a[0], &a[1])?;
                let (s, e2) = self.add(&p, &a[2])?;
                Some((s, e1 && e2))
            }
            Builtin::AcosLo | Builtin::PowLo => Some((V::S(0.0), true)),
            Builtin::Floor => Some((from_xf(Xf::from_f64(to_f64(&a[0]).floor())), true)),
            Builtin::Lt | Builtin::Le | Builtin::Eq | Builtin::Ne => Some((from_xf(Xf::from_f64(b.eval(&[to_f64(&a[0]), to_f64(&a[1])]))), true)),
            Builtin::Select => Some((if to_f64(&a[0]) != 0.0 { a[1].clone() } else { a[2].clone() }, true)),
            Builtin::Acos | Builtin::Asin => {
                if let V::S(s) = a[0] {
                    // acos(±0) = π/2, the one special argument whose value is not special.
                    return if s == 0.0 && b == Builtin::Acos { self.half_pi() } else { via_xf() };
                }
                let V::N(x) = &a[0] else { unreachable!() };
                let negative = signum(&a[0]) < 0.0;
                let beyond = Eval::cmp(&Eval::abs(&a[0]), &one()) != Some(Ordering::Less);
                match (b, beyond) {
                    (Builtin::Acos, true) if negative => self.pi(),
                    (Builtin::Acos, true) => Some((V::S(0.0), true)),
                    (_, true) => self.half_pi().map(|(h, e)| (if negative { Eval::neg(&h) } else { h }, e)),
                    (Builtin::Acos, false) => done(self.with_consts(|ctx, c| ctx.acos(x, Some(c)))),
                    _ => done(self.with_consts(|ctx, c| ctx.asin(x, Some(c)))),
                }
            }
            _ if special => via_xf(),
            Builtin::Sqrt => match &a[0] {
                V::N(x) if signum(&a[0]) > 0.0 => done(self.ctx.sqrt(x)),
                _ => Some((V::S(f64::NAN), true)),
            },
            Builtin::Exp | Builtin::ExpMulDiv => {
                let V::N(x) = &a[0] else { unreachable!() };
                let e = if to_xf(&a[0]).parts().2 >= 62 {
                    // Past 2⁶² the result's exponent would leave dashu's range: the double-double's saturation
                    // (the truth's module docs).
                    (from_xf(to_xf(&a[0]).exp()), true)
                } else {
                    done(self.with_consts(|ctx, c| ctx.exp(x, Some(c))))?
                };
                if b == Builtin::Exp {
                    return Some(e);
                }
                let (p, e1) = self.mul(&e.0, &a[1])?;
                let (q, e2) = self.div(&p, &a[2])?;
                Some((q, e.1 && e1 && e2))
            }
            Builtin::Ln => match &a[0] {
                V::N(x) if signum(&a[0]) > 0.0 => done(self.with_consts(|ctx, c| ctx.ln(x, Some(c)))),
                _ => Some((V::S(f64::NAN), true)),
            },
            Builtin::Sin | Builtin::SinNear => match &a[0] {
                V::N(x) => done(self.with_consts(|ctx, c| ctx.sin(x, Some(c)))),
                V::S(_) => unreachable!(),
            },
            Builtin::Cos => match &a[0] {
                V::N(x) => done(self.with_consts(|ctx, c| ctx.cos(x, Some(c)))),
                V::S(_) => unreachable!(),
            },
            Builtin::Tan => match &a[0] {
                V::N(x) => done(self.with_consts(|ctx, c| ctx.tan(x, Some(c)))),
                V::S(_) => unreachable!(),
            },
            Builtin::Atan => match &a[0] {
                V::N(x) => done(self.with_consts(|ctx, c| ctx.atan(x, Some(c)))),
                V::S(_) => unreachable!(),
            },
            Builtin::Pow => self.pow(&a[0], &a[1]),
        }
    }

    fn abs(a: &V) -> V {
        if signum(a).is_sign_negative() {
            Eval::neg(a)
        } else {
            a.clone()
        }
    }

    /// `pow` of two finite nonzero values, as the double-double's (C99 for the rest, there).
    fn pow(&self, x: &V, y: &V) -> Option<(V, bool)> {
        let (V::N(xr), V::N(yr)) = (x, y) else { unreachable!() };
        let one = Repr::new(IBig::from(1), 0);
        if xr == &one {
            return Some((x.clone(), true));
        }
        // y is an integer when its exponent is ≥ 0 once trailing zeros are gone (dashu normalises them away).
        let is_int = yr.exponent() >= 0;
        let negative = signum(x) < 0.0;
        if negative && !is_int {
            return Some((V::S(f64::NAN), true));
        }
        let ax = Eval::abs(x);
        let V::N(axr) = &ax else { unreachable!() };
        let small_int = is_int && yr.significand().unsigned_abs().bit_len() + (yr.exponent() as usize) <= 17;
        // |y·ln x| past 2⁶²: the double-double's saturated exponential (the truth's module docs).
        let (xa, ya) = (to_xf(&ax), to_xf(y));
        if !small_int && ya.mul(xa.ln()).abs().parts().2 >= 62 {
            return Some((from_xf(to_xf(x).pow(ya)), true));
        }
        let r = if small_int {
            let k = yr.significand().clone() << yr.exponent() as usize;
            done(self.ctx.powi(axr, k))?
        } else {
            done(self.with_consts(|ctx, c| ctx.powf(axr, yr, Some(c))))?
        };
        let odd = is_int && yr.exponent() == 0 && (yr.significand().clone() % IBig::from(2)) != IBig::ZERO;
        Some(if negative && odd { (Eval::neg(&r.0), r.1) } else { r })
    }
}

/// The formula at inputs `x` and parameters `params`, evaluated at `precision` bits: the root's value as an
/// [`Xf`] (rounded to 106 bits) and its bound (log₂, in units of 2^-(precision − 2)); `None` when dashu
/// refuses an operation (module docs). `xf`: the double-double's values and bounds at the same point; with
/// `reuse_xf`, a transcendental function whose value there is good to 2⁻⁹⁰ is taken from it (its bound carried
/// over), not computed again at `precision` bits.
pub(super) fn eval(f: &Formula, x: &[Xf; N_INPUTS], params: &[f64], precision: usize, xf: (&[Xf], &[f64]), reuse_xf: bool) -> Option<(Xf, f64)> {
    let ev = Eval { ctx: Context::new(precision) };
    let unit = -(precision as f64 - 2.0);
    // A transcendental node the double-double has to 2⁻⁹⁰: its value reused, its bound in this unit.
    let reuse = |id: crate::ir::NodeId| -> Option<f64> {
        let k = id.index();
        let cheap = !matches!(*f.ir.node(id), Node::Call(b, _) if !matches!(b, Builtin::Min | Builtin::Max | Builtin::Clamp | Builtin::Abs | Builtin::Fma | Builtin::Select | Builtin::Floor | Builtin::Lt | Builtin::Le | Builtin::Eq | Builtin::Ne | Builtin::AcosLo | Builtin::PowLo));
        let l = xf.1[k];
        (reuse_xf && !cheap && l + bound::XF_UNIT <= -90.0).then_some(if l == f64::NEG_INFINITY { l } else { l + bound::XF_UNIT - unit })
    };
    let n = f.root.index() + 1;
    let mut vals: Vec<V> = Vec::with_capacity(n);
    let mut approx: Vec<Xf> = Vec::with_capacity(n);
    let mut lr: Vec<f64> = Vec::with_capacity(n);
    for id in f.ir.ids().take(n) {
        if let Some(l) = reuse(id) {
            let v = xf.0[id.index()];
            vals.push(from_xf(v));
            approx.push(v);
            lr.push(l);
            continue;
        }
        let (v, exact) = match *f.ir.node(id) {
            Node::Const(b) => (from_xf(Xf::from_f64(f64::from_bits(b))), true),
            Node::Input(i) => (from_xf(x[i.index()]), true),
            Node::Column(_) => (V::S(f64::NAN), true),
            Node::Param(p) => (from_xf(Xf::from_f64(params.get(p as usize).copied().unwrap_or(f64::NAN))), true),
            Node::Neg(a) => (Eval::neg(&vals[a.index()]), true),
            Node::Binary(op, a, b) => {
                let (a, b) = (&vals[a.index()], &vals[b.index()]);
                match op {
                    BinOp::Add => ev.add(a, b)?,
                    BinOp::Sub => ev.add(a, &Eval::neg(b))?,
                    BinOp::Mul => ev.mul(a, b)?,
                    BinOp::Div => ev.div(a, b)?,
                }
            }
            Node::Call(b, args) => {
                let xs: Vec<V> = args[..b.arity()].iter().map(|a| vals[a.index()].clone()).collect();
                ev.call(b, &xs)?
            }
        };
        approx.push(to_xf(&v));
        vals.push(v);
        lr.push(bound::node(f, id, &approx, &lr, Some(exact), unit));
    }
    Some((approx[n - 1], lr[n - 1]))
}
