//! The overflow and underflow family: forms that keep an intermediate product, quotient or square from
//! leaving the f64 range where the value does not (`split-sqrt`, `quotient-chain`, `scaled-exp`, `smith-g1`,
//! `cancel-min`, `scaled-norm`; each described in [`super`]).

use super::rule::{Example, Rule, Sites, Source};
use super::finish;
use crate::simplify::range::Range;
use crate::simplify::rewrite::{list_operands, balanced_product, divide_apart, divide_by, product, rebuild, safe, Analysis};
use crate::base::span::Span;
use crate::builtins::Builtin;
use crate::ir::{BinOp, Formula, Ir, Node, NodeId};

/// `split-sqrt` (module docs).
pub(crate) struct SplitSqrt;

impl Rule for SplitSqrt {
    fn name(&self) -> &'static str {
        "split-sqrt"
    }
    fn doc(&self) -> &'static str {
        "sqrt(a*b) as sqrt(a)*sqrt(b): no underflow of a*b"
    }
    fn sites(&self) -> Sites {
        Sites::Everywhere
    }
    fn apply(&self, _: &Source, a: &Analysis, _: Option<usize>) -> Option<Formula> {
        finish(a, split_sqrt(a))
    }
    fn example(&self) -> Example {
        Example { before: "1/sqrt(NL*NV)", bake: &[], site: None, shows: "sqrt(clamp(NL, 0, 1)) * sqrt(" }
    }
}

/// `quotient-chain` (module docs).
pub(crate) struct QuotientChain;

impl Rule for QuotientChain {
    fn name(&self) -> &'static str {
        "quotient-chain"
    }
    fn doc(&self) -> &'static str {
        "products/quotients reassociated: divide by each tiny-or-huge factor separately"
    }
    fn sites(&self) -> Sites {
        Sites::EachInTurn
    }
    fn apply(&self, _: &Source, a: &Analysis, site: Option<usize>) -> Option<Formula> {
        finish(a, quotient_chain(a, site))
    }
    fn example(&self) -> Example {
        Example { before: "param m = 0.3 in 0.01..1\n1/(m^2 * NH^4) * exp((NH^2 - 1) / (m^2 * NH^2))", bake: &[], site: Some(0), shows: "/ t2 / nh / nh" }
    }
}

/// `scaled-exp` (module docs).
pub(crate) struct ScaledExp;

impl Rule for ScaledExp {
    fn name(&self) -> &'static str {
        "scaled-exp"
    }
    fn doc(&self) -> &'static str {
        "exp(a)*b/c as expmuldiv(a, b, c): no underflow of exp(a) before b/c rescales it"
    }
    fn sites(&self) -> Sites {
        Sites::EachInTurn
    }
    fn apply(&self, _: &Source, a: &Analysis, site: Option<usize>) -> Option<Formula> {
        finish(a, scaled_exp(a, site.unwrap_or(0)))
    }
    fn example(&self) -> Example {
        Example { before: "param m = 0.3 in 0.01..1\nexp((NH^2 - 1) / (m^2 * NH^2)) / (m*m) / NH^4 / VH / max(NL, NV)", bake: &[], site: Some(1), shows: "expmuldiv(" }
    }
}

/// `smith-g1` (module docs).
pub(crate) struct SmithG1;

impl Rule for SmithG1 {
    fn name(&self) -> &'static str {
        "smith-g1"
    }
    fn doc(&self) -> &'static str {
        "Smith G1 2/(1 + sqrt(1 + A*tan^2)) as 2|c|/(|c| + sqrt(c^2 + A*(1 - c^2))), c/c cancelled where c > 0: no inf/inf at grazing c"
    }
    fn sites(&self) -> Sites {
        Sites::Everywhere
    }
    fn apply(&self, _: &Source, a: &Analysis, _: Option<usize>) -> Option<Formula> {
        finish(a, smith_g1(a))
    }
    fn example(&self) -> Example {
        Example { before: "param a = 0.2 in 0.01..1\nlet g = 2/(1 + sqrt(1 + a*a*((1 - NL*NL)/(NL*NL))))\nNL <= 0 ? 0 : g * NH / (4*NL)", bake: &[], site: None, shows: "(nl + sqrt(" }
    }
}

/// `cancel-min` (module docs).
pub(crate) struct CancelMin;

impl Rule for CancelMin {
    fn name(&self) -> &'static str {
        "cancel-min"
    }
    fn doc(&self) -> &'static str {
        "min(K, c*x, c*y)/(x*y) as (K*d < n*min(x, y) ? K/min(x, y) : n/d)/max(x, y), c = n/d: the limit, not 0/0, at x or y = 0"
    }
    fn sites(&self) -> Sites {
        Sites::Everywhere
    }
    fn apply(&self, _: &Source, a: &Analysis, _: Option<usize>) -> Option<Formula> {
        finish(a, cancel_min(a))
    }
    fn example(&self) -> Example {
        Example { before: "param m = 0.3 in 0.01..1\nlet G = min(1, min(2*NH*NV/VH, 2*NH*NL/VH))\nexp(-NH/m)*G/(3*NL*NV)", bake: &[], site: None, shows: "/ max(nv, nl)" }
    }
}

/// `scaled-norm` (module docs).
pub(crate) struct ScaledNorm;

