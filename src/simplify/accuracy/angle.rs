//! The angle family: forms for direction-based formulas (BRDF Explorer's models read L and V, normalise
//! vectors and raise cosines to powers), each exact in real arithmetic (`one-minus-power`, `norm-cancel`;
//! described in [`super`]).

use super::finish;
use super::rule::{Example, Rule, Sites, Source};
use crate::builtins::Builtin;
use crate::ir::{BinOp, Formula, Ir, Node, NodeId};
use crate::simplify::emit::IrEmit;
use crate::simplify::rewrite::{rebuild, Analysis};
use std::collections::HashMap;

/// `one-minus-power` (module docs of [`super`]).
pub(crate) struct OneMinusPower;

impl Rule for OneMinusPower {
    fn name(&self) -> &'static str {
        "one-minus-power"
    }
    fn doc(&self) -> &'static str {
        "1 - m^k as (1 - m)*(1 + m + ... + m^(k-1)), 1 - m read as x where m = 1 - x: no cancellation near m = 1"
    }
    fn sites(&self) -> Sites {
        Sites::Everywhere
    }
    fn apply(&self, _: &Source, a: &Analysis, _: Option<usize>) -> Option<Formula> {
        finish(a, one_minus_power(a))
    }
    fn example(&self) -> Example {
        Example { before: "let m = 1 - (NL + 1)/4\n1 - m^5", bake: &[], site: None, shows: " * (1 + t" }
    }
}

/// Most factors of a power `one-minus-power` expands: k − 1 multiply-adds replace the chain's ~log₂ k products.
const MAX_POWER: usize = 16;

/// The base m and the exponent k ≥ 2 of `x` when it is m·m·…·m (a multiplication chain, as the simplifier
/// writes an integer power) or pow(m, k) with k a small integer constant.
fn power_of(a: &Analysis, x: NodeId) -> Option<(NodeId, usize)> {
    let f = &a.f;
    if let Node::Call(Builtin::Pow, [m, k, _]) = *f.ir.node(x) {
        let k = f.ir.node(k).as_const()?;
        return (k.fract() == 0.0 && (2.0..=MAX_POWER as f64).contains(&k)).then_some((m, k as usize));
    }
    let (num, den) = a.lists()[x.index()].as_ref()?;
    let m = *num.first()?;
    (den.is_empty() && num.len() >= 2 && num.iter().all(|&y| y == m)).then_some((m, num.len()))
}

// 1 − m^k → d·(1 + m·(1 + m·(… (1 + m)))),  d = x where m = 1 − x, else d = 1 − m
fn one_minus_power(a: &Analysis) -> (Ir, NodeId, bool) {
    let f = &a.f;
    let inv = a.invariant();
    rebuild(f, |ir, map, id, n| {
        let Node::Binary(BinOp::Sub, one, p) = n else { return None };
        if f.ir.node(one).as_const() != Some(1.0) || inv[id.index()] {
            return None;
        }
        let (m, k) = power_of(a, p)?;
        let sp = f.ir.span(id);
        let d = match *f.ir.node(m) {
            Node::Binary(BinOp::Sub, c, x) if f.ir.node(c).as_const() == Some(1.0) => map[x.index()],
            _ => ir.bin(BinOp::Sub, map[one.index()], map[m.index()], sp),
        };
        let (mv, c1) = (map[m.index()], ir.konst(1.0, sp));
        let mut acc = ir.bin(BinOp::Add, c1, mv, sp);
        for _ in 2..k {
            let t = ir.bin(BinOp::Mul, mv, acc, sp);
            acc = ir.bin(BinOp::Add, c1, t, sp);
        }
        Some(ir.bin(BinOp::Mul, d, acc, sp))
    })
}

/// `norm-cancel` (module docs of [`super`]).
pub(crate) struct NormCancel;

