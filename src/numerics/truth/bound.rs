//! The truth's bound on its own rounding error, and the test of whether a value is settled.
//!
//! Beside every node's value the evaluators carry log₂ of a bound on its relative error, in units of the
//! evaluator's precision (2⁻¹⁰⁰ for the double-double [`Xf`], 2⁻⁽ᵖ⁻²⁾ for the arbitrary-precision one at p bits):
//! first-order error analysis, each node's error the operands' errors times its condition plus its own rounding
//! (none where the operation is known to be exact: a sum or product of two f64s in double-double, any operation
//! the big evaluator reports exact). −∞ is an exact value; +∞ is a value of unknown error (a step within reach of
//! its operand's error); at a value that is 0 (a sum that cancels) the bound is absolute, and products, sums and
//! the smooth functions carry it on. The rules:
//! - `a ± b = s`: (|a|·rₐ + |b|·r_b)/|s| + 1; `a·b`, `a/b`: rₐ + r_b + 1 (2 for a quotient); `√a`: rₐ/2 + 2;
//! - `exp x`: |x|·rₓ + 8; `ln x`: rₓ/|ln x| + 8; `pow(x, y)`: |y|·rₓ + |y·ln x|·r_y + 8;
//! - `sin x`: |x·cot x|·rₓ + 8; `cos x`: |x·tan x|·rₓ + 8; `tan x`: |x|·(|t| + 1/|t|)·rₓ + 8 (t = tan x);
//! - `atan x`: |x|/((1 + x²)·|atan x|)·rₓ + 8; `asin x`, `acos x`: |x|/(√(1 − x²)·|v|)·rₓ + 8, and where the
//!   clamp to [−1, 1] may or may not apply within x's error, unknown;
//! - `min`, `max`, `clamp`, `abs`, `−`: the largest of the operands'; `select`, comparisons, `floor`: decided on
//!   f64s, so exact where their operands' f64 roundings are settled (2⁻⁶⁰ relative), unknown otherwise.
//!
//! A first-order bound is not a proof (a second-order term can exceed it where a condition number changes
//! within the error), but it is what decides when to evaluate again at a higher precision
//! ([`super::big`]), and where the double-double is short by hundreds of bits (π/2 − 10⁻³⁰⁹; 1 − 2⁻¹⁰⁷⁵) it says
//! so by hundreds of bits.

use super::Xf;
use crate::builtins::Builtin;
use crate::ir::{BinOp, Formula, Node, NodeId};
use std::ops::{Add, Mul, Neg, Sub};

const INF: f64 = f64::INFINITY;
const NEG_INF: f64 = f64::NEG_INFINITY;
/// log₂ of a function's own rounding, in units (8).
const FN_LOCAL: f64 = 3.0;

/// log₂ of the double-double truth's unit (its operations are good to ~2⁻¹⁰⁴; the functions to a few of those).
pub(super) const XF_UNIT: f64 = -100.0;

/// What a value must be good for.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Target {
    /// Its f64 rounding settled: both ends of the bound (at most 2⁻⁵⁴ relative) round to the same f64 (Ziv's test).
    Rounded,
    /// Its value to 2⁻⁸⁶ relative (what a check against another arbitrary-precision library asks).
    Parts,
}

/// log₂|x|: −∞ at 0, +∞ at ±∞ and NaN.
pub(super) fn lg(x: Xf) -> f64 {
    let (hi, _, e) = x.parts();
    if hi == 0.0 {
        NEG_INF
    } else if !hi.is_finite() {
        INF
    } else {
        e as f64 + hi.abs().log2()
    }
}

/// log₂(2^a + 2^b).
pub(super) fn lse(a: f64, b: f64) -> f64 {
    let (m, n) = if a >= b { (a, b) } else { (b, a) };
    if n == NEG_INF || m == INF {
        return m;
    }
    if m.is_nan() || n.is_nan() {
        return INF;
    }
    m + (1.0 + (n - m).exp2()).log2()
}

fn lse3(a: f64, b: f64, c: f64) -> f64 {
    lse(lse(a, b), c)
}

