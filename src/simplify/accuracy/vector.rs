//! The vector family: forms that use what a formula's own directions make exact in real arithmetic —
//! 1 − c² of a component the formula normalised is the sum of the other squares over the length, a common
//! factor cancels, `c²·(A + B/c²)` is `A·c² + B` (`sine-square`, `cancel-tan`, `cancel-common`,
//! `half-complement`, `interleave-quotient`; each described in [`super`]). Inputs are never taken as unit vectors: their f64
//! components are not; only a vector the formula itself divides by its length is.

use super::finish;
use super::rule::{Example, Rule, Sites, Source};
use crate::base::span::Span;
use crate::builtins::dd::{self, Arith};
use crate::builtins::Builtin;
use crate::ir::{BinOp, Formula, Input, Ir, Node, NodeId};
use crate::simplify::emit::IrEmit;
use crate::simplify::rewrite::{list_operands, divide_apart, divide_by, rebuild, safe, Analysis};

/// `sine-square` (module docs).
pub(crate) struct SineSquare;

impl Rule for SineSquare {
    fn name(&self) -> &'static str {
        "sine-square"
    }
    fn doc(&self) -> &'static str {
        "1 - c^2, c^2 - 1 and c^2*(A - 1) + 1 with c = w_z/|w| as (w_x^2 + w_y^2)/|w|^2 (of another c, fma(-c, c, 1)): no cancellation near c = 1"
    }
    fn sites(&self) -> Sites {
        Sites::Everywhere
    }
    fn apply(&self, _: &Source, a: &Analysis, _: Option<usize>) -> Option<Formula> {
        finish(a, sine_square(a))
    }
    fn example(&self) -> Example {
        Example {
            before: "param a = 0.1 in 0.001..1\nlet x = Lx + Vx\nlet y = Ly + Vy\nlet z = Lz + Vz\nlet c = z / sqrt(x*x + y*y + z*z)\na*a / (c*c*(a*a - 1) + 1)",
            bake: &[],
            site: None,
            shows: "t4 / t5 + ",
        }
    }
}

/// `cancel-tan` (module docs).
pub(crate) struct CancelTan;

impl Rule for CancelTan {
    fn name(&self) -> &'static str {
        "cancel-tan"
    }
    fn doc(&self) -> &'static str {
        "x*(a + b/x) as a*x + b: no 0*inf where x underflows (c^2*(A + tan^2) with tan^2 = (1 - c^2)/c^2)"
    }
    fn sites(&self) -> Sites {
        Sites::Everywhere
    }
    fn apply(&self, _: &Source, a: &Analysis, _: Option<usize>) -> Option<Formula> {
        finish(a, cancel_tan(a))
    }
    fn example(&self) -> Example {
        Example { before: "param a = 0.1 in 0.001..1\nlet c = NH*NH\na / (c * (a*a + (1 - c)/c))", bake: &[], site: None, shows: "t1 * (a * a) + (1 - t1)" }
    }
}

/// `cancel-common` (module docs).
pub(crate) struct CancelCommon;

impl Rule for CancelCommon {
    fn name(&self) -> &'static str {
        "cancel-common"
    }
    fn doc(&self) -> &'static str {
        "x*.../(x*...) as .../..., |x|*.../(x*...) as sign(x)*.../...: no 0/0 where a common factor underflows"
    }
    fn sites(&self) -> Sites {
        Sites::Everywhere
    }
    fn apply(&self, _: &Source, a: &Analysis, _: Option<usize>) -> Option<Formula> {
        finish(a, cancel_common(a))
    }
    fn example(&self) -> Example {
        Example { before: "let g = NL*NV/(1 + NH)\ng * (2/(NL*NV))", bake: &[], site: None, shows: "2 / (1 + clamp(NH, 0, 1))" }
    }
}

/// `interleave-quotient` (module docs).
pub(crate) struct InterleaveQuotient;

impl Rule for InterleaveQuotient {
    fn name(&self) -> &'static str {
        "interleave-quotient"
    }
    fn doc(&self) -> &'static str {
        "x*y*.../(d*...) as (x/d)*y*...: two tiny factors meet a divisor before each other, no underflow of x*y"
    }
    fn sites(&self) -> Sites {
        Sites::Everywhere
    }
    fn apply(&self, _: &Source, a: &Analysis, _: Option<usize>) -> Option<Formula> {
        finish(a, interleave_quotient(a))
    }
    fn example(&self) -> Example {
        Example { before: "NL*NV/(NL + NV - NL*NV)", bake: &[], site: None, shows: "nl / (nl + nv - nl * nv) * nv" }
    }
}