impl Rule for NormCancel {
    fn name(&self) -> &'static str {
        "norm-cancel"
    }
    fn doc(&self) -> &'static str {
        "a quotient of the same degree in a normalised vector's components w/|w| computed from w itself: the norm cancels"
    }
    fn sites(&self) -> Sites {
        Sites::Everywhere
    }
    fn apply(&self, _: &Source, a: &Analysis, _: Option<usize>) -> Option<Formula> {
        finish(a, norm_cancel(a))
    }
    fn example(&self) -> Example {
        Example {
            before: "let x = Lx + Vx\nlet z = Lz + Vz\nlet s = sqrt(x*x + Ly*Ly + z*z)\n(x/s)*(x/s) / ((z/s)*(z/s))",
            bake: &[],
            site: None,
            shows: "max(abs(",
        }
    }
}

/// The components a, b, … of `x` when it is √(a·a + b·b + …) with at least two squares: a vector's length.
fn norm_components(ir: &Ir, x: NodeId) -> Option<Vec<NodeId>> {
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
    let Node::Call(Builtin::Sqrt, [sum, ..]) = *ir.node(x) else { return None };
    let mut out = vec![];
    (squares(ir, sum, &mut out) && out.len() >= 2).then_some(out)
}

/// Per node, whether it reads `s`, and its degree in `s` when it is homogeneous: s^d times an expression
/// that does not read s (products and quotients add and subtract degrees, a sum needs equal ones, √ halves an
/// even one; abs and a select on a condition without s keep them). `None`: not homogeneous in s.
fn degrees(f: &Formula, s: NodeId) -> (Vec<bool>, Vec<Option<i32>>) {
    let mut reads = vec![false; f.ir.len()];
    let mut deg: Vec<Option<i32>> = vec![Some(0); f.ir.len()];
    for id in f.ir.ids() {
        let n = *f.ir.node(id);
        let mut any = id == s;
        n.for_each_arg(|a| any |= reads[a.index()]);
        reads[id.index()] = any;
        if !any {
            continue;
        }
        let d = |x: NodeId| deg[x.index()];
        deg[id.index()] = if id == s {
            Some(1)
        } else {
            match n {
                Node::Neg(a) | Node::Call(Builtin::Abs, [a, ..]) => d(a),
                Node::Binary(BinOp::Add | BinOp::Sub, a, b) => d(a).filter(|&x| Some(x) == d(b)),
                Node::Binary(BinOp::Mul, a, b) => d(a).zip(d(b)).map(|(x, y)| x + y),
                Node::Binary(BinOp::Div, a, b) => d(a).zip(d(b)).map(|(x, y)| x - y),
                Node::Call(Builtin::Sqrt, [a, ..]) => d(a).filter(|x| x % 2 == 0).map(|x| x / 2),
                Node::Call(Builtin::Select, [c, t, e]) if !reads[c.index()] => d(t).filter(|&x| Some(x) == d(e)),
                _ => None,
            }
        };
    }
    (reads, deg)
}

/// `x` copied into the new arena with `s` replaced by `m` (a new-arena node; nodes that do not read s are `map`'s).
fn strip(f: &Formula, ir: &mut Ir, map: &[NodeId], reads: &[bool], (s, m): (NodeId, NodeId), x: NodeId, memo: &mut HashMap<NodeId, NodeId>) -> NodeId {
    crate::base::stack::deep(|| {
        if !reads[x.index()] {
            return map[x.index()];
        }
        if let Some(&y) = memo.get(&x) {
            return y;
        }
        let y = if x == s {
            m
        } else {
            let n = f.ir.node(x).map_args(|a| strip(f, ir, map, reads, (s, m), a, memo));
            ir.push(n, f.ir.span(x))
        };
        memo.insert(x, y);
        y
    })
}