impl Rule for ScaledNorm {
    fn name(&self) -> &'static str {
        "scaled-norm"
    }
    fn doc(&self) -> &'static str {
        "x/sqrt(a^2 + b^2 + ...) with a tiny vector scaled by 2^600 first: no zero length"
    }
    fn sites(&self) -> Sites {
        Sites::Everywhere
    }
    fn apply(&self, _: &Source, a: &Analysis, _: Option<usize>) -> Option<Formula> {
        finish(a, scaled_norm(a))
    }
    fn example(&self) -> Example {
        Example { before: "let x = Lx + Vx\nlet z = Lz + Vz\nz / sqrt(x*x + z*z)", bake: &[], site: None, shows: "? 4.149515568880993e180 : 1" }
    }
}

// sqrt(a*b) → sqrt(a)*sqrt(b)   when a ≥ +0 and b ≥ +0 (by range, or by a guard around the sqrt)
fn split_sqrt(a: &Analysis) -> (Ir, NodeId, bool) {
    let (f, ranges, guards) = (&a.f, a.ranges(), a.guards());
    rebuild(f, |ir, map, id, n| {
        let Node::Call(Builtin::Sqrt, [x, ..]) = n else { return None };
        let Node::Binary(BinOp::Mul, a, b) = *f.ir.node(x) else { return None };
        let pos = |y: NodeId| ranges[y.index()].nonneg() || guards[id.index()].as_ref().is_some_and(|g| g.contains(&y));
        if !(pos(a) && pos(b)) {
            return None;
        }
        let s = f.ir.span(id);
        let sa = ir.call(Builtin::Sqrt, &[map[a.index()]], s);
        let sb = ir.call(Builtin::Sqrt, &[map[b.index()]], s);
        Some(ir.bin(BinOp::Mul, sa, sb, s))
    })
}

// x / (a*b*…) → x / (safe factors) / a / b / …   dividing by each factor that may be tiny or huge on its own
fn quotient_chain(a: &Analysis, only: Option<usize>) -> (Ir, NodeId, bool) {
    let (f, ranges, lists) = (&a.f, a.ranges(), a.lists());
    let mut site = 0;
    rebuild(f, |ir, map, id, _| {
        let (num, den) = lists[id.index()].as_ref()?;
        let (safe_den, unsafe_den): (Vec<NodeId>, Vec<NodeId>) = den.iter().partition(|d| safe(ranges[d.index()]));
        let separate = unsafe_den.len() >= 2 || (unsafe_den.len() == 1 && !safe_den.is_empty());
        if !separate {
            // At most one unsafe divisor, and nothing it must be kept apart from.
            return None;
        }
        site += 1;
        if only.is_some_and(|k| k + 1 != site) {
            return None;
        }
        Some(divide_apart(ir, map, num, &safe_den, &unsafe_den, f.ir.span(id)))
    })
}

// exp(E)·n₁·…/(d₁·…·d_k) → expmuldiv(E, n₁·…/(d₁·…·d_{k−1}), d_k)   (variant 0; 1: dividing by the safe d_i and
// the exponent's own at once, then by each other that may be tiny or huge in turn, two of them by `two_divisors`; 2: expmuldiv(E/2, expmuldiv(E/2, n₁·…/d₁/…/d_{k−2}, d_{k−1}),
// d_k))
fn scaled_exp(an: &Analysis, variant: usize) -> (Ir, NodeId, bool) {
    let (f, lists) = (&an.f, an.lists());
    rebuild(f, |ir, map, id, old| {
        let (r, rewritten) = scaled_exp_at(an, ir, map, id, old, variant)?;
        let (num, den) = lists[id.index()].as_ref()?;
        Some(if rewritten { pole_guard(an, ir, map, (num, den), r, f.ir.span(id)) } else { r })
    })
}

/// Where a divisor `d` that may be exactly 0 reads inputs no other factor of the product reads (Ward's √NL),
/// the exact value at d = 0 is a pole, ±∞ — e^E > 0 for every finite E, and nothing else there moves with d —
/// while expmuldiv sees b/c = ∞ as an overflowed finite factor and gives 0 where e^E underflows. So
/// `d₁ == 0 || … ? rest/(d₁·…) : r`, `rest` the product's other factors with the exponential taken as 1 (it
/// is positive): ±∞ at a pole, NaN (0/0, as the truth) where the rest vanishes too. `r` unchanged when there
/// is no such divisor (Beckmann's NH is read by the exponent; Cook–Torrance's NL by G beside it).
fn pole_guard(an: &Analysis, ir: &mut Ir, map: &[NodeId], (num, den): (&[NodeId], &[NodeId]), r: NodeId, s: Span) -> NodeId {
    let (f, ranges, reads) = (&an.f, an.ranges(), an.reads());
    let all: Vec<NodeId> = num.iter().chain(den).copied().collect();
    let lone: Vec<NodeId> = den
        .iter()
        .copied()
        .filter(|&d| {
            let rd = ranges[d.index()];
            let others = all.iter().filter(|&&x| x != d).fold(0u16, |m, x| m | reads[x.index()].0);
            let mine = reads[d.index()].0;
            rd.lo <= 0.0 && rd.hi >= 0.0 && mine != 0 && mine & others == 0 && all.iter().filter(|&&x| x == d).count() == 1
        })
        .collect();
    if lone.is_empty() {
        return r;
    }
    let zero = ir.konst(0.0, s);
    let one = ir.konst(1.0, s);
    let mut cond = None;
    for d in &lone {
        let z = ir.call(Builtin::Eq, &[map[d.index()], zero], s);
        cond = Some(match cond {
            None => z,
            Some(c) => ir.call(Builtin::Select, &[c, one, z], s),
        });
    }
    let cond = cond.expect("a lone divisor");
    let rest: Vec<NodeId> = num.iter().copied().filter(|x| !matches!(f.ir.node(*x), Node::Call(Builtin::Exp, _))).collect();
    let n = product(ir, map, &rest, s).unwrap_or(one);
    let d = product(ir, map, den, s).unwrap_or(one);
    let pole = ir.bin(BinOp::Div, n, d, s);
    ir.call(Builtin::Select, &[cond, pole, r], s)
}