/// `half-complement` (module docs).
pub(crate) struct HalfComplement;

impl Rule for HalfComplement {
    fn name(&self) -> &'static str {
        "half-complement"
    }
    fn doc(&self) -> &'static str {
        "1 - V.H with H = (L + V)/|L + V| as (|V x L|^2 + (1 - |V|^2)|w|^2)/(|w|(|w| + V.w)) where V.H > 1/2: no cancellation near V.H = 1"
    }
    fn sites(&self) -> Sites {
        Sites::Everywhere
    }
    fn apply(&self, _: &Source, a: &Analysis, _: Option<usize>) -> Option<Formula> {
        finish(a, half_complement(a))
    }
    fn example(&self) -> Example {
        Example {
            before: "let x = Lx + Vx\nlet y = Ly + Vy\nlet z = Lz + Vz\nlet len = sqrt(x*x + y*y + z*z)\nlet u = 1 - (Vx*(x/len) + Vy*(y/len) + Vz*(z/len))\nu*u*u*u*u",
            bake: &[],
            site: None,
            shows: "fma(",
        }
    }
}

fn is_const(ir: &Ir, x: NodeId, v: f64) -> bool {
    ir.node(x).as_const() == Some(v)
}

/// The factors of a tree of `*` (a quotient is one factor: c = x/|w| stays whole).
fn mul_factors(ir: &Ir, x: NodeId, out: &mut Vec<NodeId>) {
    crate::base::stack::deep(|| match *ir.node(x) {
        Node::Binary(BinOp::Mul, p, q) => {
            mul_factors(ir, p, out);
            mul_factors(ir, q, out);
        }
        _ => out.push(x),
    })
}

/// The bases of a sum of squares `a·a + b·b + …` (false: not one).
fn squares(ir: &Ir, x: NodeId, out: &mut Vec<NodeId>) -> bool {
    crate::base::stack::deep(|| match *ir.node(x) {
        Node::Binary(BinOp::Add, p, q) => squares(ir, p, out) && squares(ir, q, out),
        Node::Binary(BinOp::Mul, a, b) if a == b => {
            out.push(a);
            true
        }
        _ => false,
    })
}

/// A component of a vector the formula normalised, `c = x/sqrt(S)` with `S = Σ b·b` over bases that hold `x`
/// once: the sum node S and the other bases.
struct Unit {
    x: NodeId,
    sum: NodeId,
    others: Vec<NodeId>,
}

fn unit_component(ir: &Ir, c: NodeId) -> Option<Unit> {
    let Node::Binary(BinOp::Div, x, d) = *ir.node(c) else { return None };
    let Node::Call(Builtin::Sqrt, [sum, ..]) = *ir.node(d) else { return None };
    let mut bases = vec![];
    if !squares(ir, sum, &mut bases) || bases.len() < 2 || bases.iter().filter(|b| **b == x).count() != 1 {
        return None;
    }
    let others = bases.into_iter().filter(|b| *b != x).collect();
    Some(Unit { x, sum, others })
}

/// Σ b·b over `xs` (old nodes, mapped), `None` when empty.
fn sum_squares(ir: &mut Ir, map: &[NodeId], xs: &[NodeId], s: Span) -> Option<NodeId> {
    let sq: Vec<NodeId> = xs.iter().map(|b| map[b.index()]).map(|b| ir.bin(BinOp::Mul, b, b, s)).collect();
    sq.into_iter().reduce(|acc, t| ir.bin(BinOp::Add, acc, t, s))
}

/// 1 − c·c in the new arena: for a normalised component, the other squares over the length squared (exact in
/// real arithmetic: x² + R = S); otherwise `fma(−c, c, 1)`, one rounding.
fn one_minus_square(ir0: &Ir, ir: &mut Ir, map: &[NodeId], c: NodeId, s: Span) -> NodeId {
    if let Some(u) = unit_component(ir0, c) {
        let r = sum_squares(ir, map, &u.others, s).expect("a unit component has another base");
        return ir.bin(BinOp::Div, r, map[u.sum.index()], s);
    }
    let mc = map[c.index()];
    let neg = ir.neg(mc, s);
    let one = ir.konst(1.0, s);
    ir.call(Builtin::Fma, &[neg, mc, one], s)
}

