//! The rounding family: forms that carry a sum's or a power's rounding error instead of letting cancellation or
//! a large exponent amplify it (`compensated-sum`, `compensated-base`, `factor-quadratic`; described in
//! [`super`]).

use super::rule::{Example, Rule, Sites, Source};
use super::finish;
use crate::simplify::range::Range;
use crate::simplify::rewrite::{add_opt, rebuild, Analysis};
use crate::simplify::emit::IrEmit;
use crate::builtins::dd;
use crate::base::span::Span;
use crate::builtins::Builtin;
use crate::ir::{BinOp, Formula, Ir, Node, NodeId};

/// `factor-quadratic` (module docs).
pub(crate) struct FactorQuadratic;

impl Rule for FactorQuadratic {
    fn name(&self) -> &'static str {
        "factor-quadratic"
    }
    fn doc(&self) -> &'static str {
        "A*c^2 + (1 - A)*c as c*(1 + A*(c - 1)): no cancellation near c = 1"
    }
    fn sites(&self) -> Sites {
        Sites::Everywhere
    }
    fn apply(&self, _: &Source, a: &Analysis, _: Option<usize>) -> Option<Formula> {
        finish(a, factor_quadratic(a))
    }
    fn example(&self) -> Example {
        Example { before: "let c = NH\n0.786*n*c^2 + (1 - 0.786*n)*c", bake: &[], site: None, shows: "nh * (1 + 0.786 * n * (nh - 1))" }
    }
}

/// `compensated-base` (module docs).
pub(crate) struct CompensatedBase;

impl Rule for CompensatedBase {
    fn name(&self) -> &'static str {
        "compensated-base"
    }
    fn doc(&self) -> &'static str {
        "pow(a + b, y) corrected by the rounding errors of a + b and its terms: no amplification by y"
    }
    fn sites(&self) -> Sites {
        Sites::Everywhere
    }
    fn apply(&self, _: &Source, a: &Analysis, _: Option<usize>) -> Option<Formula> {
        finish(a, compensated_base(a))
    }
    fn example(&self) -> Example {
        Example { before: "param a = 16 in 1..1000\nmax(n/a*(NH - 1) + 1, 0)^a", bake: &[], site: None, shows: "fma(" }
    }
}

/// `compensated-sum` (module docs).
pub(crate) struct CompensatedSum;

impl Rule for CompensatedSum {
    fn name(&self) -> &'static str {
        "compensated-sum"
    }
    fn doc(&self) -> &'static str {
        "a + b that may cancel, plus the rounding errors of the sum and the terms below it (fma, 2Sum)"
    }
    fn sites(&self) -> Sites {
        Sites::FirstKept
    }
    fn apply(&self, _: &Source, a: &Analysis, site: Option<usize>) -> Option<Formula> {
        finish(a, compensated_sum(a, site.unwrap_or(0)))
    }
    fn example(&self) -> Example {
        Example { before: "let q = -1.1/(n*NH - n - 2*NH)\nq*n*(NH - 1) + 1", bake: &[], site: Some(2), shows: "fma(" }
    }
}

fn magnitude(r: Range) -> (f64, f64) {
    let lo = if r.lo > 0.0 { r.lo } else if r.hi < 0.0 { -r.hi } else { 0.0 };
    (lo, r.lo.abs().max(r.hi.abs()))
}

/// The exact error `a + b − s` of the rounded sum `s = a + b` (new-arena nodes): Fast2Sum (two operations)
/// when the ranges show |a| ≥ |b| (or the reverse), else Knuth's 2Sum (five), exact whatever the magnitudes.
fn sum_error(ir: &mut Ir, (a, ra): (NodeId, Range), (b, rb): (NodeId, Range), s: NodeId, sp: Span) -> NodeId {
    let (big, small) = if magnitude(ra).0 >= magnitude(rb).1 {
        (Some(a), b)
    } else if magnitude(rb).0 >= magnitude(ra).1 {
        (Some(b), a)
    } else {
        (None, a)
    };
    let em = &mut IrEmit::new(ir, sp);
    match big {
        Some(big) => dd::fast_two_sum_err(em, big, small, s),
        None => dd::two_sum_err(em, a, b, s),
    }
}