/// [`scaled_exp`] at one product node (`None`: not a product with an exp factor).
fn scaled_exp_at(an: &Analysis, ir: &mut Ir, map: &[NodeId], id: NodeId, old: Node, variant: usize) -> Option<(NodeId, bool)> {
    let (f, ranges, lists) = (&an.f, an.ranges(), an.lists());
    {
        let (num, den) = lists[id.index()].as_ref()?;
        let at = num.iter().position(|x| matches!(f.ir.node(*x), Node::Call(Builtin::Exp, _)))?;
        let Node::Call(Builtin::Exp, [arg, ..]) = *f.ir.node(num[at]) else { return None };
        if num.len() + den.len() < 2 || variant > 2 || (variant == 2 && den.len() < 2) {
            return None;
        }
        // A divisor left in b that may be tiny and that neither the exponent's own divisors cover (Beckmann's
        // NH: e^E vanishes faster) nor a square root bounds (1/√x ≤ 4.5·10¹⁶¹: Ward's √NL) overflows b before
        // e^E scales it (Cook–Torrance's VH ~ 10⁻³¹⁰ beside a tiny max(NL, NV): ∞ where the value is 10³⁰⁰).
        // Such a variant is skipped (the node unchanged), so the next is tried.
        let covered = lists[arg.index()].as_ref().map_or(vec![], |l| l.1.clone());
        let risky = |d: &NodeId| !safe(ranges[d.index()]) && !covered.contains(d) && !matches!(f.ir.node(*d), Node::Call(Builtin::Sqrt, _));
        let n_risky = den.iter().filter(|d| risky(d)).count();
        // Variant 1 takes two such divisors apart at run time ([`two_divisors`]).
        let two = variant == 1 && n_risky == 2 && den.iter().all(|d| risky(d) || safe(ranges[d.index()]) || covered.contains(d));
        if n_risky > if variant == 2 { 2 } else { 1 } && !two {
            return Some((ir.push(old.map_args(|a| map[a.index()]), f.ir.span(id)), false));
        }
        let s = f.ir.span(id);
        let rest: Vec<NodeId> = num.iter().enumerate().filter(|(i, _)| *i != at).map(|(_, x)| *x).collect();
        if two {
            return Some((two_divisors(ir, map, (map[arg.index()], &rest), den, ranges, |d| risky(d), s), true));
        }
        // Safe divisors first, so the last ones (the divisors kept apart) are those that may be tiny or huge.
        let (mut dens, unsafe_den): (Vec<NodeId>, Vec<NodeId>) = den.iter().partition(|d| safe(ranges[d.index()]));
        dens.extend(unsafe_den);
        let last = dens.pop();
        let second = if variant == 2 { dens.pop() } else { None };
        let mut b = product(ir, map, &rest, s).unwrap_or_else(|| ir.konst(1.0, s));
        if variant == 0 {
            if let Some(d) = product(ir, map, &dens, s) {
                b = ir.bin(BinOp::Div, b, d, s);
            }
        } else {
            // The safe divisors at once (one division, their product often parameter-only and so computed once
            // per parameter set), then each that may be tiny or huge on its own.
            let n_safe = dens.iter().take_while(|d| safe(ranges[d.index()])).count();
            let (cov, apart): (Vec<NodeId>, Vec<NodeId>) = dens[n_safe..].iter().partition(|d| covered.contains(d));
            b = if cov.is_empty() {
                divide_apart(ir, map, &rest, &dens[..n_safe], &apart, s)
            } else {
                // The exponent's own divisors join that product (one division, not a chain: Cook–Torrance's
                // /nh/nh/nh/nh was four dependent divisions, latency the cost model did not see).
                let n = product(ir, map, &rest, s).unwrap_or_else(|| ir.konst(1.0, s));
                let v = match joint_divisor(ir, map, &dens[..n_safe], &cov, s) {
                    Some(p) => ir.bin(BinOp::Div, n, p, s),
                    None => n,
                };
                divide_by(ir, map, v, &[], &apart, s)
            };
        }
        let c = match last {
            Some(d) => map[d.index()],
            None => ir.konst(1.0, s),
        };
        let mut a = map[arg.index()];
        if let Some(d) = second {
            // e^(E/2)·(e^(E/2)·b/d)/c: each half of the exponent meets one divisor, so neither b/d nor the
            // inner result leaves the normal range when both divisors are tiny (Cook–Torrance's NL and NV).
            let half = ir.konst(0.5, s);
            a = ir.bin(BinOp::Mul, a, half, s);
            b = ir.call(Builtin::ExpMulDiv, &[a, b, map[d.index()]], s);
        }
        Some((ir.call(Builtin::ExpMulDiv, &[a, b, c], s), true))
    }
}

/// The safe divisors and the exponent's own (`cov`) as one divisor, `None` when there are neither: with the
/// exponent's own, the balanced product of those times the safe ones' product, floored at 2⁻¹⁰²² (where it
/// underflows e^E vanishes with it, so the floor only keeps a zero numerator from 0/0; an overflowing b is
/// taken by expmuldiv as 0 beside a vanished e^E).
fn joint_divisor(ir: &mut Ir, map: &[NodeId], safe: &[NodeId], cov: &[NodeId], s: Span) -> Option<NodeId> {
    let q = product(ir, map, safe, s);
    if cov.is_empty() {
        return q;
    }
    let p = balanced_product(ir, map, cov, s);
    let p = q.map_or(p, |q| ir.bin(BinOp::Mul, q, p, s));
    let tiny = ir.konst(f64::MIN_POSITIVE, s);
    Some(ir.call(Builtin::Max, &[p, tiny], s))
}