// n/d → n(m)/d(m), n and d of the same degree k in a norm s = |w| = √(a² + b² + …) (each of the form s^k·n′,
// s^k·d′), s replaced by m = max(|a|, |b|, …) > 0: n(m)/d(m) = m^k·n′/(m^k·d′) = n/d. (w_x/s)² / (w_z/s)² →
// (w_x/m)² / (w_z/m)²: one rounding per component instead of the squares', their sum's, the sqrt's and the
// division's, and the components scaled like w/s (to [−1, 1], the largest ±1), so none underflows where w/s does not
fn norm_cancel(a: &Analysis) -> (Ir, NodeId, bool) {
    let f = &a.f;
    type Norm = (NodeId, Vec<NodeId>, (Vec<bool>, Vec<Option<i32>>));
    let norms: Vec<Norm> = f.ir.ids().filter_map(|s| Some((s, norm_components(&f.ir, s)?, degrees(f, s)))).collect();
    let mut maxes: HashMap<NodeId, NodeId> = HashMap::new();
    rebuild(f, |ir, map, id, n| {
        let Node::Binary(BinOp::Div, p, q) = n else { return None };
        let (s, comps, (reads, _)) = norms.iter().find(|(_, _, (reads, deg))| {
            (reads[p.index()] || reads[q.index()]) && deg[p.index()].is_some() && deg[p.index()] == deg[q.index()]
        })?;
        let sp = f.ir.span(id);
        let m = *maxes.entry(*s).or_insert_with(|| {
            let mags: Vec<NodeId> = comps.iter().map(|c| ir.call(Builtin::Abs, &[map[c.index()]], sp)).collect();
            mags[1..].iter().fold(mags[0], |acc, v| ir.call(Builtin::Max, &[acc, *v], sp))
        });
        let mut memo = HashMap::new();
        let p2 = strip(f, ir, map, reads, (*s, m), p, &mut memo);
        let q2 = strip(f, ir, map, reads, (*s, m), q, &mut memo);
        Some(ir.bin(BinOp::Div, p2, q2, sp))
    })
}

/// `compensated-exponent` (module docs of [`super`]).
pub(crate) struct CompensatedExponent;

impl Rule for CompensatedExponent {
    fn name(&self) -> &'static str {
        "compensated-exponent"
    }
    fn doc(&self) -> &'static str {
        "exp(E) as exp(E)*(1 + e), e the rounding error of E's + - * / tree (norms cancelled first): exp no longer amplifies it"
    }
    fn sites(&self) -> Sites {
        Sites::Everywhere
    }
    fn apply(&self, _: &Source, a: &Analysis, _: Option<usize>) -> Option<Formula> {
        // The norms cancelled first (`norm-cancel`): fewer roundings to carry, and cheaper.
        let cancelled = finish(a, norm_cancel(a)).map(Analysis::new);
        let a = cancelled.as_ref().unwrap_or(a);
        finish(a, compensated_exponent(a))
    }
    fn example(&self) -> Example {
        Example { before: "let x = Lx + Vx\nlet z = Lz + Vz\nexp(-(x*x)/(z*z))", bake: &[], site: None, shows: "fma(" }
    }
}

// exp(E) → exp(E) + exp(E)·e′, expmuldiv(E, b, c) → expmuldiv(E, b + b·e′, c): e the first-order rounding error
// of E's `+ − × /` tree below the exponential ([`rounding_error`](super::compensated)), e′ = e where |e| < ½
// (else 0: an exponent that overflowed or divided by 0 has no error to carry, and a NaN tail must not spoil a 0)
fn compensated_exponent(a: &Analysis) -> (Ir, NodeId, bool) {
    let (f, inv, ranges) = (&a.f, a.invariant(), a.ranges());
    rebuild(f, |ir, map, id, n| {
        let Node::Call(call @ (Builtin::Exp | Builtin::ExpMulDiv), [arg, b, c]) = n else { return None };
        if inv[arg.index()] || !matches!(f.ir.node(arg), Node::Binary(..) | Node::Neg(_)) {
            return None;
        }
        let sp = f.ir.span(id);
        let e = super::compensated::rounding_error(f, ranges, ir, map, (arg, map[arg.index()]), &mut vec![None; f.ir.len()], sp)?;
        let (half, zero) = (ir.konst(0.5, sp), ir.konst(0.0, sp));
        let mag = ir.call(Builtin::Abs, &[e], sp);
        let small = ir.call(Builtin::Lt, &[mag, half], sp);
        let e = ir.call(Builtin::Select, &[small, e, zero], sp);
        Some(if call == Builtin::Exp {
            let v = ir.call(Builtin::Exp, &[map[arg.index()]], sp);
            ir.call(Builtin::Fma, &[v, e, v], sp)
        } else {
            let bv = map[b.index()];
            let b2 = ir.call(Builtin::Fma, &[bv, e, bv], sp);
            ir.call(Builtin::ExpMulDiv, &[map[arg.index()], b2, map[c.index()]], sp)
        })
    })
}