/// The rounding error of old node `x` (exact value of its expression tree minus its f64 value), to first order,
/// as new-arena nodes (`s` is `x`'s node there): each `+ −` contributes its 2Sum error, each `×` its fma
/// remainder, each `/` its exact remainder over the divisor, plus the operands' errors propagated through, down
/// to leaves and calls (which count as exact). Once per node (`memo`), so a shared term carries the same error
/// wherever it is used: an error compensated on one side of a cancellation only would break it. `None`: exact.
/// Valid while no product underflows.
pub(super) fn rounding_error(f: &Formula, ranges: &[Range], ir: &mut Ir, map: &[NodeId], (x, s): (NodeId, NodeId), memo: &mut [Option<Option<NodeId>>], sp: Span) -> Option<NodeId> {
    crate::base::stack::deep(|| {
        if let Some(e) = memo[x.index()] {
            return e;
        }
        let mut err = |ir: &mut Ir, y: NodeId| rounding_error(f, ranges, ir, map, (y, map[y.index()]), memo, sp);
        let e = match *f.ir.node(x) {
            Node::Neg(a) => err(ir, a).map(|e| ir.neg(e, sp)),
            // A sum that reads no input is taken as the rounded hi + lo of a double-double (`compensated-params`'s
            // value): its 2Sum error alone, since the error terms below it are the low part's own (an fma counts as
            // exact, so recursing would count them twice). Elsewhere it is the sum's own rounding, its operands' left
            // out. Free: computed once per parameter set.
            Node::Binary(BinOp::Add, a, b) if f.ir.used_inputs(x).is_empty() => {
                Some(sum_error(ir, (map[a.index()], ranges[a.index()]), (map[b.index()], ranges[b.index()]), s, sp))
            }
            Node::Binary(op @ (BinOp::Add | BinOp::Sub), a, b) => {
                let (ea, eb) = (err(ir, a), err(ir, b));
                let (ra, mut rb) = (ranges[a.index()], ranges[b.index()]);
                let mut bv = map[b.index()];
                let eb = if op == BinOp::Sub {
                    bv = ir.neg(bv, sp);
                    rb = Range::new(-rb.hi, -rb.lo, rb.nan, false);
                    eb.map(|e| ir.neg(e, sp))
                } else {
                    eb
                };
                let e = sum_error(ir, (map[a.index()], ra), (bv, rb), s, sp);
                let e2 = add_opt(ir, ea, eb, sp);
                add_opt(ir, Some(e), e2, sp)
            }
            Node::Binary(op @ (BinOp::Mul | BinOp::Div), a, b) => {
                let (av, bv) = (map[a.index()], map[b.index()]);
                let (ea, eb) = (err(ir, a), err(ir, b));
                let ns = ir.neg(s, sp);
                if op == BinOp::Mul {
                    // (a + ea)(b + eb) − ab ≈ ea·b + a·eb, ab − s exact in one fma.
                    let mut e = dd::two_prod_err(&mut IrEmit::new(ir, sp), av, bv, s);
                    if let Some(ea) = ea {
                        e = ir.call(Builtin::Fma, &[ea, bv, e], sp);
                    }
                    if let Some(eb) = eb {
                        e = ir.call(Builtin::Fma, &[av, eb, e], sp);
                    }
                    return memoize(memo, x, Some(e));
                }
                // (a + ea)/(b + eb) − q ≈ (a − q·b + ea − q·eb)/b, a − q·b exact in one fma.
                let mut r = ir.call(Builtin::Fma, &[ns, bv, av], sp);
                if let Some(ea) = ea {
                    r = ir.bin(BinOp::Add, r, ea, sp);
                }
                if let Some(eb) = eb {
                    r = ir.call(Builtin::Fma, &[ns, eb, r], sp);
                }
                Some(ir.bin(BinOp::Div, r, bv, sp))
            }
            // acos's own rounding, ≤ 1 ulp (its tail, `acoslo`, costs ~8 beside it).
            Node::Call(Builtin::Acos, [z, ..]) => Some(ir.call(Builtin::AcosLo, &[map[z.index()]], sp)),
            _ => None,
        };
        memoize(memo, x, e)
    })
}