/// Below this a divisor is too small to join expmuldiv's b ([`two_divisors`]): 2⁻¹⁰⁰⁰.
const JOIN_B: f64 = 9.332636185032189e-302;

/// 1536·ln 2 as fdlibm's ln 2 split (`ln2_hi` has 32 bits, so `K_HI` has 34 and a + K_HI is exact for
/// a ≤ −512), and e^(−1536·ln2_lo), the factor that split leaves (1 − 2.9·10⁻⁷, rounded once).
const K_HI: f64 = 1536.0 * 0.6931471803691238;
const K_LO: f64 = 1536.0 * 1.9082149292705877e-10;

// exp(E)·n/(safe·covered·x·y) → expmuldiv(E′, n/max(safe·covered, 2⁻¹⁰²²)/x′, y·s)   with x, y the two divisors
// that may be tiny and that the exponent does not cover: (E′, x′, s) = (E, x, 1) where x ≥ 2⁻¹⁰⁰⁰, else
// (E + K_HI, e^(−K_LO), x·2¹⁵³⁶), exact in real arithmetic since e^(K_HI + K_LO) = 2¹⁵³⁶
fn two_divisors(ir: &mut Ir, map: &[NodeId], (arg, rest): (NodeId, &[NodeId]), den: &[NodeId], ranges: &[Range], risky: impl Fn(&NodeId) -> bool, s: Span) -> NodeId {
    // Both in c as written would need their product, which underflows (Cook–Torrance's VH·max(NL, NV) ~ 10⁻⁵²⁰
    // where the value is 10⁻³¹⁰); one dividing the result after expmuldiv meets it rounded into the subnormals
    // (there: 0, 44 bits). So x joins b where b/x cannot overflow unless e^E vanishes (x ≥ 2⁻¹⁰⁰⁰: b would have
    // to exceed 2²⁴), and expmuldiv carries the exponent of b/x over c = y. A tinier x scales c by 2¹⁵³⁶ instead
    // (x·2⁷⁶⁸·2⁷⁶⁸·y lies in [2⁻⁶¹², 2⁻⁴⁶⁴]: normal, both factors exact) and the exponent pays for it: there a
    // finite value needs e^E·b < 2⁻⁹⁷⁶, so E ≤ −512 wherever b ≥ 2⁻²³⁷ and E + K_HI rounds nothing.
    let (xs, others): (Vec<NodeId>, Vec<NodeId>) = den.iter().partition(|d| risky(d));
    let (x, y) = (map[xs[0].index()], map[xs[1].index()]);
    let (safe_den, cov): (Vec<NodeId>, Vec<NodeId>) = others.iter().partition(|d| safe(ranges[d.index()]));
    let mut b = product(ir, map, rest, s).unwrap_or_else(|| ir.konst(1.0, s));
    if let Some(p) = joint_divisor(ir, map, &safe_den, &cov, s) {
        b = ir.bin(BinOp::Div, b, p, s);
    }
    let k = |ir: &mut Ir, v: f64| ir.konst(v, s);
    let t = k(ir, JOIN_B);
    let tiny = ir.call(Builtin::Lt, &[x, t], s);
    let (hi, zero, lo) = (k(ir, K_HI), k(ir, 0.0), k(ir, 1.0 + (-K_LO).exp_m1()));
    let shift = ir.call(Builtin::Select, &[tiny, hi, zero], s);
    let a = ir.bin(BinOp::Add, arg, shift, s);
    let x1 = ir.call(Builtin::Select, &[tiny, lo, x], s);
    let half = k(ir, 2f64.powi(768));
    let xs1 = ir.bin(BinOp::Mul, x, half, s);
    let xs2 = ir.bin(BinOp::Mul, xs1, half, s);
    let one = k(ir, 1.0);
    let sc = ir.call(Builtin::Select, &[tiny, xs2, one], s);
    let c = ir.bin(BinOp::Mul, y, sc, s);
    let b = ir.bin(BinOp::Div, b, x1, s);
    ir.call(Builtin::ExpMulDiv, &[a, b, c], s)
}