// 1 − c·c → R/S  (c = x/sqrt(S), S = x·x + R; else fma(−c, c, 1)),  c·c − 1 → −(1 − c·c),
// c·c·(A − 1) + 1 → (1 − c·c) + A·(c·c)
fn sine_square(a: &Analysis) -> (Ir, NodeId, bool) {
    let f = &a.f;
    let ir0 = &f.ir;
    let square = |x: NodeId| match *ir0.node(x) {
        Node::Binary(BinOp::Mul, p, q) if p == q => Some(p),
        _ => None,
    };
    rebuild(f, |ir, map, id, n| {
        let s = ir0.span(id);
        match n {
            Node::Binary(BinOp::Sub, one, m) if is_const(ir0, one, 1.0) => {
                let c = square(m)?;
                Some(one_minus_square(ir0, ir, map, c, s))
            }
            Node::Binary(BinOp::Sub, m, one) if is_const(ir0, one, 1.0) => {
                let c = square(m)?;
                let om = one_minus_square(ir0, ir, map, c, s);
                Some(ir.neg(om, s))
            }
            Node::Binary(BinOp::Add, p, q) => {
                let t = if is_const(ir0, p, 1.0) { q } else if is_const(ir0, q, 1.0) { p } else { return None };
                let mut num = vec![];
                mul_factors(ir0, t, &mut num);
                if num.len() != 3 {
                    return None;
                }
                // The factor A − 1 and the pair c, c.
                let k = num.iter().position(|&k| matches!(*ir0.node(k), Node::Binary(BinOp::Sub, _, one) if is_const(ir0, one, 1.0)))?;
                let Node::Binary(BinOp::Sub, am, _) = *ir0.node(num[k]) else { return None };
                let pair: Vec<NodeId> = num.iter().enumerate().filter(|(i, _)| *i != k).map(|(_, x)| *x).collect();
                if pair[0] != pair[1] {
                    return None;
                }
                let c = pair[0];
                let om = one_minus_square(ir0, ir, map, c, s);
                let mc = map[c.index()];
                let cc = ir.bin(BinOp::Mul, mc, mc, s);
                let acc = ir.bin(BinOp::Mul, map[am.index()], cc, s);
                Some(ir.bin(BinOp::Add, om, acc, s))
            }
            _ => None,
        }
    })
}

// x·(a ± b/x) → x·a ± b,  x·(b/x ± a) → b ± x·a   (either operand order of the product)
fn cancel_tan(a: &Analysis) -> (Ir, NodeId, bool) {
    let f = &a.f;
    let ir0 = &f.ir;
    rebuild(f, |ir, map, id, n| {
        let Node::Binary(BinOp::Mul, u, v) = n else { return None };
        let s = ir0.span(id);
        for (x, sum) in [(u, v), (v, u)] {
            let Node::Binary(op @ (BinOp::Add | BinOp::Sub), p, q) = *ir0.node(sum) else { continue };
            let over_x = |t: NodeId| match *ir0.node(t) {
                Node::Binary(BinOp::Div, b, d) if d == x => Some(b),
                _ => None,
            };
            let mx = map[x.index()];
            if let Some(b) = over_x(q) {
                let xa = ir.bin(BinOp::Mul, mx, map[p.index()], s);
                return Some(ir.bin(op, xa, map[b.index()], s));
            }
            if let Some(b) = over_x(p) {
                let xa = ir.bin(BinOp::Mul, mx, map[q.index()], s);
                return Some(ir.bin(op, map[b.index()], xa, s));
            }
        }
        None
    })
}