fn memoize(memo: &mut [Option<Option<NodeId>>], x: NodeId, e: Option<NodeId>) -> Option<NodeId> {
    memo[x.index()] = Some(e);
    e
}

// a + b → (a + b) + e, e the first-order rounding error of the sum and the `+ − × /` below it, where a and b
// may have opposite signs (the sum may cancel: F_dsh, F_SCOS2); one site at a time
fn compensated_sum(a: &Analysis, only: usize) -> (Ir, NodeId, bool) {
    let (f, ranges) = (&a.f, a.ranges());
    let mut site = 0;
    let inv = f.ir.invariant();
    rebuild(f, |ir, map, id, n| {
        let Node::Binary(op @ (BinOp::Add | BinOp::Sub), a, b) = n else { return None };
        // A sum that reads no input is `compensated-params`'s to carry, once per parameter set.
        if inv[id.index()] {
            return None;
        }
        let (ra, rb) = (ranges[a.index()], ranges[b.index()]);
        let (pa, na) = (ra.hi > 0.0, ra.lo < 0.0);
        let (pb, nb) = (rb.hi > 0.0, rb.lo < 0.0);
        let cancels = match op {
            BinOp::Add => (pa && nb) || (na && pb),
            _ => (pa && pb) || (na && nb),
        };
        // A constant operand alone rounds once: nothing below it to carry.
        let deep = |x: NodeId| matches!(f.ir.node(x), Node::Binary(..));
        if !cancels || !(deep(a) || deep(b)) {
            return None;
        }
        site += 1;
        if site != only + 1 {
            return None;
        }
        let sp = f.ir.span(id);
        let sum = ir.bin(op, map[a.index()], map[b.index()], sp);
        let e = rounding_error(f, ranges, ir, map, (id, sum), &mut vec![None; f.ir.len()], sp)?;
        Some(ir.bin(BinOp::Add, sum, e, sp))
    })
}

// pow(s, y) with s = a + b (or max(a + b, 0)) → p + p·y·(e/s), p = pow(s, y), e = a + b − s exactly (2Sum)
fn compensated_base(a: &Analysis) -> (Ir, NodeId, bool) {
    let (f, ranges) = (&a.f, a.ranges());
    rebuild(f, |ir, map, id, n| {
        let Node::Call(Builtin::Pow, [base, y, _]) = n else { return None };
        // Constant exponents become chains (or compensated chains); this is for pow calls.
        if f.ir.node(y).as_const().is_some() {
            return None;
        }
        let sum = match *f.ir.node(base) {
            Node::Call(Builtin::Max, [s, z, _]) if f.ir.node(z).as_const() == Some(0.0) => s,
            _ => base,
        };
        if !matches!(f.ir.node(sum), Node::Binary(BinOp::Add, ..)) {
            return None;
        }
        let sp = f.ir.span(id);
        // The sum's own rounding error and, to first order, its addends' (F_ST's n/a·(c − 1)).
        let e = rounding_error(f, ranges, ir, map, (sum, map[sum.index()]), &mut vec![None; f.ir.len()], sp)?;
        let (s, y) = (map[sum.index()], map[y.index()]);
        // pow(s + e, y) = pow(s, y)·(1 + y·e/s + O((y·e/s)²)). The pair is renormalised first (Fast2Sum: s' the
        // sum s + e rounded, e' what it left out), so |e'/s'| ≤ 2⁻⁵³ and the first order holds even where the sum
        // cancelled (F_ST at n = a and NH = 10⁻²⁰: s = 0, e = NH, so s' = NH and e' = 0). s' ≤ 0 (clamped to a zero
        // base) divides by the smallest normal instead, so the correction is finite.
        let (s, e) = dd::fast_two_sum(&mut IrEmit::new(ir, sp), s, e);
        let b = match *f.ir.node(base) {
            Node::Call(Builtin::Max, [_, z, _]) => ir.call(Builtin::Max, &[s, map[z.index()]], sp),
            _ => s,
        };
        let tiny = ir.konst(f64::MIN_POSITIVE, sp);
        let den = ir.call(Builtin::Max, &[s, tiny], sp);
        let r = ir.bin(BinOp::Div, e, den, sp);
        let yr = ir.bin(BinOp::Mul, y, r, sp);
        let p = ir.call(Builtin::Pow, &[b, y], sp);
        Some(ir.call(Builtin::Fma, &[p, yr, p], sp))
    })
}

