//! The accuracy pass's candidate rewrites: IR → IR forms that avoid overflow, underflow and cancellation.
//!
//! # Design
//! Herbie's split (Panchekha et al., PLDI 2015): this module only *proposes* — each [`Rule`] rewrites a whole
//! simplified formula into an algebraically equal one and states its cost ([`cost`]); it evaluates nothing.
//! Which candidates are kept is decided above the backends (`numerics::robust`), by measured bits of error
//! against a higher-precision truth over the formula's domain, within a cost budget. A rule that does not
//! apply returns `None`. Every rule is exact in real arithmetic; what changes is where f64 rounds:
//!
//! - `split-sqrt`: `sqrt(a·b) → sqrt(a)·sqrt(b)` for a, b ≥ 0 (range analysis). a·b underflows to 0 when both
//!   are below ~10⁻¹⁶², but sqrt(a)·sqrt(b) ≥ sqrt(4.9·10⁻³²⁴) never does (Ward's 1/sqrt(NL·NV)). One more
//!   sqrt (cost +3), one more rounding (≤ 1.5 ulp instead of ≤ 1).
//! - `quotient-chain`: a maximal tree of `*` and `/` is flattened into numerator and denominator factors and
//!   rebuilt as `(numerators) / (safe denominators) / d₁ / d₂ / …`: each divisor that may be tiny or huge
//!   divides on its own, so no product of two of them is formed (the numerator is multiplied out first: in a
//!   BRDF the factor that vanishes, exp(−1/x²), is there, and it must meet the divisions as 0, not as ∞·0). Then `exp(E)/(m²·NH⁴)` at NH = 10⁻¹⁰⁰ is `0/m²/NH/NH/NH/NH = 0` instead of
//!   `inf·0 = NaN` (NH⁴ = 0), and Cook–Torrance's `…/(π·NL·NV)` stays finite when NL·NV underflows. Integer
//!   powers `x·x` in a denominator are split into their base. A factor is *safe* when its range lies in
//!   [2⁻³⁰⁰, 2³⁰⁰] in magnitude. Cost: one division per unsafe factor (~3 multiplications each).
//! - `factor-quadratic`: `A·c² + (1 − A)·c → c·(1 + A·(c − 1))` (the quadratic model): c − 1 is exact for
//!   c ∈ [0.5, 2] (Sterbenz), so near c = 1 the result rounds ~twice instead of cancelling two terms of size A.
//!   The same cost (three multiplications and two additions either way).
//!
//! A fourth candidate, large integer powers kept as `pow` calls instead of multiplication chains, is the
//! simplifier's own [`super::Policy::max_chain`]; the chooser builds it with [`pow_call_policy`].
//!
//! # Cost model
//! [`cost`] counts live nodes with weights fitted to JIT timings on x86-64 (BENCHMARKS.md, 2026-11-30: five
//! extra divisions add ~3.4 ns to Beckmann's 8.5 ns, a libm exp ~5 ns): `+ − ×`, abs, min, max 1; clamp 2;
//! `/` and sqrt 3; libm calls (pow, exp, ln, trig) 20; leaves and negation 0.
//! It ranks candidates; the kernel's run time, measured in `lobe bench`, is what the README reports.

use super::range::Range;
use super::{node_ranges, Policy};
use crate::builtins::Builtin;
use crate::ir::{BinOp, Formula, Ir, Node, NodeId};

/// One candidate rewrite of the accuracy pass.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Rule {
    SplitSqrt,
    QuotientChain,
    FactorQuadratic,
}

impl Rule {
    pub const ALL: [Rule; 3] = [Rule::SplitSqrt, Rule::QuotientChain, Rule::FactorQuadratic];

