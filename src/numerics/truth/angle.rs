//! Angles as a multiple of π/2 plus a remainder: what keeps tan(acos(10⁻³⁰⁹)) right in the double-double.
//!
//! acos(z) for a tiny z is π/2 − z: as one double-double that is π/2 rounded to 104 bits, and tan of it is ±2¹⁰⁴
//! where the value is 1/z. Written as q·π/2 + r with q exact (a dyadic f64) and r a double-double, the angle keeps
//! z, and sin, cos and tan of it are sin, cos or tan of r shifted by q quadrants: exact to 104 bits of r.
//!
//! The form comes from the inverse functions (acos x = π/2 − asin x for |x| ≤ ½; asin x = ±(π/2 − acos|x|) for
//! |x| > ½; atan x = ±π/2 − atan(1/x) for |x| > 1) and passes through negation, sums, differences, products and
//! quotients by a power of two, and min, max and clamp (compared by q, then r); any other operation ends it. The
//! node's value stays the plain double-double (every other consumer reads that); the trigonometric functions and
//! their bound ([`super::bound`]) read the form of their argument where there is one and q is an integer. Derived
//! on demand from the operands, so it costs nothing where no trigonometric function reads an angle.

use super::Xf;
use crate::builtins::Builtin;
use crate::ir::{BinOp, Formula, Node, NodeId};
use std::cmp::Ordering;
use std::ops::{Add, Div, Mul, Neg, Sub};

/// An angle q·π/2 + r, and log₂ of the bound on r's relative error ([`super::bound`]'s units) when asked for.
#[derive(Clone, Copy, Debug)]
pub(super) struct Form {
    pub q: f64,
    pub r: Xf,
    pub lr: f64,
}

/// 2^k exactly, for a constant node that is a power of two (up to sign).
fn power_of_two(f: &Formula, id: NodeId) -> Option<f64> {
    match *f.ir.node(id) {
        Node::Const(b) => {
            let c = f64::from_bits(b);
            (c.is_normal() && c.abs().to_bits() & ((1u64 << 52) - 1) == 0).then_some(c)
        }
        _ => None,
    }
}