// K/(1 + sqrt(1 + A·(1 − c·c)/(c·c))) → K·|c|/(|c| + sqrt(c·c + A·(1 − c·c)))   (A any product, however the
// tan² is spelt: ((1 − c·c)/(c·c)), (1 − c·c)/c/c), c for |c| where c > 0 (range or guard), then c/c
// cancelled in the products around it
fn smith_g1(a: &Analysis) -> (Ir, NodeId, bool) {
    let (f, ranges, guards, lists) = (&a.f, a.ranges(), a.guards(), a.lists());
    let ir0 = &f.ir;
    let is_one = |x: NodeId| ir0.node(x).as_const() == Some(1.0);
    // (A's factors, c, c·c) when `x` is 1 + A·(1 − c·c)/(c·c) (either operand order of +, any of · and /).
    let inner = |x: NodeId| -> Option<(Vec<NodeId>, NodeId, NodeId)> {
        let Node::Binary(BinOp::Add, p, q) = *ir0.node(x) else { return None };
        let m = if is_one(p) { q } else if is_one(q) { p } else { return None };
        let (num, den) = lists[m.index()].as_ref()?;
        let [c, c2] = den[..] else { return None };
        let at = num.iter().position(|&t| {
            matches!(*ir0.node(t), Node::Binary(BinOp::Sub, one, sq)
                if is_one(one) && matches!(*ir0.node(sq), Node::Binary(BinOp::Mul, u, v) if u == c && v == c))
        })?;
        let Node::Binary(BinOp::Sub, _, sq) = *ir0.node(num[at]) else { return None };
        let rest: Vec<NodeId> = num.iter().enumerate().filter(|(i, _)| *i != at).map(|(_, t)| *t).collect();
        (c == c2).then_some((rest, c, sq))
    };
    let (ir, root, fired) = rebuild(f, |ir, map, id, n| {
        let Node::Binary(BinOp::Div, k, den) = n else { return None };
        let Node::Binary(BinOp::Add, p, q) = *ir0.node(den) else { return None };
        let r = if is_one(p) { q } else if is_one(q) { p } else { return None };
        let Node::Call(Builtin::Sqrt, [x, ..]) = *ir0.node(r) else { return None };
        let (a, c, sq) = inner(x)?;
        let positive = ranges[c.index()].lo > 0.0 || guards[id.index()].as_ref().is_some_and(|g| g.contains(&c));
        let s = f.ir.span(id);
        let a = product(ir, map, &a, s).unwrap_or_else(|| ir.konst(1.0, s));
        let (c, sq) = (map[c.index()], map[sq.index()]);
        // K/(1 + sqrt(1 + A·t²)) times |c|/|c|: |c|·sqrt(1 + A·(1 − c²)/c²) = sqrt(c² + A·(1 − c²)).
        let c = if positive { c } else { ir.call(Builtin::Abs, &[c], s) };
        let one = ir.konst(1.0, s);
        let om = ir.bin(BinOp::Sub, one, sq, s);
        let am = ir.bin(BinOp::Mul, a, om, s);
        let rad = ir.bin(BinOp::Add, sq, am, s);
        let root = ir.call(Builtin::Sqrt, &[rad], s);
        let d = ir.bin(BinOp::Add, c, root, s);
        let kc = ir.bin(BinOp::Mul, map[k.index()], c, s);
        Some(ir.bin(BinOp::Div, kc, d, s))
    });
    if !fired {
        return (ir, root, false);
    }
    let g = Formula { ir, root, ..f.clone() };
    let (ir, root, _) = cancel_positive(&Analysis::new(g));
    (ir, root, true)
}

// x·…/(x·…) → …/…   for x > 0 by range or guard (exact in real arithmetic); the divisors that remain are
// divided one by one (safe ones first, as a product), as in `quotient-chain`
fn cancel_positive(a: &Analysis) -> (Ir, NodeId, bool) {
    // Longer lists than elsewhere: a microfacet BRDF's D·G·F/(4·NL·NV) has 14 factors once G is rationalised.
    let (f, lists, guards, ranges) = (&a.f, a.wide_lists(), a.guards(), a.ranges());
    rebuild(f, |ir, map, id, _| {
        let (num, den) = lists[id.index()].as_ref()?;
        let pos = |x: NodeId| {
            let r = ranges[x.index()];
            (r.lo > 0.0 && r.hi.is_finite()) || guards[id.index()].as_ref().is_some_and(|g| g.contains(&x))
        };
        let (mut num, mut den) = (num.clone(), den.clone());
        let mut cancelled = false;
        let mut i = 0;
        while i < num.len() {
            match den.iter().position(|d| *d == num[i]) {
                Some(j) if pos(num[i]) => {
                    num.remove(i);
                    den.remove(j);
                    cancelled = true;
                }
                _ => i += 1,
            }
        }
        if !cancelled {
            return None;
        }
        let (safe_den, unsafe_den): (Vec<NodeId>, Vec<NodeId>) = den.iter().partition(|d| safe(ranges[d.index()]));
        Some(divide_apart(ir, map, &num, &safe_den, &unsafe_den, f.ir.span(id)))
    })
}

