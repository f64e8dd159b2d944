//! The power forms the power family's rules rebuild formulas into: integer powers above 8 kept as `pow` calls
//! ([`pow_call_policy`]) or rebuilt as compensated multiplication chains ([`compensated_powers`]). Plain
//! transforms of the IR: the rules that choose them are in `power`.

use crate::builtins::dd::Arith;
use crate::builtins::Builtin;
use crate::ir::{BinOp, Formula, Ir, Node, NodeId};
use crate::simplify::emit::IrEmit;
use crate::simplify::rewrite::rebuild;
use crate::simplify::{node_ranges, Policy};

/// The simplifier policy of the `pow-call` candidate: integer powers above 8 stay `pow` calls (libm's < 1 ulp)
/// instead of multiplication chains (error up to (k − 1)·u; 449 ulp measured at k = 1000).
pub fn pow_call_policy() -> Policy {
    Policy { max_chain: 8, ..Policy::default() }
}

/// The `compensated-power` candidate: `f` simplified with [`pow_call_policy`] (so integer powers above 8 are
/// still `pow` calls), each `pow(x, k)` with a constant integer 9 ≤ k ≤ [`crate::simplify::MAX_POW_CHAIN`] and
/// |x| ≤ 2^(1000/k) by range analysis rebuilt as a compensated multiplication chain, then simplified again.
/// `None` when no power qualifies.
///
/// The plain chain's relative error is Σ mⱼ·δⱼ, δⱼ the rounding of step j and mⱼ how often its power enters
/// x^k ([`crate::simplify::powi::multiplicities`]; Σ mⱼ = k − 1, most of it on the first squarings). Each step whose
/// error would weigh more carries x^j as an unevaluated sum `h + l`: `h = hₐ·h_b` and its exact rounding error
/// `fma(hₐ, h_b, −h)` plus the first-order terms `hₐ·l_b + lₐ·h_b` (one or two more fmas) make the new `l`.
/// The last steps, as many as keep their Σ mⱼ ≤ [`UNTAILED_WEIGHT`] (3: the last two of a binary chain), round
/// once each instead: a step whose operands carry an `l` folds it into its product with one fma
/// (`fma(hₐ, h_b, hₐ·l_b + lₐ·h_b)`), the others are plain products. The result is within 3u relative (< 3 ulp)
/// of x^k to first order whatever k, where the plain chain's grows like k·u (~490 ulp at k = 1000) and the
/// fully compensated chain's is 0.5u: measured against the truth on 10⁵ points, ≤ 2 ulp at k ∈ {9 … 1024}
/// (live `pow` ≤ 0.51), so baked and live agree within 4 ulp. It saves the last steps' tails, the error fma
/// of the fold and the final `h + l`: 13 operations over the plain chain's 7 at k = 50 where carrying every
/// step took 17, 31 over 14 at k = 1000 (BENCHMARKS.md §2).
///
/// Why a special budget ([`crate::numerics::robust`]) remains: the tails cannot be much cheaper. Within
/// 3u, every step but the last two needs its rounding error, one fma each, and carrying it one step further
/// is another fma (and `hₐ + hₐ` for a square), so ~2–3 operations per step where the plain chain has 1; no
/// k ≥ 9 fits in 1.3× the plain chain's static cost (k = 9: 4 multiplications, 7 more here).
///
/// For a base known ≥ +0 (Blinn's and Phong's clamped cosines) two more things: (1) below the x₀ where x^k
/// rounds to +0 the chain no longer underflows on large k, and raises a clamp's lower bound to x₀ on small k
/// ([`underflow_guard`]); (2) an odd power's result is wrapped in `abs` (it is ≥ +0 already) so the range
/// analysis can drop the lowering's root `max(raw, 0)` (two instructions, one here); an even power ends in a
/// square, which it knows.
pub fn compensated_powers(f: &Formula) -> Option<Formula> {
    let ranges = node_ranges(f, &Policy::default());
    let uses = f.ir.use_counts(f.root);
    let (ir, root, fired) = rebuild(f, |ir, map, id, n| {
        let Node::Call(Builtin::Pow, [x, k, _]) = n else { return None };
        let k = f.ir.node(k).as_const()?;
        let r = ranges[x.index()];
        // |x| ≤ 2^(1000/k): x^k, every partial power and every error term stay finite (∞ − ∞ would be NaN).
        let bound = (1000.0 / k).exp2();
        if !(k.fract() == 0.0 && (9.0..=f64::from(crate::simplify::MAX_POW_CHAIN)).contains(&k) && !r.nan && r.lo >= -bound && r.hi <= bound) {
            return None;
        }
        let s = f.ir.span(id);
        let k = k as u32;
        let steps = crate::simplify::powi::steps(k);
        let m = crate::simplify::powi::multiplicities(k);
        // Steps from `plain_from` on carry no error term; their multiplicities add up to ≤ UNTAILED_WEIGHT.
        let mut left = UNTAILED_WEIGHT;
        let plain_from = (0..steps.len())
            .rev()
            .take_while(|&j| {
                let fits = m[j] <= left;
                left = left.saturating_sub(m[j]);
                fits
            })
            .last()
            .unwrap_or(steps.len());
        let base = if r.nonneg() { underflow_guard(f, ir, map, x, k, uses[x.index()] == 1) } else { map[x.index()] };
        // Exponent j → (h, l) with x^j = h + l to first order; l = None where h carries no error term.
        let mut have: Vec<(u32, NodeId, Option<NodeId>)> = vec![(1, base, None)];
        for (j, &(a, b)) in steps.iter().enumerate() {
            let get = |j: u32| have.iter().find(|e| e.0 == j).map(|e| (e.1, e.2));
            let ((ha, la), (hb, lb)) = (get(a)?, get(b)?);
            if j >= plain_from {
                // One rounding: hₐ·h_b + (hₐ·l_b + lₐ·h_b) in one fma, or a plain product when neither has a tail.
                let t = if a == b {
                    la.map(|la| {
                        let two = ir.bin(BinOp::Add, ha, ha, s);
                        ir.bin(BinOp::Mul, two, la, s)
                    })
                } else {
                    match (la, lb) {
                        (None, None) => None,
                        (Some(la), None) => Some(ir.bin(BinOp::Mul, la, hb, s)),
                        (None, Some(lb)) => Some(ir.bin(BinOp::Mul, ha, lb, s)),
                        (Some(la), Some(lb)) => {
                            let p = ir.bin(BinOp::Mul, la, hb, s);
                            Some(ir.call(Builtin::Fma, &[ha, lb, p], s))
                        }
                    }
                };
                let h = match t {
                    Some(t) => ir.call(Builtin::Fma, &[ha, hb, t], s),
                    None => ir.bin(BinOp::Mul, ha, hb, s),
                };
                have.push((a + b, h, None));
                continue;
            }
            let (h, mut l) = IrEmit::new(ir, s).two_prod(ha, hb);
            if a == b {
                if let Some(la) = la {
                    let two = ir.bin(BinOp::Add, ha, ha, s);
                    l = ir.call(Builtin::Fma, &[two, la, l], s);
                }
            } else {
                if let Some(lb) = lb {
                    l = ir.call(Builtin::Fma, &[ha, lb, l], s);
                }
                if let Some(la) = la {
                    l = ir.call(Builtin::Fma, &[la, hb, l], s);
                }
            }
            have.push((a + b, h, Some(l)));
        }
        // The last step's multiplicity is 1, so it never carries a tail.
        let (_, y, _) = *have.last()?;
        let square = matches!(*ir.node(y), Node::Binary(BinOp::Mul, p, q) if p == q);
        Some(if r.nonneg() && !square { ir.call(Builtin::Abs, &[y], s) } else { y })
    });
    if !fired {
        return None;
    }
    let g = Formula { ir, root, ..f.clone() };
    Some(crate::simplify::simplify_with(&g, &[], &Policy::default()).0)
}