/// `one-minus-exp` (module docs of [`super`]).
pub(crate) struct OneMinusExp;

impl Rule for OneMinusExp {
    fn name(&self) -> &'static str {
        "one-minus-exp"
    }
    fn doc(&self) -> &'static str {
        "1 - exp(E) as (1 - u)*E/ln(u), u = exp(E), for |E| < 1/2 (Kahan's expm1; -E*(1 + E/2) where u rounds to 1): no cancellation at small E"
    }
    fn sites(&self) -> Sites {
        Sites::Everywhere
    }
    fn apply(&self, _: &Source, a: &Analysis, _: Option<usize>) -> Option<Formula> {
        finish(a, one_minus_exp(a))
    }
    fn example(&self) -> Example {
        // E in [−0.26, −0.01], where the truth of 1 − exp(E) (double-double) holds it to ~2⁻¹⁰⁶ relative.
        Example { before: "1 - exp(-NH/4 - 0.01)", bake: &[], site: None, shows: "ln(" }
    }
}

// 1 − exp(E) → |E| < ½ ? (u == 1 ? −E·(1 + E/2) : (1 − u)·E/ln(u)) : 1 − u,  u = exp(E): Kahan's expm1 through
// exp and ln, exact in reals ((1 − e^E)·E/E; the series where u rounds to 1 is within 2⁻¹⁰⁷), where 1 − u
// cancels to the rounding of u (Nishino's 1 − exp(−k·NH^n))
fn one_minus_exp(a: &Analysis) -> (Ir, NodeId, bool) {
    let f = &a.f;
    let inv = a.invariant();
    rebuild(f, |ir, map, id, n| {
        let Node::Binary(BinOp::Sub, one, ex) = n else { return None };
        let Node::Call(Builtin::Exp, [e, ..]) = *f.ir.node(ex) else { return None };
        if f.ir.node(one).as_const() != Some(1.0) || inv[id.index()] {
            return None;
        }
        let sp = f.ir.span(id);
        let (ev, c1) = (map[e.index()], map[one.index()]);
        let u = map[ex.index()];
        let plain = ir.bin(BinOp::Sub, c1, u, sp);
        let half = ir.konst(0.5, sp);
        let lnu = ir.call(Builtin::Ln, &[u], sp);
        let q = ir.bin(BinOp::Mul, plain, ev, sp);
        let kahan = ir.bin(BinOp::Div, q, lnu, sp);
        // u rounds to 1 where |E| < 2⁻⁵³: there −E·(1 + E/2), off by E²/6 relative (< 2⁻¹⁰⁷).
        let at_one = ir.call(Builtin::Eq, &[u, c1], sp);
        let ne = ir.neg(ev, sp);
        let h = ir.bin(BinOp::Mul, ev, half, sp);
        let h1 = ir.bin(BinOp::Add, c1, h, sp);
        let series = ir.bin(BinOp::Mul, ne, h1, sp);
        let small_e = ir.call(Builtin::Select, &[at_one, series, kahan], sp);
        let mag = ir.call(Builtin::Abs, &[ev], sp);
        let small = ir.call(Builtin::Lt, &[mag, half], sp);
        Some(ir.call(Builtin::Select, &[small, small_e, plain], sp))
    })
}