// z·min(K, c·x, c·y)/(v·x·y) → z·min(K·d/min(x, y), n)/(v·d)/max(x, y)   for K > 0 and x, y, n, d ≥ 0 by range,
// c = n/d the product/quotient of the factors both arguments share (the min's arguments in any order and nesting)
fn cancel_min(a: &Analysis) -> (Ir, NodeId, bool) {
    let (f, ranges, lists) = (&a.f, a.ranges(), a.lists());
    let ir0 = &f.ir;
    fn leaves(ir: &Ir, x: NodeId, out: &mut Vec<NodeId>) {
        crate::base::stack::deep(|| {
            match *ir.node(x) {
                Node::Call(Builtin::Min, [a, b, _]) => {
                    leaves(ir, a, out);
                    leaves(ir, b, out);
                }
                _ => out.push(x),
            }
        })
    }
    let factors = |x: NodeId| match &lists[x.index()] {
        Some(l) => l.clone(),
        None => (vec![x], vec![]),
    };
    let nonneg = |xs: &[NodeId]| xs.iter().all(|x| ranges[x.index()].nonneg());
    // (c's numerator and denominator, x, y) when `args` are K, c·x, c·y with x, y divisors of the tree.
    let split = |args: &[NodeId], den: &[NodeId]| -> Option<(Vec<NodeId>, Vec<NodeId>, NodeId, NodeId)> {
        let k = args.iter().position(|a| ranges[a.index()].lo > 0.0)?;
        let rest: Vec<NodeId> = args.iter().enumerate().filter(|(i, _)| *i != k).map(|(_, a)| *a).collect();
        let [p, q] = rest[..] else { return None };
        let ((pn, pd), (qn, qd)) = (factors(p), factors(q));
        for (i, x) in pn.iter().enumerate() {
            for (j, y) in qn.iter().enumerate() {
                if x == y || !den.contains(x) || !den.contains(y) {
                    continue;
                }
                let mut cn = pn.clone();
                cn.remove(i);
                let mut qn2 = qn.clone();
                qn2.remove(j);
                let (mut a, mut b, mut c, mut d) = (cn.clone(), qn2, pd.clone(), qd.clone());
                for v in [&mut a, &mut b, &mut c, &mut d] {
                    v.sort();
                }
                if a == b && c == d && nonneg(&cn) && nonneg(&pd) && nonneg(&[*x, *y]) {
                    return Some((cn, pd, *x, *y));
                }
            }
        }
        None
    };
    // Only whole trees: an operand of a flattened product would not have x and y among its divisors.
    let inner = list_operands(ir0, lists);
    rebuild(f, |ir, map, id, _| {
        let (num, den) = lists[id.index()].as_ref().filter(|_| !inner[id.index()])?;
        let at = num.iter().position(|x| matches!(ir0.node(*x), Node::Call(Builtin::Min, _)))?;
        let mut args = vec![];
        leaves(ir0, num[at], &mut args);
        if args.len() != 3 {
            return None;
        }
        let (cn, cd, x, y) = split(&args, den)?;
        let k = *args.iter().find(|a| ranges[a.index()].lo > 0.0)?;
        let s = ir0.span(id);
        let (mx, my) = (map[x.index()], map[y.index()]);
        let u = ir.call(Builtin::Min, &[mx, my], s);
        let w = ir.call(Builtin::Max, &[mx, my], s);
        // min(K, c·u)/u with c = cn/cd is K/u where K·cd < cn·u, else cn/cd: the branch is chosen by products
        // (no quotient that rounds into the subnormals, as K·VH/u did at VH = 5·10⁻³²⁴: 26 % low), each side
        // scaled by 2^e (exact) so tiny cd and u compare at full precision, and the value divides by one of
        // u, cd. At u = 0 the test fails and the limit cn/(cd·w) is taken.
        let mag = |xs: &[NodeId]| xs.iter().map(|v| ranges[v.index()].lo.abs().max(ranges[v.index()].hi.abs())).product::<f64>();
        let top = (mag(&[k]) * mag(&cd)).max(mag(&cn) * mag(&[x]).max(mag(&[y])));
        let e = if top.is_finite() { (1000.0 - top.max(1.0).log2()).floor().min(600.0) } else { 0.0 };
        let scale = ir.konst(2f64.powi(e.max(0.0) as i32), s);
        let cden = product(ir, map, &cd, s);
        let kd = cden.map_or(scale, |p| ir.bin(BinOp::Mul, p, scale, s));
        let lhs = ir.bin(BinOp::Mul, map[k.index()], kd, s);
        let us = ir.bin(BinOp::Mul, u, scale, s);
        let cnum = product(ir, map, &cn, s);
        let rhs = cnum.map_or(us, |p| ir.bin(BinOp::Mul, p, us, s));
        let first = ir.call(Builtin::Lt, &[lhs, rhs], s);
        let one = ir.konst(1.0, s);
        let g = ir.call(Builtin::Select, &[first, map[k.index()], cnum.unwrap_or(one)], s);
        let gd = ir.call(Builtin::Select, &[first, u, cden.unwrap_or(one)], s);
        let others: Vec<NodeId> = num.iter().enumerate().filter(|(i, _)| *i != at).map(|(_, v)| *v).collect();
        let mut rest = den.clone();
        for v in [x, y] {
            rest.remove(rest.iter().position(|d| *d == v)?);
        }
        let (safe_den, unsafe_den): (Vec<NodeId>, Vec<NodeId>) = rest.iter().partition(|d| safe(ranges[d.index()]));
        let v = product(ir, map, &others, s).map_or(g, |p| ir.bin(BinOp::Mul, p, g, s));
        let v = divide_by(ir, map, v, &safe_den, &unsafe_den, s);
        let v = ir.bin(BinOp::Div, v, gd, s);
        Some(ir.bin(BinOp::Div, v, w, s))
    })
}

// x / sqrt(a·a + b·b + …) → (x·s) / sqrt((a·s)·(a·s) + …),  s = 2^600 if max(|a|, |b|, …) < 2^-500 else 1,
// x one of a, b, …: the squares of a tiny vector (L + V at L ≈ −V) no longer underflow to a zero length
fn scaled_norm(a: &Analysis) -> (Ir, NodeId, bool) {
    let f = &a.f;
    let ir0 = &f.ir;
    fn squares(ir: &Ir, x: NodeId, out: &mut Vec<NodeId>) -> bool {
        crate::base::stack::deep(|| {
            match *ir.node(x) {
                Node::Binary(BinOp::Add, p, q) => squares(ir, p, out) && squares(ir, q, out),
                Node::Binary(BinOp::Mul, a, b) if a == b => {
                    out.push(a);
                    true
                }
                _ => false,
            }
        })
    }
    rebuild(f, |ir, map, id, n| {
        let Node::Binary(BinOp::Div, x, d) = n else { return None };
        let Node::Call(Builtin::Sqrt, [sum, ..]) = *ir0.node(d) else { return None };
        let mut bases = vec![];
        if !squares(ir0, sum, &mut bases) || bases.len() < 2 || !bases.contains(&x) {
            return None;
        }
        let sp = f.ir.span(id);
        let mags: Vec<NodeId> = bases.iter().map(|b| ir.call(Builtin::Abs, &[map[b.index()]], sp)).collect();
        let m = mags[1..].iter().fold(mags[0], |acc, v| ir.call(Builtin::Max, &[acc, *v], sp));
        let tiny = ir.konst(2f64.powi(-500), sp);
        let small = ir.call(Builtin::Lt, &[m, tiny], sp);
        let (up, one) = (ir.konst(2f64.powi(600), sp), ir.konst(1.0, sp));
        let sc = ir.call(Builtin::Select, &[small, up, one], sp);
        let scaled: Vec<NodeId> = bases.iter().map(|b| ir.bin(BinOp::Mul, map[b.index()], sc, sp)).collect();
        let sq: Vec<NodeId> = scaled.iter().map(|v| ir.bin(BinOp::Mul, *v, *v, sp)).collect();
        let total = sq[1..].iter().fold(sq[0], |acc, v| ir.bin(BinOp::Add, acc, *v, sp));
        let root = ir.call(Builtin::Sqrt, &[total], sp);
        let xs = ir.bin(BinOp::Mul, map[x.index()], sc, sp);
        Some(ir.bin(BinOp::Div, xs, root, sp))
    })
}