/// The form of node `id`, if it has one, from the nodes' values `v` (and their bounds `lr`, for the form's).
pub(super) fn form(f: &Formula, id: NodeId, v: &[Xf], lr: Option<&[f64]>) -> Option<Form> {
    let l = |a: NodeId| lr.map_or(0.0, |lr| lr[a.index()]);
    // A node without a form, as q = 0 and r its value (for combining with one that has).
    let plain = |a: NodeId| Form { q: 0.0, r: v[a.index()], lr: l(a) };
    let either = |a: NodeId| form(f, a, v, lr);
    match *f.ir.node(id) {
        Node::Neg(a) => either(a).map(|g| Form { q: -g.q, r: g.r.neg(), lr: g.lr }),
        Node::Binary(op @ (BinOp::Add | BinOp::Sub), a, b) => {
            let (fa, fb) = (either(a), either(b));
            if fa.is_none() && fb.is_none() {
                return None;
            }
            let (fa, fb) = (fa.unwrap_or_else(|| plain(a)), fb.unwrap_or_else(|| plain(b)));
            let (qb, rb) = if op == BinOp::Sub { (-fb.q, fb.r.neg()) } else { (fb.q, fb.r) };
            let q = fa.q + qb;
            // q stays exact (a few halvings of small integers), or the form ends.
            if q - fa.q != qb {
                return None;
            }
            let r = fa.r.add(rb);
            Some(Form { q, r, lr: super::bound::sum(fa.r, fa.lr, rb, fb.lr, r, 0.0) })
        }
        Node::Binary(op @ (BinOp::Mul | BinOp::Div), a, b) => {
            let (g, c) = match (power_of_two(f, b), power_of_two(f, a)) {
                (Some(c), _) => (either(a)?, c),
                (None, Some(c)) if op == BinOp::Mul => (either(b)?, c),
                _ => return None,
            };
            let c = if op == BinOp::Div { 1.0 / c } else { c };
            Some(Form { q: g.q * c, r: g.r.mul(Xf::from_f64(c)), lr: g.lr })
        }
        Node::Call(b @ (Builtin::Min | Builtin::Max | Builtin::Clamp), args) => {
            let forms: Vec<Form> = args[..b.arity()].iter().map(|&a| either(a).unwrap_or_else(|| plain(a))).collect();
            if forms.iter().all(|g| g.q == 0.0) {
                return None;
            }
            let pick = |x: Form, y: Form, max: bool| match cmp(x, y) {
                Some(Ordering::Less) => if max { y } else { x },
                Some(_) => if max { x } else { y },
                None => Form { q: 0.0, r: Xf::NAN, lr: x.lr.max(y.lr) },
            };
            Some(match b {
                Builtin::Min => pick(forms[0], forms[1], false),
                Builtin::Max => pick(forms[0], forms[1], true),
                _ => pick(pick(forms[0], forms[1], true), forms[2], false),
            })
        }
        Node::Call(b @ (Builtin::Acos | Builtin::Asin | Builtin::Atan), args) => {
            let a = args[0];
            let x = v[a.index()];
            if x.is_nan() {
                return None;
            }
            let half = Xf::from_f64(0.5);
            let ax = x.abs();
            let sign = if x.to_f64() < 0.0 { -1.0 } else { 1.0 };
            let (q, r) = match b {
                Builtin::Acos if ax.partial_cmp(half) != Some(Ordering::Greater) => (1.0, x.asin().neg()),
                Builtin::Asin if ax.partial_cmp(half) == Some(Ordering::Greater) => (sign, Xf::from_f64(sign).mul(ax.acos()).neg()),
                Builtin::Atan if ax.partial_cmp(Xf::ONE) == Some(Ordering::Greater) => (sign, Xf::ONE.div(x).atan().neg()),
                _ => return None,
            };
            // r's error from the argument's: the condition of ∓asin x (≤ 1.21 for |x| ≤ ½), of ∓acos|x| (any size
            // near 1: |x|/(√(1 − x²)·|r|)), of −atan(1/x) (≤ 1, after a division), plus their own rounding.
            let lr = lr.map_or(0.0, |lr| {
                let lx = lr[a.index()];
                let cond = match b {
                    Builtin::Acos => 0.3,
                    Builtin::Atan => 1.0,
                    _ => {
                        let d = Xf::ONE.sub(ax);
                        super::bound::lg(ax) - 0.5 * (super::bound::lg(d) + (2.0 - d.to_f64()).log2()) - super::bound::lg(r)
                    }
                };
                super::bound::lse(if lx == f64::NEG_INFINITY { lx } else { lx + cond }, 3.0)
            });
            Some(Form { q, r, lr })
        }
        _ => None,
    }
}

/// The order of two angles: by q·π/2 + r, exactly where q is the same.
fn cmp(x: Form, y: Form) -> Option<Ordering> {
    if x.q == y.q {
        x.r.partial_cmp(y.r)
    } else {
        x.plain().partial_cmp(y.plain())
    }
}

/// The quadrant shift of an integer q (0–3), or `None`.
pub(super) fn quadrant(q: f64) -> Option<i64> {
    (q.fract() == 0.0 && q.abs() < 2f64.powi(52)).then(|| (q as i64).rem_euclid(4))
}

impl Form {
    /// q·π/2 + r as one double-double.
    fn plain(self) -> Xf {
        let half_pi = Xf::from_f64(super::PI3[0] / 2.0).add(Xf::from_f64(super::PI3[1] / 2.0)).add(Xf::from_f64(super::PI3[2] / 2.0));
        half_pi.mul(Xf::from_f64(self.q)).add(self.r)
    }

    /// (sin, cos) of the angle, from r's and the quadrant; `None` where q is not an integer.
    pub fn sin_cos(self) -> Option<(Xf, Xf)> {
        let k = quadrant(self.q)?;
        let (s, c) = self.r.sin_cos();
        Some(match k {
            0 => (s, c),
            1 => (c, s.neg()),
            2 => (s.neg(), c.neg()),
            _ => (c.neg(), s),
        })
    }
}

/// The argument of a trigonometric call `id` as a form, when it has one with an integer q.
pub(super) fn trig_argument(f: &Formula, id: NodeId, v: &[Xf], lr: Option<&[f64]>) -> Option<Form> {
    match *f.ir.node(id) {
        Node::Call(Builtin::Sin | Builtin::SinNear | Builtin::Cos | Builtin::Tan, args) => {
            form(f, args[0], v, lr).filter(|g| quadrant(g.q).is_some())
        }
        _ => None,
    }
}