/// `tan-pole` (module docs of [`super`]).
pub(crate) struct TanPole;

impl Rule for TanPole {
    fn name(&self) -> &'static str {
        "tan-pole"
    }
    fn doc(&self) -> &'static str {
        "tan(x) of an angle near pi/2 as 1/tan(pi/2 - x), pi/2 - x from x's double-double (acos's acoslo tail): the distance to the pole, not a rounded angle"
    }
    fn sites(&self) -> Sites {
        Sites::Everywhere
    }
    fn apply(&self, _: &Source, a: &Analysis, _: Option<usize>) -> Option<Formula> {
        finish(a, tan_pole(a))
    }
    fn example(&self) -> Example {
        // Angles in [0.72, 1.05], on both sides of π/4, where the truth holds them to ~2⁻¹⁰⁶ relative.
        Example { before: "let a = acos(0.5 + NL/4)\nlet b = acos(0.5 + NV/4)\ntan((max(a, b) + min(a, b))/2)", bake: &[], site: None, shows: "acoslo(" }
    }
}

/// π/2 as a double-double.
const HALF_PI: (f64, f64) = (std::f64::consts::FRAC_PI_2, 6.123233995736766e-17);

/// The low part of old node `x` as a new-arena node (`x`'s exact value minus its f64 value `map[x]`), where `x`
/// is built from acos calls (their `acoslo` tails) by min, max, sums and products with powers of two; `None`
/// where there is none to carry. A min or max picks its operand's tail by comparing the double-doubles.
fn angle_low(f: &Formula, ir: &mut Ir, map: &[NodeId], x: NodeId, memo: &mut HashMap<NodeId, Option<NodeId>>) -> Option<NodeId> {
    crate::base::stack::deep(|| {
        if let Some(&l) = memo.get(&x) {
            return l;
        }
        let sp = f.ir.span(x);
        let mut low = |ir: &mut Ir, y: NodeId| angle_low(f, ir, map, y, memo);
        let zero = |ir: &mut Ir| ir.konst(0.0, sp);
        let l = match *f.ir.node(x) {
            Node::Call(Builtin::Acos, [z, ..]) => Some(ir.call(Builtin::AcosLo, &[map[z.index()]], sp)),
            Node::Call(b @ (Builtin::Min | Builtin::Max), [p, q, _]) => {
                let (lp, lq) = (low(ir, p), low(ir, q));
                if lp.is_none() && lq.is_none() {
                    None
                } else {
                    let (lp, lq) = (lp.unwrap_or_else(|| zero(ir)), lq.unwrap_or_else(|| zero(ir)));
                    let (hp, hq) = (map[p.index()], map[q.index()]);
                    // p's tail where p is the chosen one: p < q (min) or p > q (max), or equal with the smaller
                    // (larger) tail.
                    let (strict, tie) = if b == Builtin::Min {
                        (ir.call(Builtin::Lt, &[hp, hq], sp), ir.call(Builtin::Le, &[lp, lq], sp))
                    } else {
                        (ir.call(Builtin::Lt, &[hq, hp], sp), ir.call(Builtin::Le, &[lq, lp], sp))
                    };
                    let eq = ir.call(Builtin::Eq, &[hp, hq], sp);
                    let (one, no) = (ir.konst(1.0, sp), zero(ir));
                    let tie = ir.call(Builtin::Select, &[eq, tie, no], sp);
                    let pick = ir.call(Builtin::Select, &[strict, one, tie], sp);
                    Some(ir.call(Builtin::Select, &[pick, lp, lq], sp))
                }
            }
            Node::Binary(op @ (BinOp::Add | BinOp::Sub), p, q) => {
                let (lp, lq) = (low(ir, p), low(ir, q));
                if lp.is_none() && lq.is_none() {
                    None
                } else {
                    let qv = if op == BinOp::Sub { ir.neg(map[q.index()], sp) } else { map[q.index()] };
                    let e = crate::builtins::dd::two_sum_err(&mut IrEmit::new(ir, sp), map[p.index()], qv, map[x.index()]);
                    let e = lp.map_or(e, |l| ir.bin(BinOp::Add, e, l, sp));
                    Some(lq.map_or(e, |l| ir.bin(op, e, l, sp)))
                }
            }
            Node::Binary(BinOp::Mul, p, c) | Node::Binary(BinOp::Mul, c, p)
                if f.ir.node(c).as_const().is_some_and(|k| k != 0.0 && k.is_finite() && k.abs().log2().fract() == 0.0) =>
            {
                low(ir, p).map(|l| ir.bin(BinOp::Mul, l, map[c.index()], sp))
            }
            _ => None,
        };
        memo.insert(x, l);
        l
    })
}