#[cfg(test)]
mod tests {
    use super::super::tests::parse;
    use super::*;

    #[test]
    fn split_sqrt_needs_nonnegative_factors() {
        let f = parse("1/sqrt(NL*NV)");
        let g = SplitSqrt.apply_to(&f, None).unwrap();
        assert_eq!(g.to_text().matches("sqrt").count(), 2, "{}", g.to_text());
        // x − 1 may be negative: sqrt((x−1)·y) is NaN for x < 1 either way, but the split is not exact.
        assert!(SplitSqrt.apply_to(&parse("sqrt((NL - 2)*(NV - 2))"), None).is_none());
        // A guard makes the factors positive where the sqrt's value is used; without it, no split.
        let guarded = "let a = NL - 0.5\nlet b = NV - 0.5\na <= 0 || b <= 0 ? 0 : 1/sqrt(a*b)";
        assert!(SplitSqrt.apply_to(&parse(guarded), None).is_some());
        assert!(SplitSqrt.apply_to(&parse("let a = NL - 0.5\nlet b = NV - 0.5\na <= 0 ? 0 : 1/sqrt(a*b)"), None).is_none());
        assert!(SplitSqrt.apply_to(&parse("let a = NL - 0.5\nlet b = NV - 0.5\n(a <= 0 || b <= 0 ? 0 : 1) + sqrt(a*b)"), None).is_none());
    }

    #[test]
    fn quotient_chain_divides_by_each_unsafe_factor() {
        let f = parse("param m = 0.3 in 0.01..1\n1/(m^2 * NH^4) * exp((NH^2 - 1) / (m^2 * NH^2))");
        let g = QuotientChain.apply_to(&f, None).unwrap();
        let t = g.to_program_text();
        // NH⁴ split into four divisions by NH; m² (safe) divides once.
        assert!(t.contains("/ nh / nh / nh / nh"), "{t}");
        assert!(super::super::cost(&g) > super::super::cost(&f));
        // One site at a time: the first is 1/(m²·NH⁴), the last the whole product.
        let sites: Vec<Formula> = (0..4).filter_map(|k| QuotientChain.apply_to(&f, Some(k))).collect();
        assert_eq!(sites.len(), 3, "{:?}", sites.iter().map(|g| g.to_text()).collect::<Vec<_>>());
        // A single divisor is left alone.
        assert!(QuotientChain.apply_to(&parse("NH / NL"), None).is_none());
    }

    #[test]
    fn scaled_exp_needs_an_exp_factor_and_another_factor() {
        let f = parse("param m = 0.3 in 0.01..1\nexp((NH^2 - 1) / (m^2 * NH^2)) / (m*m) / NH / NL");
        let t = |k| ScaledExp.apply_to(&f, Some(k)).map(|g| g.to_program_text());
        let (v0, v1, v2) = (t(0).unwrap(), t(1).unwrap(), t(2).unwrap());
        assert!(v0.contains("expmuldiv(") && !v0.contains("exp("), "{v0}");
        assert!(v1 != v0 && v2.matches("expmuldiv(").count() == 2, "{v1}\n{v2}");
        // Variant 1 divides by the safe divisors' product once (m·m: parameter-only, computed once per parameter
        // set), then by each divisor that may be tiny on its own, not by m twice in the chain.
        assert!(!v1.contains("/ m /") && !v1.contains("/ m,"), "{v1}");
        assert!(t(3).is_none());
        assert!(ScaledExp.apply_to(&parse("exp(-NH)"), None).is_none());
        assert!(ScaledExp.apply_to(&parse("NL / exp(NH)"), None).is_none());
    }