// A*c^2 + (1 - A)*c → c*(1 + A*(c - 1))
fn factor_quadratic(a: &Analysis) -> (Ir, NodeId, bool) {
    let f = &a.f;
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
    use super::super::tests::parse;
    use super::*;

    #[test]
    fn compensated_sum_carries_the_errors_below_a_cancelling_sum() {
        let f = parse("let q = -1.1/(n*NH - n - 2*NH)\nq*n*(NH - 1) + 1");
        // The sites in arena order: n·c − n, then − 2c, then the final + 1.
        let t = CompensatedSum.apply_to(&f, Some(2)).unwrap().to_program_text();
        assert!(CompensatedSum.apply_to(&f, Some(3)).is_none());
        // The sum's 2Sum error, the products' and the quotient's fma remainders, c − 1's Fast2Sum error.
        assert!(t.matches("fma(").count() >= 4, "{t}");
        // Same-signed terms do not cancel: no site. (Accuracy: tests/it/robust.rs.)
        assert!(CompensatedSum.apply_to(&parse("NH*NL + NV"), None).is_none());
    }

    #[test]
    fn compensated_base_corrects_a_live_power_of_a_sum() {
        let f = parse("param a = 16 in 1..1000\nmax(n/a*(NH - 1) + 1, 0)^a");
        let g = CompensatedBase.apply_to(&f, None).unwrap();
        let t = g.to_program_text();
        // One pow, the correction an fma, the renormalised base clamped as written.
        assert_eq!(t.matches("pow(").count(), 1, "{t}");
        assert!(t.contains("fma(") && t.contains("max("), "{t}");
        // At n = a the sum cancels to nothing (s = 0, e = NH): the renormalised base is NH itself.
        let ev = crate::backend::interp::Interp::new(&g);
        let mut x = [0.5; crate::ir::N_INPUTS];
        x[crate::ir::Input::NH.index()] = 1e-20;
        assert_eq!(crate::backend::Evaluator::eval(&ev, &x, &[1.0, 1.0]), 1e-20);
        // A constant exponent (a chain) and a base that is not a sum are left alone.
        assert!(CompensatedBase.apply_to(&parse("(NH + 1)^3"), None).is_none());
        assert!(CompensatedBase.apply_to(&parse("NH^n"), None).is_none());
    }

    #[test]
    fn quadratic_factors_live_and_baked() {
        let src = "let c = NH\n0.786*n*c^2 + (1 - 0.786*n)*c";
        let g = FactorQuadratic.apply_to(&parse(src), None).unwrap();
        assert!(g.to_text().contains("- 1"), "{}", g.to_text());
        let f = crate::front::parse("q.brdf", src).unwrap();
        let baked = crate::simplify::simplify(&f, &[(0, 1000.0)]);
        assert!(FactorQuadratic.apply_to(&baked, None).is_some(), "{}", baked.to_text());
        assert!(FactorQuadratic.apply_to(&parse("2*NH^2 + 3*NH"), None).is_none());
    }
}