// x·n…/(x·d…) → n…/d…,  |x|·n…/(x·d…) → (x < 0 ? −1 : 1)·n…/d…   over whole product/quotient trees, the
// divisors left divided one by one where they may be tiny or huge (as `quotient-chain`)
fn cancel_common(a: &Analysis) -> (Ir, NodeId, bool) {
    let (f, lists, ranges) = (&a.f, a.wide_lists(), a.ranges());
    let ir0 = &f.ir;
    // Only whole trees: an operand of a flattened product is rebuilt with it.
    let inner = list_operands(ir0, lists);
    rebuild(f, |ir, map, id, _| {
        let (num, den) = lists[id.index()].as_ref().filter(|_| !inner[id.index()])?;
        let (mut num, mut den) = (num.clone(), den.clone());
        let mut signs = vec![];
        let mut cancelled = false;
        let mut i = 0;
        while i < num.len() {
            let abs_of = match *ir0.node(num[i]) {
                Node::Call(Builtin::Abs, [x, ..]) => Some(x),
                _ => None,
            };
            if let Some(j) = den.iter().position(|d| *d == num[i]) {
                num.remove(i);
                den.remove(j);
                cancelled = true;
            } else if let Some(j) = abs_of.and_then(|x| den.iter().position(|d| *d == x)) {
                signs.push(den.remove(j));
                num.remove(i);
                cancelled = true;
            } else {
                i += 1;
            }
        }
        if !cancelled {
            return None;
        }
        let s = ir0.span(id);
        let (safe_den, unsafe_den): (Vec<NodeId>, Vec<NodeId>) = den.iter().partition(|d| safe(ranges[d.index()]));
        let v = divide_apart(ir, map, &num, &safe_den, &unsafe_den, s);
        Some(signs.iter().fold(v, |v, x| {
            let zero = ir.konst(0.0, s);
            let neg = ir.call(Builtin::Lt, &[map[x.index()], zero], s);
            let (m1, p1) = (ir.konst(-1.0, s), ir.konst(1.0, s));
            let sg = ir.call(Builtin::Select, &[neg, m1, p1], s);
            ir.bin(BinOp::Mul, sg, v, s)
        }))
    })
}

// x·y·n…/(d·e…) → (x/d)·y·n…/e…   over whole product/quotient trees with at least two numerator factors and
// one divisor that may be tiny or huge (x, y, d the first such): a product of two tiny factors (NL·NV ~ 10⁻⁴⁰⁰,
// 0 in f64) meets the divisor that scales it back (NL + NV − NL·NV) one factor at a time
fn interleave_quotient(a: &Analysis) -> (Ir, NodeId, bool) {
    let (f, lists, ranges) = (&a.f, a.wide_lists(), a.ranges());
    let ir0 = &f.ir;
    let inner = list_operands(ir0, lists);
    rebuild(f, |ir, map, id, _| {
        let (num, den) = lists[id.index()].as_ref().filter(|_| !inner[id.index()])?;
        let risky = |x: &NodeId| !safe(ranges[x.index()]);
        let tiny_num: Vec<usize> = (0..num.len()).filter(|&i| risky(&num[i])).collect();
        let j = den.iter().position(risky)?;
        if tiny_num.len() < 2 {
            return None;
        }
        let s = ir0.span(id);
        let first = ir.bin(BinOp::Div, map[num[tiny_num[0]].index()], map[den[j].index()], s);
        let rest: Vec<NodeId> = num.iter().enumerate().filter(|(i, _)| *i != tiny_num[0]).map(|(_, x)| *x).collect();
        let v = rest.iter().fold(first, |v, x| ir.bin(BinOp::Mul, v, map[x.index()], s));
        let others: Vec<NodeId> = den.iter().enumerate().filter(|(i, _)| *i != j).map(|(_, x)| *x).collect();
        let (safe_den, unsafe_den): (Vec<NodeId>, Vec<NodeId>) = others.iter().partition(|d| safe(ranges[d.index()]));
        Some(divide_by(ir, map, v, &safe_den, &unsafe_den, s))
    })
}

/// The direction inputs, axis by axis.
const AXES: [[Input; 3]; 2] = [[Input::Lx, Input::Ly, Input::Lz], [Input::Vx, Input::Vy, Input::Vz]];

/// (direction, axis) of an input node.
fn direction_input(ir: &Ir, x: NodeId) -> Option<(usize, usize)> {
    let Node::Input(i) = *ir.node(x) else { return None };
    (0..2).find_map(|d| AXES[d].iter().position(|&j| j == i).map(|k| (d, k)))
}

/// The terms of a sum tree of `+`.
fn addends(ir: &Ir, x: NodeId, out: &mut Vec<NodeId>) {
    crate::base::stack::deep(|| match *ir.node(x) {
        Node::Binary(BinOp::Add, p, q) => {
            addends(ir, p, out);
            addends(ir, q, out);
        }
        _ => out.push(x),
    })
}