// tan(x) → t = tan(c ? d : x), c ? 1/t : t, with c = π/4 < x and d = (π/2ʰ − x) + (π/2ˡ − xˡ), xˡ x's low part
// ([`angle_low`]): π/2ʰ − x is exact for x in [π/4, π] (Sterbenz), so d is the distance to the pole to a
// rounding, where tan(x) of the rounded angle was off by its whole error over d (Oren–Nayar's tan(β) and
// tan((α + β)/2) at grazing angles: 1.6e16 for 1e20)
fn tan_pole(a: &Analysis) -> (Ir, NodeId, bool) {
    let f = &a.f;
    let mut memo = HashMap::new();
    rebuild(f, |ir, map, id, n| {
        let Node::Call(Builtin::Tan, [x, ..]) = n else { return None };
        let lo = angle_low(f, ir, map, x, &mut memo)?;
        let sp = f.ir.span(id);
        let hi = map[x.index()];
        let (ph, pl, q) = (ir.konst(HALF_PI.0, sp), ir.konst(HALF_PI.1, sp), ir.konst(std::f64::consts::FRAC_PI_4, sp));
        let dh = ir.bin(BinOp::Sub, ph, hi, sp);
        let dl = ir.bin(BinOp::Sub, pl, lo, sp);
        let d = ir.bin(BinOp::Add, dh, dl, sp);
        let c = ir.call(Builtin::Lt, &[q, hi], sp);
        let y = ir.call(Builtin::Select, &[c, d, hi], sp);
        let t = ir.call(Builtin::Tan, &[y], sp);
        let one = ir.konst(1.0, sp);
        let inv = ir.bin(BinOp::Div, one, t, sp);
        Some(ir.call(Builtin::Select, &[c, inv, t], sp))
    })
}

#[cfg(test)]
mod tests {
    use super::super::tests::parse;
    use super::*;
    use crate::backend::interp::Interp;
    use crate::backend::Evaluator;
    use crate::ir::N_INPUTS;
    use crate::numerics::truth;

    /// Random unit directions with z from 1e-300 to 1 (fixed seed), as kernel inputs.
    fn points(n: usize) -> Vec<[f64; N_INPUTS]> {
        let mut r = crate::base::rng::Rng(0x5eed);
        (0..n)
            .map(|_| {
                let z = |r: &mut crate::base::rng::Rng| 10f64.powf(-300.0 * r.unit() * r.unit() * r.unit());
                let (zl, zv) = (z(&mut r), z(&mut r));
                let l = crate::numerics::dir_from_cos(zl, std::f64::consts::TAU * r.unit());
                let v = crate::numerics::dir_from_cos(zv, std::f64::consts::TAU * r.unit());
                crate::numerics::inputs_from_dirs(l, v)
            })
            .collect()
    }