    pub fn name(self) -> &'static str {
        match self {
            Rule::SplitSqrt => "split-sqrt",
            Rule::QuotientChain => "quotient-chain",
            Rule::FactorQuadratic => "factor-quadratic",
        }
    }

    /// What the rule does, for reports.
    pub fn describe(self) -> &'static str {
        match self {
            Rule::SplitSqrt => "sqrt(a*b) as sqrt(a)*sqrt(b): no underflow of a*b",
            Rule::QuotientChain => "products/quotients reassociated: divide by each tiny-or-huge factor separately",
            Rule::FactorQuadratic => "A*c^2 + (1 - A)*c as c*(1 + A*(c - 1)): no cancellation near c = 1",
        }
    }

    /// The rewritten formula, or `None` when the rule does not apply. The result is simplified again (default
    /// policy) so constants fold.
    pub fn apply(self, f: &Formula) -> Option<Formula> {
        self.apply_at(f, None)
    }

    /// [`Rule::apply`] at one site only (the `k`-th place the rule matches, in arena order), so the chooser
    /// can keep it where it helps and leave it where it only costs (Beckmann: the product whose exp factor
    /// vanishes, not the exponent's own quotient). Only `quotient-chain` has sites; the others apply everywhere.
    pub fn apply_at(self, f: &Formula, site: Option<usize>) -> Option<Formula> {
        let ranges = node_ranges(f, &Policy::default());
        let (ir, root, fired) = match self {
            Rule::SplitSqrt => split_sqrt(f, &ranges),
            Rule::QuotientChain => quotient_chain(f, &ranges, site),
            Rule::FactorQuadratic => factor_quadratic(f),
        };
        if !fired {
            return None;
        }
        let g = Formula { ir, root, ..f.clone() };
        Some(super::simplify_with(&g, &[], &Policy::default()).0)
    }
}

/// The simplifier policy of the `pow-call` candidate: integer powers above 8 stay `pow` calls (libm's < 1 ulp)
/// instead of multiplication chains (error up to (k − 1)·u; 449 ulp measured at k = 1000).
pub fn pow_call_policy() -> Policy {
    Policy { max_chain: 8, ..Policy::default() }
}

/// Static cost of a formula's live nodes (module docs).
pub fn cost(f: &Formula) -> f64 {
    let mut c = 0.0;
    f.ir.walk(f.root, |n| {
        c += match n {
            Node::Const(_) | Node::Input(_) | Node::Param(_) | Node::Column(_) | Node::Neg(_) => 0.0,
            Node::Binary(BinOp::Div, ..) => 3.0,
            Node::Binary(..) => 1.0,
            Node::Call(b, _) => match b {
                Builtin::Sqrt => 3.0,
                Builtin::Abs | Builtin::Min | Builtin::Max => 1.0,
                Builtin::Clamp => 2.0,
                Builtin::Lt | Builtin::Le | Builtin::Eq | Builtin::Ne | Builtin::Select => 2.0,
                Builtin::Floor => 6.0,
                _ => 20.0,
            },
        }
    });
    c
}

/// Rebuilds `f` node by node through `rw`, which returns the new node for an old one given the map so far.
fn rebuild(f: &Formula, mut rw: impl FnMut(&mut Ir, &[NodeId], NodeId, Node) -> Option<NodeId>) -> (Ir, NodeId, bool) {
    let mut ir = Ir::new();
    let mut map: Vec<NodeId> = Vec::with_capacity(f.ir.len());
    let mut fired = false;
    for id in f.ir.ids() {
        let span = f.ir.span(id);
        let old = *f.ir.node(id);
        let new = match rw(&mut ir, &map, id, old) {
            Some(n) => {
                fired = true;
                n
            }
            None => ir.push(old.map_args(|a| map[a.index()]), span),
        };
        map.push(new);
    }
    let (ir, root) = ir.compact(map[f.root.index()]);
    (ir, root, fired)
}