/// The sum `L_k + V_k` a base of the normalised half vector is, or is scaled from (`scaled-norm`: `(L_k + V_k)·s`):
/// the axis k.
fn half_axis(ir: &Ir, b: NodeId) -> Option<(usize, NodeId)> {
    let w = match *ir.node(b) {
        Node::Binary(BinOp::Mul, w, _) if matches!(ir.node(w), Node::Binary(BinOp::Add, ..)) => w,
        _ => b,
    };
    let Node::Binary(BinOp::Add, p, q) = *ir.node(w) else { return None };
    let ((dp, kp), (dq, kq)) = (direction_input(ir, p)?, direction_input(ir, q)?);
    (dp != dq && kp == kq).then_some((kp, w))
}

/// `1 − D` where D = u_x·h_x + u_y·h_y + u_z·h_z, u one of the directions L, V and h = (L + V)/|L + V| the half
/// vector (each h_k a normalised component whose base is L_k + V_k, scaled or not): (u's direction, the sums
/// L_k + V_k by axis).
fn half_dot(ir: &Ir, d: NodeId) -> Option<(usize, [NodeId; 3])> {
    let mut terms = vec![];
    addends(ir, d, &mut terms);
    if terms.len() != 3 {
        return None;
    }
    let mut dir = None;
    let mut w: [Option<NodeId>; 3] = [None; 3];
    let mut sum = None;
    for t in terms {
        let Node::Binary(BinOp::Mul, p, q) = *ir.node(t) else { return None };
        let (u, h) = if direction_input(ir, p).is_some() { (p, q) } else { (q, p) };
        let (du, ku) = direction_input(ir, u)?;
        let unit = unit_component(ir, h)?;
        let (kw, wk) = half_axis(ir, unit.x)?;
        if kw != ku || dir.is_some_and(|d| d != du) || sum.is_some_and(|s| s != unit.sum) || w[ku].is_some() {
            return None;
        }
        dir = Some(du);
        sum = Some(unit.sum);
        w[ku] = Some(wk);
    }
    Some((dir?, [w[0]?, w[1]?, w[2]?]))
}

// 1 − u·h → (|u × o|² + (1 − |u|²)·|w|²)/(|w|·(|w| + u·w))   where u·h > 1/2, else as written; w = L + V,
// h = w/|w|, o the other direction. Exact in real arithmetic for any u, o (Lagrange: |u|²|w|² − (u·w)² =
// |u × w|², u × w = u × o), so |w|² − (u·w)² = |u × o|² + (1 − |u|²)|w|². The cross product's components
// as Kahan's differences of products (fma), 1 − |u|² in double-double (|u|² − 1 is a few ulps of an f64
// direction, and matters where 1 − u·h is that small).
fn half_complement(a: &Analysis) -> (Ir, NodeId, bool) {
    let f = &a.f;
    let ir0 = &f.ir;
    rebuild(f, |ir, map, id, n| {
        let Node::Binary(BinOp::Sub, one, d) = n else { return None };
        if !is_const(ir0, one, 1.0) {
            return None;
        }
        let (du, w) = half_dot(ir0, d)?;
        let s = ir0.span(id);
        let (u, o): (Vec<NodeId>, Vec<NodeId>) = {
            let inp = |ir: &mut Ir, d: usize| AXES[d].iter().map(|&i| ir.input(i, s)).collect::<Vec<_>>();
            (inp(ir, du), inp(ir, 1 - du))
        };
        let w: Vec<NodeId> = w.iter().map(|x| map[x.index()]).collect();
        let mut e = IrEmit::new(ir, s);
        // u × o by Kahan's difference of products: a·b − c·d = (a·b − c·d rounded through fma) + fma's remainder.
        let dop = |e: &mut IrEmit, a: NodeId, b: NodeId, c: NodeId, d: NodeId| {
            let cd = e.mul(c, d);
            let err = {
                let n = e.neg(c);
                e.fma(n, d, cd)
            };
            let n = e.neg(cd);
            let hi = e.fma(a, b, n);
            e.add(hi, err)
        };
        let cx = dop(&mut e, u[1], o[2], u[2], o[1]);
        let cy = dop(&mut e, u[2], o[0], u[0], o[2]);
        let cz = dop(&mut e, u[0], o[1], u[1], o[0]);
        let sq = |e: &mut IrEmit, x: NodeId| e.mul(x, x);
        let (qx, qy, qz) = (sq(&mut e, cx), sq(&mut e, cy), sq(&mut e, cz));
        let cross = {
            let t = e.add(qx, qy);
            e.add(t, qz)
        };
        // 1 − |u|²: each square exact as a pair (fma's remainder), the three summed by 2Sum; 1 − s is exact for
        // |u|² in [1/2, 2] (Sterbenz), and the low parts, each below an ulp of 1, are added after it.
        let mut pairs = vec![];
        for &x in &u {
            pairs.push(e.two_prod(x, x));
        }
        let (s1, e1) = dd::two_sum(&mut e, pairs[0].0, pairs[1].0);
        let (s2, e2) = dd::two_sum(&mut e, s1, pairs[2].0);
        let slack = {
            let one = e.konst(1.0);
            let hi = e.sub(one, s2);
            let lo = [e2, pairs[0].1, pairs[1].1, pairs[2].1].into_iter().fold(e1, |acc, t| e.add(acc, t));
            e.sub(hi, lo)
        };
        let ww = {
            let (a, b, c) = (sq(&mut e, w[0]), sq(&mut e, w[1]), sq(&mut e, w[2]));
            let t = e.add(a, b);
            e.add(t, c)
        };
        let len = e.sqrt(ww);
        let uw = {
            let (a, b, c) = (e.mul(u[0], w[0]), e.mul(u[1], w[1]), e.mul(u[2], w[2]));
            let t = e.add(a, b);
            e.add(t, c)
        };
        let num = {
            let t = e.mul(slack, ww);
            e.add(cross, t)
        };
        let den = {
            let t = e.add(len, uw);
            e.mul(len, t)
        };
        let exact = e.div(num, den);
        let half = e.konst(0.5);
        let dot = map[d.index()];
        let near = ir.call(Builtin::Lt, &[half, dot], s);
        let plain = ir.bin(BinOp::Sub, map[one.index()], dot, s);
        Some(ir.call(Builtin::Select, &[near, exact, plain], s))
    })
}