/// lr + l (an error bound scaled by a ratio of magnitudes), with an unknown error staying unknown and an exact
/// value (or a zero weight) staying exact.
fn scaled(lr: f64, l: f64) -> f64 {
    if lr == INF {
        INF
    } else if lr == NEG_INF || l == NEG_INF {
        NEG_INF
    } else {
        lr + l
    }
}

/// `a + b − s` for `s = fl(a + b)`: the rounding error of one f64 sum, exactly (Knuth's two-sum).
fn sum_err(a: f64, b: f64, s: f64) -> f64 {
    let bb = s - a;
    (a - (s - bb)) + (b - bb)
}

/// The relative rounding error of the double-double product of two [`Xf`] mantissas (`dd::mul`), from the
/// error-free transformations of its steps: the rounding of each cross product and sum, and the tails' product it
/// leaves out. 0 where every step is exact (a product of two f64s, a product by a power of two), which is what
/// keeps `1 − (1 − 2⁻²⁵⁰)⁵` settled in the double-double: its terms are short.
fn mul_rel_err(a: Xf, b: Xf) -> f64 {
    let ((ah, al, _), (bh, bl, _)) = (a.parts(), b.parts());
    if al == 0.0 && bl == 0.0 {
        return 0.0;
    }
    let p = ah * bh;
    let err = ah.mul_add(bh, -p);
    let x = ah * bl;
    let y = al * bh;
    let cross = x + y;
    let lo = err + cross;
    let total = ah.mul_add(bl, -x).abs() + al.mul_add(bh, -y).abs() + sum_err(x, y, cross).abs() + sum_err(err, cross, lo).abs() + (al * bl).abs() * 1.0000000000000004;
    total / p.abs()
}

/// The relative rounding error of the double-double sum `a + b = r` of two [`Xf`]s (`Xf::add`: aligned to the
/// larger exponent, then `dd::add`), from the error-free transformations of its steps, as [`mul_rel_err`].
fn add_rel_err(a: Xf, b: Xf) -> f64 {
    let ((ah, al, ae), (bh, bl, be)) = (a.parts(), b.parts());
    let d = ae - be;
    if d.abs() > 1100 {
        // The smaller one is dropped: below 2⁻¹⁰⁷⁴ of the larger.
        return 2f64.powi(-1000);
    }
    let scale = |x: f64, k: i64| super::ldexp(x, k);
    let ((xh, xl), (yh, yl)) = if d >= 0 { ((ah, al), (scale(bh, -d), scale(bl, -d))) } else { ((scale(ah, d), scale(al, d)), (bh, bl)) };
    // Bits lost in the alignment (a tail scaled into the subnormals).
    let lost = if d >= 0 { (scale(yl, d) - bl).abs() + (scale(yh, d) - bh).abs() } else { (scale(xl, -d) - al).abs() + (scale(xh, -d) - ah).abs() };
    let lost = if lost == 0.0 { 0.0 } else { 2f64.powi(-1073) };
    let s1 = xh + yh;
    let s2 = sum_err(xh, yh, s1);
    let t1 = xl + yl;
    let t2 = sum_err(xl, yl, t1);
    let u = s2 + t1;
    let e1 = sum_err(s2, t1, u);
    let v1 = s1 + u;
    let v2 = u - (v1 - s1);
    let e2 = sum_err(s1, u, v1) - v2;
    let w = v2 + t2;
    let e3 = sum_err(v2, t2, w);
    let z1 = v1 + w;
    let z2 = w - (z1 - v1);
    let e4 = sum_err(v1, w, z1) - z2;
    let total = e1.abs() + e2.abs() + e3.abs() + e4.abs() + lost;
    if total == 0.0 {
        0.0
    } else {
        total / (z1 + z2).abs()
    }
}

/// The relative rounding error of `Xf::pow`'s binary powering of |x| to the k-th power (its products' errors,
/// each [`mul_rel_err`], carried through the later products), and of the reciprocal for a negative exponent.
fn pow_rel_err(x: Xf, k: u64, negative: bool) -> f64 {
    let (mut acc, mut base) = (Xf::ONE, x.abs());
    let (mut e_acc, mut e_base) = (0.0, 0.0);
    let mut k = k;
    while k > 0 {
        if k & 1 == 1 {
            e_acc += e_base + mul_rel_err(acc, base);
            acc = acc.mul(base);
        }
        k >>= 1;
        if k > 0 {
            e_base = 2.0 * e_base + mul_rel_err(base, base);
            base = base.mul(base);
        }
    }
    if negative {
        e_acc += 2f64.powi(-100);
    }
    e_acc
}