    /// Over `pts`: the largest relative difference of the two formulas' truths (exact in reals: ~1e-25), and
    /// each formula's largest error in ulps against the first one's truth.
    fn compare(f: &Formula, g: &Formula, params: &[f64], pts: &[[f64; N_INPUTS]]) -> (f64, f64, f64) {
        let (ef, eg) = (Interp::new(f), Interp::new(g));
        let (mut rel, mut uf, mut ug) = (0f64, 0f64, 0f64);
        for x in pts {
            let (tf, tg) = (truth::eval(f, x, params), truth::eval(g, x, params));
            if !tf.is_finite() || tf == 0.0 {
                continue;
            }
            rel = rel.max(((tf - tg) / tf).abs());
            uf = uf.max(crate::numerics::robust::ulps(ef.eval(x, params), tf));
            ug = ug.max(crate::numerics::robust::ulps(eg.eval(x, params), tf));
        }
        (rel, uf, ug)
    }

    #[test]
    fn one_minus_power_is_exact_and_has_no_cancellation() {
        // Ashikhmin–Shirley's diffuse factor 1 − (1 − c/2)⁵ at small c.
        let f = parse("let m = 1 - NL/2\nNL <= 0 ? 0 : 1 - m^5");
        let g = OneMinusPower.apply_to(&f, None).unwrap();
        let t = g.to_program_text();
        assert!(t.contains("t1 * (1 + t2 * (1 + t2 * (1 + t2 * (1 + t2))))") && !t.contains("1 - t2 *"), "{t}");
        // The truth of the written form holds 1 − NL/2 to ~2⁻¹⁰⁶: compared where that is far below NL.
        let pts: Vec<_> = points(4000).into_iter().filter(|x| x[0] > 1e-8).collect();
        assert!(pts.len() > 1000);
        let (rel, uf, ug) = compare(&f, &g, &[50.0], &pts);
        assert!(rel < 1e-20, "not exact in reals: {rel:e}");
        assert!(ug <= 4.0 && uf > 1e6, "written {uf} ulp, rewritten {ug} ulp");
        // A base that is not 1 − x: 1 − m stays a subtraction (exact by Sterbenz near m = 1); pow calls too.
        let h = OneMinusPower.apply_to(&parse("1 - pow(NH, 3)"), None).unwrap().to_program_text();
        assert!(h.contains("(1 - nh) * (1 + nh * (1 + nh))"), "{h}");
        assert!(OneMinusPower.apply_to(&parse("2 - NH^3"), None).is_none());
        assert!(OneMinusPower.apply_to(&parse("1 - NH*NL"), None).is_none());
    }

    #[test]
    fn norm_cancel_is_exact_and_drops_the_norms_roundings() {
        // Ward's exponent: (hx²/ax² + hy²/ay²)/hz² of H = (L + V)/|L + V|.
        let src = "param ax = 0.1 in 0.01..1\nparam ay = 0.3 in 0.01..1\nlet x = Lx + Vx\nlet y = Ly + Vy\nlet z = Lz + Vz\n\
                   let s = sqrt(x*x + y*y + z*z)\nlet hx = x/s/ax\nlet hy = y/s/ay\nlet hz = z/s\n(hx*hx + hy*hy)/(hz*hz)";
        let f = parse(src);
        let g = NormCancel.apply_to(&f, None).unwrap();
        let t = g.to_program_text();
        assert!(!t.contains("sqrt") && t.contains("max(max(abs("), "the norm is gone: {t}");
        let pts = points(4000);
        let (rel, uf, ug) = compare(&f, &g, &[50.0, 0.1, 0.3], &pts);
        assert!(rel < 1e-25, "not exact in reals: {rel:e}");
        assert!(ug < uf && ug <= 8.0, "written {uf} ulp, rewritten {ug} ulp");
        // Different degrees (1 − hz² is not homogeneous) or a norm that is one square: no site.
        let not = "let x = Lx + Vx\nlet z = Lz + Vz\nlet s = sqrt(x*x + z*z)\n(x/s)*(x/s)/(1 - (z/s)*(z/s))";
        assert!(NormCancel.apply_to(&parse(not), None).is_none());
        assert!(NormCancel.apply_to(&parse("let x = Lx + Vx\nlet s = sqrt(x*x)\n(x/s)/(Lz/s)"), None).is_none());
    }