#[cfg(test)]
mod tests {
    use super::super::tests::parse;
    use super::*;
    use crate::backend::interp::Interp;
    use crate::backend::Evaluator;
    use crate::numerics::robust::sample;
    use crate::numerics::truth;

    /// Bits of error of `g` at the sample of `f`'s domain (fixed seed), against the truth of `f`, where it is
    /// finite, nonzero and well conditioned (κ ≤ 16): (the worst, how many points), asserting on the way that
    /// `g` equals `f` in real arithmetic at every point where `f`'s value is finite.
    fn exact_and_error(f: &Formula, g: &Formula, seed: u64) -> (f64, usize) {
        let ev = Interp::new(g);
        let (mut worst, mut n) = (0f64, 0);
        for pt in sample(f, &[], 4000, seed) {
            let (a, b) = (truth::eval(f, &pt.x, &pt.p), truth::eval(g, &pt.x, &pt.p));
            if !a.is_finite() || a == 0.0 {
                continue;
            }
            assert!((a - b).abs() <= 1e-12 * a.abs(), "{a} vs {b} at {pt:?}\n{}", g.to_text());
            if crate::numerics::robust::condition_ulps(f, &pt, a) > 16.0 {
                continue;
            }
            n += 1;
            let v = Evaluator::eval(&ev, &pt.x, &pt.p);
            worst = worst.max(crate::numerics::robust::ulps(v, a));
        }
        ((worst + 1.0).log2().min(64.0), n)
    }

    /// `src` parsed, simplified and its normalisations scaled (`scaled-norm`), as the pass has it when the
    /// vector rules run.
    fn scaled(src: &str) -> Formula {
        let f = parse(src);
        super::super::scale::ScaledNorm.apply_to(&f, None).unwrap_or(f)
    }

    #[test]
    fn sine_square_takes_the_other_squares_of_a_normalised_vector() {
        let f = scaled(SineSquare.example().before);
        let g = SineSquare.apply_to(&f, None).unwrap();
        let t = g.to_program_text();
        // GGX's D at α = 0.001 near the normal: NH²(α² − 1) + 1 as ((L + V)_x² + (L + V)_y²)/|L + V|² + α²·NH².
        assert!(t.contains("t5 * t5 + t6 * t6") && !t.contains("- 1) + 1"), "{t}");
        let (before, n) = exact_and_error(&f, &f, 7);
        let (after, _) = exact_and_error(&f, &g, 7);
        assert!(n > 1000 && before > 12.0 && after < 4.0, "{before} → {after} bits at {n} points");
        // 1 − c² of an input: one rounding; 1 − c alone is not a square's complement.
        let t = SineSquare.apply_to(&parse("1 - NL*NL"), None).unwrap().to_program_text();
        assert!(t.contains("fma(-nl, nl, 1)"), "{t}");
        assert!(SineSquare.apply_to(&parse("1 - NL*NV"), None).is_none());
        assert!(SineSquare.apply_to(&parse("NL*NL*(NV - 2) + 1"), None).is_none());
    }