/// log₂ of a relative error in units of 2^`unit`.
fn in_units(rel: f64, unit: f64) -> f64 {
    if rel == 0.0 {
        NEG_INF
    } else {
        rel.log2() - unit
    }
}

/// The bound of a sum `s = a + b` (not 0) from its operands' bounds and its own rounding `own` (all log₂, in
/// units): (|a|·rₐ + |b|·r_b)/|s| + own.
pub(super) fn sum(a: Xf, la: f64, b: Xf, lb: f64, s: Xf, own: f64) -> f64 {
    let ls = lg(s);
    lse3(abs_err(a, la) - ls, abs_err(b, lb) - ls, own)
}

/// log₂ of a value's absolute error bound (in units) from its bound: a zero's bound is absolute already.
fn abs_err(x: Xf, l: f64) -> f64 {
    if x.is_zero() {
        l
    } else {
        scaled(l, lg(x))
    }
}

fn is_special(x: Xf) -> bool {
    let hi = x.parts().0;
    hi == 0.0 || !hi.is_finite()
}

/// Whether a value's f64 rounding is settled to 2⁻⁶⁰ relative: a step (comparison, floor, select) decides on it.
fn f64_settled(lr: f64, unit: f64) -> bool {
    lr == NEG_INF || lr + unit <= -60.0
}