// sqrt(a*b) → sqrt(a)*sqrt(b)   when a ≥ +0 and b ≥ +0
fn split_sqrt(f: &Formula, ranges: &[Range]) -> (Ir, NodeId, bool) {
    rebuild(f, |ir, map, id, n| {
        let Node::Call(Builtin::Sqrt, [x, ..]) = n else { return None };
        let Node::Binary(BinOp::Mul, a, b) = *f.ir.node(x) else { return None };
        if !(ranges[a.index()].nonneg() && ranges[b.index()].nonneg()) {
            return None;
        }
        let s = f.ir.span(id);
        let sa = ir.call(Builtin::Sqrt, &[map[a.index()]], s);
        let sb = ir.call(Builtin::Sqrt, &[map[b.index()]], s);
        Some(ir.bin(BinOp::Mul, sa, sb, s))
    })
}

/// Most factors a flattened product keeps; a longer one (a long power chain) stays one factor.
const MAX_FACTORS: usize = 12;

fn safe(r: Range) -> bool {
    let (lo, hi) = (2f64.powi(-300), 2f64.powi(300));
    !r.nan && ((r.lo >= lo && r.hi <= hi) || (r.hi <= -lo && r.lo >= -hi))
}

// x / (a*b*…) → x / (safe factors) / a / b / …   dividing by each factor that may be tiny or huge on its own
fn quotient_chain(f: &Formula, ranges: &[Range], only: Option<usize>) -> (Ir, NodeId, bool) {
    // Per old node: (numerator, denominator) factor lists of old atomic nodes, if it is a short product tree.
    let mut lists: Vec<Option<(Vec<NodeId>, Vec<NodeId>)>> = Vec::with_capacity(f.ir.len());
    for id in f.ir.ids() {
        let of = |x: NodeId, lists: &[Option<(Vec<NodeId>, Vec<NodeId>)>]| match &lists[x.index()] {
            Some(l) => l.clone(),
            None if f.ir.node(x).as_const() == Some(1.0) => (vec![], vec![]),
            None => (vec![x], vec![]),
        };
        let l = match *f.ir.node(id) {
            Node::Binary(op @ (BinOp::Mul | BinOp::Div), a, b) => {
                let (mut n, mut d) = of(a, &lists);
                let (mut n2, mut d2) = of(b, &lists);
                if op == BinOp::Div {
                    std::mem::swap(&mut n2, &mut d2);
                }
                n.extend(n2);
                d.extend(d2);
                Some((n, d))
            }
            _ => None,
        };
        lists.push(l.filter(|(n, d)| n.len() + d.len() <= MAX_FACTORS));
    }
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
        let s = f.ir.span(id);
        let prod = |ir: &mut Ir, xs: &[NodeId]| -> Option<NodeId> {
            let mut it = xs.iter().map(|x| map[x.index()]);
            let first = it.next()?;
            Some(it.fold(first, |acc, x| ir.bin(BinOp::Mul, acc, x, s)))
        };
        // The whole numerator first (in a BRDF the factor that vanishes, exp(−1/x²), is there, and it must meet
        // the divisions as 0, not as ∞·0), then the safe divisors at once, then each unsafe divisor.
        let mut v = match prod(ir, num) {
            Some(v) => v,
            None => ir.konst(1.0, s),
        };
        if let Some(d) = prod(ir, &safe_den) {
            v = ir.bin(BinOp::Div, v, d, s);
        }
        for d in unsafe_den {
            v = ir.bin(BinOp::Div, v, map[d.index()], s);
        }
        Some(v)
    })
}