    #[test]
    fn cancel_tan_multiplies_out_a_quotient_by_the_same_factor() {
        let f = parse(CancelTan.example().before);
        let g = CancelTan.apply_to(&f, None).unwrap();
        // NH² underflows at NH = 1e-200: (1 − 0)/0 = ∞ times 0 was NaN; a·a·0 + 1 is 1. Then 1 − NH² of an
        // input is sine-square's: one rounding.
        let h = SineSquare.apply_to(&g, None).unwrap();
        let (before, n) = exact_and_error(&f, &f, 3);
        let (tan, _) = exact_and_error(&f, &g, 3);
        let (after, _) = exact_and_error(&f, &h, 3);
        assert!(n > 1000 && before == 64.0 && tan < 64.0 && after < 4.0, "{before} → {tan} → {after} bits at {n} points");
        assert!(CancelTan.apply_to(&parse("NH * (NL + 1/NV)"), None).is_none());
    }

    #[test]
    fn cancel_common_cancels_factors_and_signs() {
        let f = parse(CancelCommon.example().before);
        let g = CancelCommon.apply_to(&f, None).unwrap();
        let (before, n) = exact_and_error(&f, &g, 5);
        let (after, _) = exact_and_error(&f, &f, 5);
        // (before/after named by formula: g is the rewrite) NL·NV underflows: 0·(1/0) was NaN.
        assert!(n > 1000 && before < 4.0 && after == 64.0, "{after} → {before} bits at {n} points");
        // |x|/x is the sign of x (the written form is 0/0 at x = 0).
        let g = CancelCommon.apply_to(&parse("let x = NL - 0.5\nabs(x)*NV/(x*NH)"), None).unwrap();
        let t = g.to_program_text();
        assert!(t.contains("< 0 ? -1 : 1") && !t.contains("abs("), "{t}");
        assert!(CancelCommon.apply_to(&parse("NL*NV/(NH*VH)"), None).is_none());
    }

    #[test]
    fn interleave_quotient_divides_between_two_tiny_factors() {
        let f = parse(InterleaveQuotient.example().before);
        let g = InterleaveQuotient.apply_to(&f, None).unwrap();
        // NL = NV = 1e-200: NL·NV = 0 where the value is 5e-201.
        let (before, n) = exact_and_error(&f, &f, 13);
        let (after, _) = exact_and_error(&f, &g, 13);
        assert!(n > 1000 && before > 50.0 && after < 4.0, "{before} → {after} bits at {n} points");
        assert!(InterleaveQuotient.apply_to(&parse("NL*NV/2"), None).is_none());
        assert!(InterleaveQuotient.apply_to(&parse("NL/(NV*NH)"), None).is_none());
    }

    #[test]
    fn half_complement_is_exact_for_directions_that_are_not_unit() {
        let f = scaled(HalfComplement.example().before);
        let g = HalfComplement.apply_to(&f, None).unwrap();
        // Where 1 − V·H is small, a 1-ulp change of a direction's length moves it by many ulps (ill-conditioned,
        // left out); the well-conditioned points gain most of a bit at the fifth power.
        let (before, n) = exact_and_error(&f, &f, 9);
        let (after, _) = exact_and_error(&f, &g, 9);
        assert!(n > 1000 && after < before - 0.5 && after < 4.6, "{before} → {after} bits at {n} points");
        // L·H as well; not a dot product with another vector.
        let lh = HalfComplement.example().before.replace("(Vx*(x/len) + Vy*(y/len) + Vz*(z/len))", "(Lx*(x/len) + Ly*(y/len) + Lz*(z/len))");
        assert!(HalfComplement.apply_to(&parse(&lh), None).is_some());
        let other = HalfComplement.example().before.replace("(Vx*(x/len) + Vy*(y/len) + Vz*(z/len))", "(Vx*(x/len) + Vy*(y/len) + Lz*(z/len))");
        assert!(HalfComplement.apply_to(&parse(&other), None).is_none());
    }
}