/// The base of a compensated power x^k for x ≥ +0 (docs of [`compensated_powers`]): x₀ = 2^(−1076/k)·(1 − 2⁻⁴⁰)
/// is where x^k drops below a quarter of the smallest subnormal, so that below it the result rounds to +0.
/// - x₀ ≥ 2⁻⁸ (k ≥ 135): the base becomes 0 below x₀, `max(min(x, fma(x, 2¹⁰⁰⁰, −x₀·2¹⁰⁰⁰)), 0)` (the fma
///   exceeds 2⁹⁴⁶ above x₀ and is ≤ 0 at and below it), so the chain multiplies zeros there instead of
///   underflowing: an underflowing product costs a microcode assist (measured: `clamp(NH, x₀, 1)^1000`, whose last product
///   underflows to 0 on the 47 % of `lobe bench`'s uniform inputs below x₀, takes 33 ns against NH^1000's
///   6.2 ns). Two instructions when x is the lowering's `clamp(v, 0, hi)` read only here (the min and the
///   fma go inside it), four otherwise. On uniform inputs that pays from ~0.5 % of them below x₀.
/// - Otherwise, when x is such a clamp, x₀ replaces its 0 (the chain on x₀ gives +0, the rounded x^k):
///   `max(v, x₀)` is one instruction where `max(v, +0)` is two (it repairs −0). Other bases stay as they are.
fn underflow_guard(f: &Formula, ir: &mut Ir, map: &[NodeId], x: NodeId, k: u32, only_use: bool) -> NodeId {
    let s = f.ir.span(x);
    let floor = (-1076.0 / f64::from(k)).exp2() * (1.0 - 2f64.powi(-40));
    let clamp = match *f.ir.node(x) {
        Node::Call(Builtin::Clamp, [v, lo, hi])
            if only_use && f.ir.node(lo).as_const() == Some(0.0) && f.ir.node(hi).as_const().is_some_and(|h| h >= floor) =>
        {
            Some((map[v.index()], map[hi.index()]))
        }
        _ => None,
    };
    let zero = ir.konst(0.0, s);
    if floor >= 2f64.powi(-8) {
        let big = ir.konst(2f64.powi(1000), s);
        let shift = ir.konst(-floor * 2f64.powi(1000), s);
        let (v, lo, hi) = match clamp {
            Some((v, hi)) => (v, zero, Some(hi)),
            None => (map[x.index()], zero, None),
        };
        let g = ir.call(Builtin::Fma, &[v, big, shift], s);
        let m = ir.call(Builtin::Min, &[v, g], s);
        return match hi {
            Some(hi) => ir.call(Builtin::Clamp, &[m, lo, hi], s),
            None => ir.call(Builtin::Max, &[m, lo], s),
        };
    }
    match clamp {
        Some((v, hi)) => {
            let x0 = ir.konst(floor, s);
            ir.call(Builtin::Clamp, &[v, x0, hi], s)
        }
        None => map[x.index()],
    }
}