    #[test]
    fn scaled_exp_takes_two_tiny_divisors_apart_in_one_call() {
        let f = parse("param m = 0.3 in 0.01..1\nexp((NH^2 - 1) / (m^2 * NH^2)) / (m*m) / NH^4 / VH / max(NL, NV)");
        let g = ScaledExp.apply_to(&f, Some(1)).unwrap();
        let t = g.to_program_text();
        // One expmuldiv (one exp), VH and max(NL, NV) chosen apart at run time, NH⁴ one division, not four.
        assert_eq!(t.matches("expmuldiv(").count(), 1, "{t}");
        assert!(t.contains("< 9.332636185032189e-302") && !t.contains("/ nh /"), "{t}");
        let ev = crate::backend::interp::Interp::new(&g);
        let at = |nl: f64, nv: f64, nh: f64, vh: f64| {
            let mut x = [0.5; crate::ir::N_INPUTS];
            for (i, v) in [(0, nl), (1, nv), (2, nh), (4, vh)] {
                x[i] = v;
            }
            crate::backend::Evaluator::eval(&ev, &x, &[0.5, 0.8])
        };
        // VH·max(NL, NV) ~ 1e-520 where the value is subnormal: b/VH joins expmuldiv (VH ≥ 2⁻¹⁰⁰⁰); at VH ~ 1e-310
        // the exponent carries the 2¹⁵³⁶ that scales c. Reference by logarithms (relative error ~700·2⁻⁵³).
        for (nl, nv, nh, vh) in [(1e-260f64, 2e-260f64, 0.0285f64, 2e-260f64), (1e-310, 3e-310, 0.0269, 2e-310)] {
            let m = 0.8f64;
            let ln = (nh * nh - 1.0) / (m * m * nh * nh) - 2.0 * m.ln() - 4.0 * nh.ln() - vh.ln() - nl.max(nv).ln();
            let (got, want) = (at(nl, nv, nh, vh), ln.exp());
            assert!(want > 0.0 && want < 2.2e-308 && ((got - want) / want).abs() < 1e-11, "{got:e} {want:e}");
        }
    }

    #[test]
    fn smith_g1_needs_a_positive_cosine_and_cancels_it() {
        let g1 = "let g = 2/(1 + sqrt(1 + a*a*((1 - NL*NL)/(NL*NL))))";
        let src = format!("param a = 0.2 in 0.01..1\n{g1}\nlet c = NL - 0.5\nNL <= 0 ? 0 : g * NH / (4*NL)");
        let t = SmithG1.apply_to(&parse(&src), None).unwrap().to_program_text();
        // G1·…/(4·NL) with G1 = 2·NL/(NL + …): NL cancelled, so nothing is ∞/∞ or 0/0 at tiny NL.
        assert!(!t.contains("/ nl") && !t.contains("* nl /") && t.contains("sqrt("), "{t}");
        // Without the guard NL may be 0: nothing cancelled. (Of a clamped NL, |NL| simplifies to NL; of a
        // direction's component, Lz, it stays: G1 is even in c.)
        let t = SmithG1.apply_to(&parse(&format!("param a = 0.2 in 0.01..1\n{g1}\ng * NH / (4*NL)")), None).unwrap().to_program_text();
        assert!(t.contains("(nl + sqrt(") && t.contains("/ (4 * nl)"), "{t}");
        let lz = format!("param a = 0.2 in 0.01..1\n{}\ng * NH / (4*Lz)", g1.replace("NL", "Lz"));
        let t = SmithG1.apply_to(&parse(&lz), None).unwrap().to_program_text();
        assert!(t.contains("abs(Lz)") && t.contains("Lz)"), "{t}");
        // tan² spelt (1 − c²)/c/c, as BRDF Explorer's Walter file has it.
        let walter = "param a = 0.2 in 0.01..1\nlet g = 2/(1 + sqrt(1 + a*a*(1 - NV*NV)/NV/NV))\nNV <= 0 ? 0 : g / NV";
        let t = SmithG1.apply_to(&parse(walter), None).unwrap().to_program_text();
        assert!(t.contains("(nv + sqrt(") && !t.contains("/ nv"), "{t}");
    }

    #[test]
    fn cancel_min_needs_a_positive_bound_and_a_nonnegative_shared_factor() {
        let f = parse("param m = 0.3 in 0.01..1\nlet G = min(1, min(2*NH*NV/VH, 2*NH*NL/VH))\nexp(-NH/m)*G/(3*NL*NV)");
        let t = CancelMin.apply_to(&f, None).unwrap().to_program_text();
        // (VH·2^e < 2·NH·min(NL, NV)·2^e ? 1/min(NL, NV) : 2·NH/VH)/max(NL, NV): no NL·NV, and the branch is
        // chosen by products, not by a quotient that may round into the subnormals.
        assert!(t.contains("vh * 4.149515568880993e180 <") && t.contains("? 1 : t1)") && t.contains("? t") && t.contains("/ max("), "{t}");
        assert!(!t.contains("nl * nv") && !t.contains("vh / min("), "{t}");
        // A shared factor that may be negative (NH − 0.5) or a bound that may be 0: not rewritten.
        assert!(CancelMin.apply_to(&parse("min(1, min((NH - 0.5)*NV, (NH - 0.5)*NL))/(NL*NV)"), None).is_none());
        assert!(CancelMin.apply_to(&parse("min(NH, min(2*NV, 2*NL))/(NL*NV)"), None).is_none());
        assert!(CancelMin.apply_to(&parse("min(1, min(2*NV, 2*NL))/(NL*NV)"), None).is_some());
    }

    #[test]
    fn scaled_norm_scales_the_vector_not_a_lone_sqrt() {
        let f = parse("let x = Lx + Vx\nlet z = Lz + Vz\nz / sqrt(x*x + z*z)");
        let t = ScaledNorm.apply_to(&f, None).unwrap().to_program_text();
        assert!(t.contains("? 4.149515568880993e180 : 1") && t.contains("t5 / sqrt(t4 * t4 + t5 * t5)"), "{t}");
        assert!(ScaledNorm.apply_to(&parse("let x = Lx + Vx\nlet z = Lz + Vz\nNH / sqrt(x*x + z*z)"), None).is_none());
        assert!(ScaledNorm.apply_to(&parse("let x = Lx + Vx\nx / sqrt(x*x)"), None).is_none());
    }
}