// A*c^2 + (1 - A)*c → c*(1 + A*(c - 1))
fn factor_quadratic(f: &Formula) -> (Ir, NodeId, bool) {
    let ir0 = &f.ir;
    // (A, c) when `id` is A*(c*c) or (c*c)*A.
    let square_term = |id: NodeId| -> Option<(NodeId, NodeId)> {
        let Node::Binary(BinOp::Mul, p, q) = *ir0.node(id) else { return None };
        for (a, s) in [(p, q), (q, p)] {
            if let Node::Binary(BinOp::Mul, c1, c2) = *ir0.node(s) {
                if c1 == c2 {
                    return Some((a, c1));
                }
            }
        }
        None
    };
    // B when `id` is B*c or c*B.
    let linear_term = |id: NodeId, c: NodeId| -> Option<NodeId> {
        let Node::Binary(BinOp::Mul, p, q) = *ir0.node(id) else { return None };
        if q == c {
            Some(p)
        } else if p == c {
            Some(q)
        } else {
            None
        }
    };
    // B is 1 − A: the node itself, or constants with B = fl(1 − A).
    let one_minus = |b: NodeId, a: NodeId| match (*ir0.node(b), ir0.node(a).as_const()) {
        (Node::Binary(BinOp::Sub, one, x), _) if x == a && ir0.node(one).as_const() == Some(1.0) => true,
        (Node::Const(bits), Some(av)) => f64::from_bits(bits) == 1.0 - av,
        _ => false,
    };
    rebuild(f, |ir, map, id, n| {
        let Node::Binary(BinOp::Add, x, y) = n else { return None };
        for (sq, lin) in [(x, y), (y, x)] {
            let Some((a, c)) = square_term(sq) else { continue };
            let Some(b) = linear_term(lin, c) else { continue };
            if !one_minus(b, a) {
                continue;
            }
            let s = f.ir.span(id);
            let (a, c) = (map[a.index()], map[c.index()]);
            let one = ir.konst(1.0, s);
            let cm1 = ir.bin(BinOp::Sub, c, one, s);
            let t = ir.bin(BinOp::Mul, a, cm1, s);
            let u = ir.bin(BinOp::Add, one, t, s);
            return Some(ir.bin(BinOp::Mul, c, u, s));
        }
        None
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(src: &str) -> Formula {
        let f = crate::front::parse("t.brdf", src).unwrap();
        super::super::simplify(&f, &[])
    }

    #[test]
    fn split_sqrt_needs_nonnegative_factors() {
        let f = parse("1/sqrt(NL*NV)");
        let g = Rule::SplitSqrt.apply(&f).unwrap();
        assert_eq!(g.to_text().matches("sqrt").count(), 2, "{}", g.to_text());
        // x − 1 may be negative: sqrt((x−1)·y) is NaN for x < 1 either way, but the split is not exact.
        assert!(Rule::SplitSqrt.apply(&parse("sqrt((NL - 2)*(NV - 2))")).is_none());
    }

    #[test]
    fn quotient_chain_divides_by_each_unsafe_factor() {
        let f = parse("param m = 0.3 in 0.01..1\n1/(m^2 * NH^4) * exp((NH^2 - 1) / (m^2 * NH^2))");
        let g = Rule::QuotientChain.apply(&f).unwrap();
        let t = g.to_program_text();
        // NH⁴ split into four divisions by NH; m² (safe) divides once.
        assert!(t.contains("/ nh / nh / nh / nh"), "{t}");
        assert!(cost(&g) > cost(&f));
        // One site at a time: the first is 1/(m²·NH⁴), the last the whole product.
        let sites: Vec<Formula> = (0..4).filter_map(|k| Rule::QuotientChain.apply_at(&f, Some(k))).collect();
        assert_eq!(sites.len(), 3, "{:?}", sites.iter().map(|g| g.to_text()).collect::<Vec<_>>());
        // A single divisor is left alone.
        assert!(Rule::QuotientChain.apply(&parse("NH / NL")).is_none());
    }

    #[test]
    fn quadratic_factors_live_and_baked() {
        let src = "let c = NH\n0.786*n*c^2 + (1 - 0.786*n)*c";
        let g = Rule::FactorQuadratic.apply(&parse(src)).unwrap();
        assert!(g.to_text().contains("- 1"), "{}", g.to_text());
        let f = crate::front::parse("q.brdf", src).unwrap();
        let baked = super::super::simplify(&f, &[(0, 1000.0)]);
        assert!(Rule::FactorQuadratic.apply(&baked).is_some(), "{}", baked.to_text());
        assert!(Rule::FactorQuadratic.apply(&parse("2*NH^2 + 3*NH")).is_none());
    }
}