/// How much multiplicity (module docs of [`compensated_powers`]) the chain's last, uncompensated steps may
/// have: their roundings bound the result's relative error by 3u, under 3 ulp, so with live `pow` (≤ 0.51 ulp
/// measured) baked and live stay within the 4 ulp.
pub(crate) const UNTAILED_WEIGHT: u32 = 3;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn compensated_power_replaces_large_integer_powers_only() {
        let f = crate::front::parse("b.brdf", "NH^n").unwrap();
        let calls = |b: u32| crate::simplify::simplify_with(&f, &[(0, f64::from(b))], &pow_call_policy()).0;
        let g = compensated_powers(&calls(1000)).unwrap();
        let t = g.to_program_text();
        assert!(t.contains("fma(") && !t.contains("pow("), "{t}");
        let mut xs = [0.5; crate::ir::N_INPUTS];
        xs[crate::ir::Input::NH.index()] = 0.999_999_7;
        let ev = crate::backend::interp::Interp::new(&g);
        // glibc's pow is within 1 ulp; the plain chain is off by ~100 ulp here.
        let (got, want) = (crate::backend::Evaluator::eval(&ev, &xs, &[1000.0]), 0.999_999_7f64.powf(1000.0));
        assert!((got - want).abs() <= 2.0 * f64::EPSILON * want, "{got} {want}");
        // Small powers stay chains, live exponents and bases whose power may overflow (|x| > 2^(1000/k)) stay as
        // they are; a base above 1 whose power is finite becomes a chain, as accurate.
        assert!(compensated_powers(&calls(8)).is_none());
        assert!(compensated_powers(&crate::simplify::simplify_with(&f, &[], &pow_call_policy()).0).is_none());
        let power = |text: &str| compensated_powers(&crate::simplify::simplify_with(&crate::front::parse("b.brdf", text).unwrap(), &[(0, 1000.0)], &pow_call_policy()).0);
        assert!(power("(4*NH)^n").is_none());
        let g = power("(2*NH)^n").unwrap();
        let got = crate::backend::Evaluator::eval(&crate::backend::interp::Interp::new(&g), &xs, &[1000.0]);
        let want = (2.0 * 0.999_999_7f64).powf(1000.0);
        assert!(want.is_finite() && (got - want).abs() <= 2.0 * f64::EPSILON * want, "{got} {want}");
    }
}