    #[test]
    fn one_minus_exp_is_exact_and_has_no_cancellation() {
        // Nishino's 1 − exp(−k·NH^n) where k·NH^n is small.
        let f = parse("param k = 2 in 0.1..10\n1 - exp(-k * NH * NH)");
        let g = OneMinusExp.apply_to(&f, None).unwrap();
        let t = g.to_program_text();
        assert!(t.contains("ln(") && t.matches("exp(").count() == 1, "{t}");
        // The truth of the written form holds e^E to ~2⁻¹⁰⁶ absolute: compared where that is far below |E|.
        let pts: Vec<_> = points(4000).into_iter().filter(|x| x[2] > 1e-4).collect();
        assert!(pts.len() > 1000);
        let (rel, uf, ug) = compare(&f, &g, &[50.0, 2.0], &pts);
        assert!(rel < 1e-20, "not exact in reals: {rel:e}");
        assert!(uf > 1e6 && ug <= 4.0, "written {uf} ulp, rewritten {ug} ulp");
        assert!(OneMinusExp.apply_to(&parse("2 - exp(-NH)"), None).is_none());
    }

    #[test]
    fn tan_pole_is_exact_and_keeps_the_distance_to_the_pole() {
        // Oren–Nayar's tan(β) and tan((α + β)/2), α = max and β = min of the two polar angles.
        let src = "let a = acos(Lz)\nlet b = acos(Vz)\nLz <= 0 || Vz <= 0 ? 0 : tan(min(a, b)) + tan((max(a, b) + min(a, b))/2)";
        let f = parse(src);
        let g = TanPole.apply_to(&f, None).unwrap();
        let t = g.to_program_text();
        assert_eq!(t.matches("acoslo(").count(), 2, "{t}");
        // The truth holds π/2 − acos(z) to ~2⁻¹⁰⁶ absolute (~1e-32): compared where that is far below z.
        let pts: Vec<_> = points(12000).into_iter().filter(|x| x[7].min(x[10]) > 1e-12).collect();
        assert!(pts.len() > 1000);
        let (rel, uf, ug) = compare(&f, &g, &[50.0], &pts);
        assert!(rel < 1e-18, "not exact in reals: {rel:e}");
        assert!(uf > 1e10 && ug <= 8.0, "written {uf} ulp, rewritten {ug} ulp");
        // An angle that is no acos (nothing to carry) is left alone.
        assert!(TanPole.apply_to(&parse("tan(NH * 1.5)"), None).is_none());
    }

    #[test]
    fn compensated_exponent_is_exact_and_carries_the_exponents_error() {
        // Ward's highlight after norm-cancel: exp amplifies the exponent's roundings by its size.
        let src = "param ax = 0.1 in 0.01..1\nparam ay = 0.3 in 0.01..1\nlet x = (Lx + Vx)/ax\nlet y = (Ly + Vy)/ay\n\
                   let z = Lz + Vz\nexp(-(x*x + y*y)/(z*z))";
        let f = parse(src);
        let g = CompensatedExponent.apply_to(&f, None).unwrap();
        let t = g.to_program_text();
        assert!(t.contains("fma(") && t.matches("exp(").count() == 1, "{t}");
        let pts = points(4000);
        let (rel, uf, ug) = compare(&f, &g, &[50.0, 0.05, 0.02], &pts);
        assert!(rel < 1e-25, "not exact in reals: {rel:e}");
        assert!(ug < uf && ug <= 4.0, "written {uf} ulp, rewritten {ug} ulp");
        // An exponent without rounding (a lone input) or without inputs: nothing to carry.
        assert!(CompensatedExponent.apply_to(&parse("exp(-NH)"), None).is_none());
        assert!(CompensatedExponent.apply_to(&parse("exp(-n * 2) * NH"), None).is_none());
    }
}