/// The bound (log₂, in units of 2^`unit`) of node `id`, whose value `v[id]` and operands' values and bounds are
/// known. `exact`: whether the evaluator knows the node's own operation was exact (the big evaluator does); `None`
/// derives it for the double-double.
pub(super) fn node(f: &Formula, id: NodeId, v: &[Xf], lr: &[f64], exact: Option<bool>, unit: f64) -> f64 {
    let r = v[id.index()];
    let max_of = |args: &[NodeId]| args.iter().map(|a| lr[a.index()]).fold(NEG_INF, f64::max);
    match *f.ir.node(id) {
        Node::Const(_) | Node::Input(_) | Node::Param(_) | Node::Column(_) => NEG_INF,
        Node::Neg(a) => lr[a.index()],
        Node::Binary(op, a, b) => {
            let (x, y) = (v[a.index()], v[b.index()]);
            let (la, lb) = (lr[a.index()], lr[b.index()]);
            let rh = r.parts().0;
            if rh.is_nan() || rh.is_infinite() {
                return la.max(lb);
            }
            let yp = y.parts();
            match op {
                BinOp::Add | BinOp::Sub => {
                    if rh == 0.0 {
                        // A cancellation to 0 (exact in both evaluators): the operands' absolute errors.
                        return lse(abs_err(x, la), abs_err(y, lb));
                    }
                    let own = match exact {
                        Some(e) => if e { NEG_INF } else { 0.0 },
                        None => in_units(add_rel_err(x, if op == BinOp::Sub { y.neg() } else { y }), unit),
                    };
                    sum(x, la, y, lb, r, own)
                }
                BinOp::Mul | BinOp::Div if rh == 0.0 => {
                    // 0·y, 0/y: absolute, the zero's error times |y| (or over it).
                    let (lz, other) = if x.is_zero() { (la, y) } else { (lb, x) };
                    if op == BinOp::Div && !x.is_zero() {
                        return INF;
                    }
                    if op == BinOp::Mul { scaled(lz, lg(other)) } else { scaled(lz, -lg(other)) }
                }
                BinOp::Mul => {
                    let own = match exact {
                        Some(e) => if e { NEG_INF } else { 0.0 },
                        None => in_units(mul_rel_err(x, y), unit),
                    };
                    lse3(la, lb, own)
                }
                BinOp::Div => {
                    let own = exact.unwrap_or(yp.0.abs() == 1.0 && yp.1 == 0.0);
                    lse3(la, lb, if own { NEG_INF } else { 1.0 })
                }
            }
        }
        Node::Call(b, args) => {
            let args = &args[..b.arity()];
            let a = |i: usize| v[args[i].index()];
            let l = |i: usize| lr[args[i].index()];
            let local = if exact == Some(true) { NEG_INF } else { FN_LOCAL };
            match b {
                Builtin::AcosLo | Builtin::PowLo => return NEG_INF,
                Builtin::Min | Builtin::Max | Builtin::Clamp | Builtin::Abs => return max_of(args),
                Builtin::Floor | Builtin::Lt | Builtin::Le | Builtin::Eq | Builtin::Ne => {
                    if args.iter().all(|&x| f64_settled(lr[x.index()], unit)) {
                        return NEG_INF;
                    }
                    // Not every operand's rounding is settled, but the step may be far: the operands (or the
                    // operand and the nearest integer) further apart than their errors and a few ulps.
                    let (x, lx) = (a(0), l(0));
                    let (y, ly) = if b == Builtin::Floor { (Xf::from_f64(x.to_f64().round()), NEG_INF) } else { (a(1), l(1)) };
                    let gap = lg(x.sub(y));
                    let reach = lse3(abs_err(x, lx) + unit, abs_err(y, ly) + unit, lg(x).max(lg(y)) - 50.0);
                    return if gap > reach + 2.0 { NEG_INF } else { INF };
                }
                Builtin::Select => {
                    if !f64_settled(l(0), unit) {
                        return INF;
                    }
                    return if a(0).to_f64() != 0.0 { l(1) } else { l(2) };
                }
                _ => {}
            }
            if is_special(r) && r.parts().0 != 0.0 || args.iter().any(|&x| is_special(v[x.index()])) {
                // A NaN or an infinity, or a function of a special value (exp(0) = 1, pow(x, 0) = 1): exact as far
                // as its operands are. A zero known only to an absolute error ε moves exp, sin, tan, atan, asin,
                // acos and cos by at most ε (relatively, or absolutely where the value is 0); sqrt, ln and pow of
                // it are unknown.
                let uncertain_zero = args.iter().any(|&x| v[x.index()].is_zero() && lr[x.index()] != NEG_INF);
                if uncertain_zero && matches!(b, Builtin::Sqrt | Builtin::Ln | Builtin::Pow | Builtin::Fma | Builtin::ExpMulDiv) {
                    return INF;
                }
                if b == Builtin::Pow && a(1).is_zero() {
                    return if l(1) == NEG_INF { NEG_INF } else { INF };
                }
                // A rounded constant (acos 0 = π/2, atan ±∞ = ±π/2) is not exact; 1, 0, ±∞ and NaN are.
                let rh = r.parts().0;
                let rounded = rh.is_finite() && rh != 0.0 && r.parts() != Xf::ONE.parts() && r.parts() != Xf::ONE.neg().parts();
                return if rounded { lse(max_of(args), local) } else { max_of(args) };
            }
            let lx = lg(a(0));
            let lv = lg(r);
            match b {
                Builtin::Sqrt => lse(scaled(l(0), -1.0), if exact == Some(true) { NEG_INF } else { 1.0 }),
                Builtin::Exp => {
                    let e = a(0).parts().2;
                    if e >= 62 {
                        // Saturated in both evaluators (the truth's module docs): exact as far as the argument's sign
                        // is.
                        return if l(0) == INF { INF } else { NEG_INF };
                    }
                    if e >= 52 {
                        // The double-double saturates from 2⁵², the big evaluator only from 2⁶².
                        return INF;
                    }
                    lse(scaled(l(0), lx), local)
                }
                Builtin::Ln => {
                    if r.is_zero() {
                        return if l(0) == NEG_INF { NEG_INF } else { INF };
                    }
                    lse(scaled(l(0), -lv), local)
                }
                Builtin::Pow => {
                    let (x, y) = (a(0), a(1));
                    if x.parts() == Xf::ONE.parts() {
                        return scaled(l(0), lg(y));
                    }
                    let (h, _, e) = x.parts();
                    let ln_x = (e as f64 + h.abs().log2()) * std::f64::consts::LN_2;
                    let ly = lg(y);
                    // |y·ln x| past 2⁶²: the exponential inside saturates in both evaluators; past 2⁵² only in the
                    // double-double (as exp's rule).
                    let t = ly + ln_x.abs().log2();
                    if t >= 62.0 {
                        return if max_of(args) == INF { INF } else { NEG_INF };
                    }
                    if t >= 52.0 && exact.is_none() {
                        return INF;
                    }
                    // Integer powers by repeated squaring: the double-double's products' own errors (exact for a
                    // short base), or one correctly rounded power in the big evaluator.
                    let yf = y.to_f64();
                    let own = match exact {
                        Some(e) => if e { NEG_INF } else { 0.0 },
                        None if yf.fract() == 0.0 && yf.abs() <= 65536.0 => in_units(pow_rel_err(x, yf.abs() as u64, yf < 0.0), unit),
                        None => local + 1.0,
                    };
                    lse3(scaled(l(0), ly), scaled(l(1), ly + ln_x.abs().log2()), own)
                }
                Builtin::Sin | Builtin::SinNear | Builtin::Cos | Builtin::Tan => {
                    // An angle held as q·π/2 + r (super::angle) is computed from r: r's error is what moves it.
                    let (lx, l0) = match super::angle::trig_argument(f, id, v, Some(lr)) {
                        Some(g) => (lg(g.r), g.lr),
                        None => (lx, l(0)),
                    };
                    let cond = if b == Builtin::Tan {
                        let m = lv.abs();
                        m + (1.0 + (-2.0 * m).exp2()).log2()
                    } else {
                        // The other of the pair's magnitude, from this one's.
                        let t = r.to_f64().clamp(-1.0, 1.0);
                        (1.0 - t * t).max(0.0).sqrt().log2() - lv
                    };
                    lse(scaled(l0, lx + cond), local)
                }
                Builtin::Atan => {
                    let one_plus = 2.0 * lx.max(0.0) + (1.0 + (-2.0 * lx.abs()).exp2()).log2();
                    lse(scaled(l(0), lx - one_plus - lv), local)
                }
                Builtin::Asin | Builtin::Acos => {
                    let x = a(0);
                    let d = Xf::ONE.sub(x.abs());
                    let ld = lg(d);
                    let err = scaled(l(0), lx) + unit;
                    if d.parts().0 <= 0.0 {
                        // Clamped: a constant (0, π/2 or π), unless x's error reaches back below 1.
                        return if l(0) == NEG_INF || err < ld - 1.0 { local } else { INF };
                    }
                    if err >= ld - 1.0 {
                        return INF;
                    }
                    // √(1 − x²) = √((1 − |x|)(1 + |x|)).
                    let root = 0.5 * (ld + (2.0f64 - d.to_f64()).log2());
                    lse(scaled(l(0), lx - root - lv), local)
                }
                Builtin::Fma => {
                    let p = a(0).mul(a(1));
                    if r.is_zero() {
                        return if max_of(args) == NEG_INF { NEG_INF } else { INF };
                    }
                    let lp = lse3(l(0), l(1), 0.0);
                    lse3(scaled(lp, lg(p) - lv), scaled(l(2), lg(a(2)) - lv), 0.0)
                }
                Builtin::ExpMulDiv => lse(lse3(scaled(l(0), lx), l(1), l(2)), local + 1.0),
                // Handled above.
                _ => max_of(args),
            }
        }
    }
}

/// Whether `v`, with bound `lr` in units of 2^`unit`, is good enough for `t`.
pub(super) fn sure(v: Xf, lr: f64, unit: f64, t: Target) -> bool {
    if lr == NEG_INF {
        return true;
    }
    let rel = lr + unit;
    if rel.is_nan() || rel == INF {
        return false;
    }
    if v.is_zero() {
        // An absolute bound: settled when nothing it allows reaches half the smallest subnormal.
        return rel < -1076.0;
    }
    if t == Target::Rounded && lg(v).max(rel + lg(v)) < -1076.0 {
        // The value and all its bound allows round to zero (the sign of that zero aside).
        return true;
    }
    match t {
        Target::Parts => rel <= -86.0,
        Target::Rounded => {
            if rel > -54.0 {
                return false;
            }
            if is_special(v) {
                return true;
            }
            // Both ends of the interval the bound allows round to the same f64.
            let delta = v.abs().mul(Xf::from_f64(rel.exp2()));
            v.sub(delta).to_f64() == v.add(delta).to_f64()
        }
    }
}
