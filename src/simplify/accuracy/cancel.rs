//! The accuracy pass's rules for the last ulps: rewrites that move a cancellation into work on the parameters
//! only, which is free per point, or into one fused operation, and that carry the roundings exp would amplify.
//!
//! # Design
//! `rational-form`: a sum whose terms are rational in one live *atom* x (an input, or any live node that is
//! not `+ − × /`), with coefficients that read no input, is the quotient of two polynomials in x. With both of
//! degree ≤ 1, the sum is rewritten `(a₁·x + a₀)/(b₁·x + b₀)` (a polynomial, the denominator constant,
//! as `a₁·x + a₀` with the constant divided into its coefficients), each polynomial evaluated as
//! `fma(a₁ʰ, x, a₀ʰ) + fma(a₁ˡ, x, a₀ˡ)`, where every coefficient is a double-double `aʰ + aˡ` computed (2Sum, fma
//! two-product) from the subexpressions that read no input, themselves in double-double (the quadratic model's
//! 1 − 0.786·n at n = 1/0.786 is the low part of 0.786·n). A baked kernel folds the same expression the live
//! one's prepared block computes: the pass decides live and bakes that decision (`numerics::robust`).
//! In a sum with other terms (of higher degree, or in another atom), the terms that qualify are regrouped and
//! the others added to the quotient as written: F_dsh's c/(n(1 − c) + c) − 0.25 beside its c⁸ term, where
//! the first two cancel (0.266 − 0.25). That changes where the whole sum rounds, so a baked and a live kernel
//! agree only if the pass makes the same choice for both: it decides with every parameter live and bakes that
//! choice (`numerics::robust`). The written form's cancellation — Modified cosine-quadratic's
//! `1 − 1.1·u/(u + 2c)`, u = n(1 − c) — then happens inside the coefficient arithmetic, in double-double; what is
//! left per point is one rounding of a₁ʰx + a₀ʰ (the fma), one of the addition of the low parts (below an ulp
//! of it), and the same for the denominator and the quotient: ≤ ~2.5 ulp, except near the numerator's own
//! zero, where the value is ill-conditioned by nature (its zero moves with the parameters).
//!
//! A term's form is found bottom-up ([`shapes`]): degrees add under `×`, `/` and `+` (a common denominator, no
//! gcd); a sum whose numerator or denominator would exceed degree 1 is left alone.
//!
//! `compensated-exp`: exp multiplies its argument's absolute error into its result's relative error, so an
//! argument of −8.6 (Beckmann) or −20 (the Gaussian) carrying a few roundings of ½ ulp each costs 10–40 ulp where
//! the formula's condition is 14. The argument, a product/quotient tree `K·q` with K the factors that read no
//! input and q the live ones, is computed as a = Kʰ·q with K = Kʰ + Kˡ in double-double (free: parameter-only),
//! and t = fma(Kʰ, q, −a) + Kˡ·q + Kʰ·e_q, e_q the rounding error of q where it is one factor or a product of two
//! (an fma; an acos factor's own error through the builtin `acoslo`); a quotient's is left out (a division). Then
//! exp(K·q) = e^a·(1 + t): `fma(e, t, e)`, or for `expmuldiv(K·q, b, c)` the tail multiplies b's parameter-only
//! factor (b's other factors divided in after), so no new rounding meets it. The exponent must be ≤ 0 by its
//! factors' signs, and q's divisors (≥ 0) are floored at 2⁻¹⁰⁰⁰, so where one vanishes the exponent is a huge
//! negative number and not −∞ (e^a is 0 either way; t stays a number instead of ∞ − ∞).
//!
//! `compensated-params`: a parameter-only value is computed once per parameter set, so it can afford
//! double-double. Each maximal parameter-only subtree a live node reads, if its plain evaluation rounds more than
//! once (pow and acos count twice: they are not correctly rounded), is rebuilt with `+ − × /` as above, pow as
//! `pow + powlo` plus its operands' low parts to first order, acos as `acos + acoslo − xˡ/√((1 − x)(1 + x))` (the
//! first-order term dropped where it is not small next to acos: near ±1 acos grows like √(1 − x)), sqrt with its
//! fma remainder, exp and ln with their operands' low parts, and rounded once where the kernel reads it. The rule
//! runs on the live formula (`numerics::robust`); baking the decision then folds the same double-double
//! expression through the same builtins the live kernel's prepared block runs, so the two agree bit for bit.
//!
//! # Cost model
//! Coefficients read no input: free ([`super::cost`]). Per point: two fmas and an addition per
//! polynomial (fewer where a coefficient is exact or zero), one division when the denominator is not constant
//! — usually cheaper than the written chain of products, quotients and sums it replaces. `compensated-exp`: 2–4
//! fmas, one max per floored divisor, one fma applying the tail, acoslo (8) per acos factor; b's parameter-only
//! factor no longer multiplies per point. Both catalogue uses sit just within the 1.3× budget, statically and as
//! measured (BENCHMARKS.md §2). `compensated-params`: nothing per point (the prepared block grows; compile
//! time with it, e.g. F_kutlog's JIT from ~6 to ~30 ms).

use crate::simplify::rewrite::{add_opt, divide_apart, product, rebuild, Analysis};
use crate::simplify::emit::IrEmit;
use crate::builtins::dd;
use crate::builtins::dd::Arith;
use crate::base::span::Span;
use crate::builtins::Builtin;
use crate::ir::{BinOp, Formula, Ir, Node, NodeId};
use std::collections::HashMap;
use super::rule::{Example, Rule, Sites, Source};
use super::finish;

/// `rational-form` (module docs).
pub(crate) struct RationalForm;

impl Rule for RationalForm {
    fn name(&self) -> &'static str {
        "rational-form"
    }
    fn doc(&self) -> &'static str {
        "a sum rational in one input as (a1*x + a0)/(b1*x + b0), coefficients in double-double: the cancellation moves to the parameters"
    }
    fn sites(&self) -> Sites {
        Sites::Everywhere
    }
    fn apply(&self, _: &Source, a: &Analysis, _: Option<usize>) -> Option<Formula> {
        finish(a, rational_form(a))
    }
    fn example(&self) -> Example {
        Example { before: "let c = NH\nc/(n - n*c + c) - 0.25", bake: &[], site: None, shows: "fma(" }
    }
}

/// `compensated-exp` (module docs).
pub(crate) struct CompensatedExp;

impl Rule for CompensatedExp {
    fn name(&self) -> &'static str {
        "compensated-exp"
    }
    fn doc(&self) -> &'static str {
        "exp(K*q) as exp(hi)*(1 + t), K's parameter-only factors in double-double and t the product's rounding error: exp no longer amplifies it"
    }
    fn sites(&self) -> Sites {
        Sites::Everywhere
    }
    fn apply(&self, _: &Source, a: &Analysis, _: Option<usize>) -> Option<Formula> {
        finish(a, compensated_exp(a))
    }
    fn example(&self) -> Example {
        Example { before: "exp(-n * NH * NH)", bake: &[], site: None, shows: "fma(" }
    }
}

/// `compensated-params` (module docs): the current formula (live) with each parameter-only subtree the kernel
/// reads in double-double and rounded once, then simplified with the source's baked values: baking the pass's
/// decision folds the same expression the live kernel's prepared block computes. Free per point: the block is
/// computed once per parameter set.
pub(crate) struct CompensatedParams;

impl Rule for CompensatedParams {
    fn name(&self) -> &'static str {
        "compensated-params"
    }
    fn doc(&self) -> &'static str {
        "parameter-only subexpressions in double-double, rounded once where the kernel reads them"
    }
    fn sites(&self) -> Sites {
        Sites::Whole
    }
    fn apply(&self, src: &Source, a: &Analysis, _: Option<usize>) -> Option<Formula> {
        let (ir, root, fired) = compensated_params(a);
        fired.then(|| crate::simplify::simplify(&Formula { ir, root, ..a.f.clone() }, src.bake()))
    }
    fn example(&self) -> Example {
        Example { before: "param k = 2 in 1..5\nparam Q = 0.5 in 0.1..0.9\nacos(pow(Q, 1/k)) * NH", bake: &[], site: None, shows: "acoslo(" }
    }
    /// First where a parameter-only part calls a transcendental builtin (F_kutlog's C = acos(Q^(1/k))/acos(Q^(1/n))):
    /// the rules after it carry those parts' residuals, which exist only once they are double-double. Otherwise
    /// last: the rules' patterns read rational parameter parts as written (the quadratic model's 1 − A beside A).
    fn early(&self, a: &Analysis) -> bool {
        let (f, inv) = (&a.f, a.invariant());
        f.ir.ids().any(|id| {
            inv[id.index()] && matches!(f.ir.node(id), Node::Call(b, _) if !matches!(b, Builtin::Min | Builtin::Max | Builtin::Abs | Builtin::Clamp | Builtin::Sqrt | Builtin::Fma | Builtin::Select))
        })
    }
}

/// Largest degree in x of a rewritten numerator or denominator: linear-fractional forms, whose evaluation by
/// one fma per part keeps the bound above (a Horner chain would round at each step).
const MAX_DEG: u8 = 1;

/// The degrees of an old node as a rational function of its atom (`None`: reads no input).
#[derive(Clone, Copy, Debug, PartialEq)]
struct Shape {
    atom: Option<NodeId>,
    num: u8,
    den: u8,
}

const COEF: Shape = Shape { atom: None, num: 0, den: 0 };

fn combine(op: BinOp, x: Shape, y: Shape) -> Option<Shape> {
    let atom = match (x.atom, y.atom) {
        (Some(a), Some(b)) if a != b => return None,
        (a, b) => a.or(b),
    };
    let (num, den) = match op {
        BinOp::Add | BinOp::Sub => ((x.num + y.den).max(y.num + x.den), x.den + y.den),
        BinOp::Mul => (x.num + y.num, x.den + y.den),
        BinOp::Div => (x.num + y.den, x.den + y.num),
    };
    Some(Shape { atom, num, den }).filter(|s| s.num <= MAX_DEG && s.den <= MAX_DEG)
}

/// Per old node, its shape when it is rational of degree ≤ [`MAX_DEG`] in one atom.
fn shapes(f: &Formula, inv: &[bool]) -> Vec<Option<Shape>> {
    let mut out: Vec<Option<Shape>> = Vec::with_capacity(f.ir.len());
    for id in f.ir.ids() {
        let s = if inv[id.index()] {
            Some(COEF)
        } else {
            match *f.ir.node(id) {
                Node::Neg(a) => out[a.index()],
                Node::Binary(op, a, b) => out[a.index()].zip(out[b.index()]).and_then(|(x, y)| combine(op, x, y)),
                _ => Some(Shape { atom: Some(id), num: 1, den: 0 }),
            }
        };
        out.push(s);
    }
    out
}

/// A double-double `hi + lo` of new-arena nodes (`lo: None` when hi is exact).
type Dd = dd::partial::Dd<NodeId>;

/// A polynomial in the atom, lowest degree first; `None` is an exact zero coefficient.
type Poly = Vec<Option<Dd>>;

struct Builder<'a> {
    f: &'a Formula,
    inv: &'a [bool],
    sp: Span,
    rats: HashMap<NodeId, (Poly, Poly)>,
}

impl<'a> Builder<'a> {
    fn new(f: &'a Formula, inv: &'a [bool]) -> Builder<'a> {
        Builder { f, inv, sp: Span::default(), rats: HashMap::new() }
    }

    fn is(&self, ir: &Ir, x: NodeId, v: f64) -> bool {
        ir.node(x).as_const() == Some(v)
    }

    fn norm(&self, ir: &mut Ir, hi: NodeId, lo: Option<NodeId>) -> Dd {
        dd::partial::norm(&mut IrEmit::new(ir, self.sp), hi, lo)
    }

    fn neg(&self, ir: &mut Ir, a: Dd) -> Dd {
        dd::partial::neg(&mut IrEmit::new(ir, self.sp), a)
    }

    fn add(&self, ir: &mut Ir, a: Dd, b: Dd) -> Dd {
        dd::partial::add(&mut IrEmit::new(ir, self.sp), a, b)
    }

    fn mul(&self, ir: &mut Ir, a: Dd, b: Dd) -> Dd {
        dd::partial::mul(&mut IrEmit::new(ir, self.sp), a, b)
    }

    fn div(&self, ir: &mut Ir, a: Dd, b: Dd) -> Dd {
        dd::partial::div(&mut IrEmit::new(ir, self.sp), a, b)
    }

    fn padd(&self, ir: &mut Ir, p: &Poly, q: &Poly) -> Poly {
        (0..p.len().max(q.len()))
            .map(|i| match (p.get(i).copied().flatten(), q.get(i).copied().flatten()) {
                (Some(a), Some(b)) => Some(self.add(ir, a, b)),
                (a, b) => a.or(b),
            })
            .collect()
    }

    fn pmul(&self, ir: &mut Ir, p: &Poly, q: &Poly) -> Poly {
        let mut out: Poly = vec![None; p.len() + q.len() - 1];
        for (i, a) in p.iter().enumerate() {
            for (j, b) in q.iter().enumerate() {
                let (Some(a), Some(b)) = (a, b) else { continue };
                let t = self.mul(ir, *a, *b);
                out[i + j] = Some(match out[i + j] {
                    Some(s) => self.add(ir, s, t),
                    None => t,
                });
            }
        }
        out
    }

    fn pneg(&self, ir: &mut Ir, p: &Poly) -> Poly {
        p.iter().map(|c| c.map(|c| self.neg(ir, c))).collect()
    }

    fn one(&self, ir: &mut Ir) -> Poly {
        vec![Some(Dd { hi: ir.konst(1.0, self.sp), lo: None })]
    }

    /// `x` (an old node of some shape) as numerator and denominator polynomials; a parameter-only node as
    /// `leaf` gives it (its double-double value).
    fn rat(&mut self, ir: &mut Ir, x: NodeId, shapes: &[Option<Shape>], leaf: &mut dyn FnMut(&mut Ir, NodeId) -> Dd) -> (Poly, Poly) {
        crate::base::stack::deep(|| {
            if let Some(r) = self.rats.get(&x) {
                return r.clone();
            }
            let one = self.one(ir);
            let r = if self.inv[x.index()] {
                // In double-double (the quadratic model's 1 − 0.786·n at n = 1/0.786 is the low part of 0.786·n):
                // the live kernel computes it once per parameter set, and a baked one folds the same expression.
                (vec![Some(leaf(ir, x))], one)
            } else {
                match *self.f.ir.node(x) {
                    Node::Neg(a) => {
                        let (n, d) = self.rat(ir, a, shapes, leaf);
                        (self.pneg(ir, &n), d)
                    }
                    Node::Binary(op, a, b) if shapes[x.index()].is_some() => {
                        let (na, da) = self.rat(ir, a, shapes, leaf);
                        let (nb, db) = self.rat(ir, b, shapes, leaf);
                        let nb = if op == BinOp::Sub { self.pneg(ir, &nb) } else { nb };
                        match op {
                            BinOp::Add | BinOp::Sub => {
                                let l = self.pmul(ir, &na, &db);
                                let r = self.pmul(ir, &nb, &da);
                                (self.padd(ir, &l, &r), self.pmul(ir, &da, &db))
                            }
                            BinOp::Mul => (self.pmul(ir, &na, &nb), self.pmul(ir, &da, &db)),
                            BinOp::Div => (self.pmul(ir, &na, &db), self.pmul(ir, &da, &nb)),
                        }
                    }
                    // The atom: 0 + 1·x.
                    _ => (vec![None, one[0]], one),
                }
            };
            self.rats.insert(x, r.clone());
            r
        })
    }

    /// A polynomial of degree ≤ 1 at the atom `x`: `fma(c₁ʰ, x, c₀ʰ) + fma(c₁ˡ, x, c₀ˡ)`, terms that are zero or
    /// one left out.
    fn eval(&self, ir: &mut Ir, p: &Poly, x: NodeId) -> NodeId {
        let sp = self.sp;
        let (c0, c1) = (p.first().copied().flatten(), p.get(1).copied().flatten());
        let part = |ir: &mut Ir, a: Option<NodeId>, b: Option<NodeId>| match (a, b) {
            (None, b) => b,
            (Some(a), b) if self.is(ir, a, 1.0) => Some(match b {
                Some(b) => ir.bin(BinOp::Add, x, b, sp),
                None => x,
            }),
            (Some(a), Some(b)) => Some(ir.call(Builtin::Fma, &[a, x, b], sp)),
            (Some(a), None) => Some(ir.bin(BinOp::Mul, a, x, sp)),
        };
        let hi = part(ir, c1.map(|c| c.hi), c0.map(|c| c.hi));
        let lo = part(ir, c1.and_then(|c| c.lo), c0.and_then(|c| c.lo));
        add_opt(ir, hi, lo, sp).unwrap_or_else(|| ir.konst(0.0, sp))
    }
}

/// Most terms [`terms`] lists for one sum. A sum is a DAG: `s₁ = x + x`, `s₂ = s₁ + s₁`, … lists 2ᵏ terms
/// from k nodes, so a sum with more terms than this is left as written rather than flattened.
const MAX_TERMS: usize = 4096;

/// Signed terms of the sum tree under `x` (through `+`, `−` and negation of live nodes); `false` (and `out`
/// incomplete) when there are more than [`MAX_TERMS`].
fn terms(f: &Formula, inv: &[bool], x: NodeId, neg: bool, out: &mut Vec<(NodeId, bool)>) -> bool {
    if out.len() >= MAX_TERMS {
        return false;
    }
    crate::base::stack::deep(|| match *f.ir.node(x) {
        _ if inv[x.index()] => {
            out.push((x, neg));
            true
        }
        Node::Neg(a) => terms(f, inv, a, !neg, out),
        Node::Binary(op @ (BinOp::Add | BinOp::Sub), a, b) => {
            terms(f, inv, a, neg, out) && terms(f, inv, b, neg ^ (op == BinOp::Sub), out)
        }
        _ => {
            out.push((x, neg));
            true
        }
    })
}

// Σ ±tᵢ (tᵢ rational in one atom, of degree ≤ 1 together) → (a₁x + a₀)/(b₁x + b₀)
pub(super) fn rational_form(a: &Analysis) -> (Ir, NodeId, bool) {
    let (f, inv, ranges) = (&a.f, a.invariant(), a.ranges());
    let shapes = shapes(f, inv);
    // A sum's root: a live `+`/`−` none of whose users is one (the whole tree is rewritten at its root).
    let mut in_sum = vec![false; f.ir.len()];
    for i in (0..f.ir.len()).rev() {
        let n = *f.ir.node(NodeId(i as u32));
        if matches!(n, Node::Binary(BinOp::Add | BinOp::Sub, ..)) || matches!(n, Node::Neg(_)) && in_sum[i] {
            n.for_each_arg(|a| in_sum[a.index()] = true);
        }
    }
    let uses = f.ir.use_counts(f.root);
    let mut b = Builder::new(f, inv);
    let mut pd = ParamDd { b: Builder::new(f, inv), ranges, memo: HashMap::new() };
    rebuild(f, |ir, map, id, n| {
        if inv[id.index()] || in_sum[id.index()] && uses[id.index()] <= 1 || !matches!(n, Node::Binary(BinOp::Add | BinOp::Sub, ..)) {
            return None;
        }
        let mut all = vec![];
        if !terms(f, inv, id, false, &mut all) {
            return None;
        }
        // The terms that are rational in one atom and of degree ≤ 1 together join, in order (F_dsh's
        // c/(n − n·c + c) and −0.25); the others (its c⁸ term) are added to the joined quotient as written.
        let mut acc: Option<Shape> = None;
        let (mut ts, mut rest) = (vec![], vec![]);
        for t in all {
            let joined = shapes[t.0.index()].and_then(|s| match acc {
                None => Some(s),
                Some(a) => combine(BinOp::Add, a, s),
            });
            match joined {
                Some(s) => {
                    acc = Some(s);
                    ts.push(t);
                }
                None => rest.push(t),
            }
        }
        // Only a sum that may cancel (terms of both signs, by range) has rounding errors to move; a sum of
        // same-signed terms is accurate as written.
        let signs = |(t, neg): &(NodeId, bool)| {
            let r = ranges[t.index()];
            let (lo, hi) = if *neg { (-r.hi, -r.lo) } else { (r.lo, r.hi) };
            (hi > 0.0, lo < 0.0)
        };
        if !(ts.iter().any(|t| signs(t).0) && ts.iter().any(|t| signs(t).1)) {
            return None;
        }
        let atom = acc.and_then(|s| s.atom)?;
        // Nothing to gain where the live terms are the atom itself: the sum is already x + a₀.
        if ts.len() < 2 || ts.iter().all(|(t, _)| inv[t.index()] || *t == atom) {
            return None;
        }
        b.sp = f.ir.span(id);
        pd.b.sp = b.sp;
        let one = b.one(ir);
        let (mut num, mut den): (Poly, Poly) = (vec![None], one);
        for (t, neg) in ts {
            let (n, d) = b.rat(ir, t, &shapes, &mut |ir, x| pd.dd(ir, map, x));
            let n = if neg { b.pneg(ir, &n) } else { n };
            let l = b.pmul(ir, &num, &d);
            let r = b.pmul(ir, &n, &den);
            num = b.padd(ir, &l, &r);
            den = b.pmul(ir, &den, &d);
        }
        let x = map[atom.index()];
        // A polynomial (constant denominator): its coefficients divided by that constant in double-double, and
        // no division per point. The same cost as Modified cosine's n/2·(c − 1) + 1 written, and exact where the
        // written form cancels to nothing (n = 2 at c = 10⁻¹⁰: 1 + (c − 1) loses c − 1's rounding, ~10⁻¹⁶).
        let mut v = if den.len() < 2 {
            let d0 = den.first().copied().flatten()?;
            let num: Poly = num.iter().map(|c| c.map(|c| b.div(ir, c, d0))).collect();
            b.eval(ir, &num, x)
        } else {
            let (nv, dv) = (b.eval(ir, &num, x), b.eval(ir, &den, x));
            ir.bin(BinOp::Div, nv, dv, b.sp)
        };
        for (t, neg) in rest {
            v = ir.bin(if neg { BinOp::Sub } else { BinOp::Add }, v, map[t.index()], b.sp);
        }
        Some(v)
    })
}

/// Factors of a `×`/`÷`/negation tree under `x`: (negated, numerators, denominators); `None` beyond
/// [`MAX_FACTORS`] factors. A parameter-only subtree is one factor, taken as the kernel computes it, which is
/// what baking folds it to: baked and live kernels then start from the same values.
fn factors(f: &Formula, inv: &[bool], x: NodeId) -> Option<(bool, Vec<NodeId>, Vec<NodeId>)> {
    type Out = (bool, Vec<NodeId>, Vec<NodeId>);
    fn go(f: &Formula, inv: &[bool], x: NodeId, den: bool, out: &mut Out) {
        crate::base::stack::deep(|| {
            match *f.ir.node(x) {
                _ if inv[x.index()] && f.ir.node(x).as_const() != Some(1.0) => {
                    if den {
                        out.2.push(x);
                    } else {
                        out.1.push(x);
                    }
                }
                Node::Neg(a) => {
                    out.0 = !out.0;
                    go(f, inv, a, den, out);
                }
                Node::Binary(op @ (BinOp::Mul | BinOp::Div), a, b) => {
                    go(f, inv, a, den, out);
                    go(f, inv, b, den ^ (op == BinOp::Div), out);
                }
                _ if f.ir.node(x).as_const() == Some(1.0) => {}
                _ if den => out.2.push(x),
                _ => out.1.push(x),
            }
        })
    }
    let mut out = (false, vec![], vec![]);
    go(f, inv, x, false, &mut out);
    (out.1.len() + out.2.len() <= MAX_FACTORS).then_some(out)
}

/// Largest product/quotient tree [`compensated_exp`] takes apart.
const MAX_FACTORS: usize = 8;

/// Divisors of the live core are kept ≥ this, so the exponent stays finite where one vanishes (it is then
/// below −1416 and the exponential 0 either way) and its tail is a number, not ∞ − ∞.
const MIN_DIVISOR: f64 = 9.332636185032189e-302; // 2^-1000

/// The rounding error of a live core q that is one factor or the product of two (`None` otherwise, or when q is
/// exact): the product's fma remainder, and each acos factor's tail (`acoslo`), which exp would otherwise
/// amplify (the Gaussian's exp(−n·acos(c)²/2): 2·|exponent| times acos's half ulp). A quotient's remainder
/// costs a division and is left out.
fn core_error(f: &Formula, ir: &mut Ir, map: &[NodeId], num: &[NodeId], den: &[NodeId], q: NodeId, sp: Span) -> Option<NodeId> {
    let tail = |ir: &mut Ir, x: NodeId| match *f.ir.node(x) {
        Node::Call(Builtin::Acos, [z, ..]) => Some(ir.call(Builtin::AcosLo, &[map[z.index()]], sp)),
        _ => None,
    };
    match (num, den) {
        ([x], []) => tail(ir, *x),
        ([x, y], []) => {
            let (xv, yv) = (map[x.index()], map[y.index()]);
            let mut e = dd::two_prod_err(&mut IrEmit::new(ir, sp), xv, yv, q);
            // (x + xˡ)(y + yˡ) − x·y ≈ xˡ·y + x·yˡ; a square's two terms are one, 2x·xˡ.
            if x == y {
                if let Some(l) = tail(ir, *x) {
                    let two = ir.bin(BinOp::Add, xv, xv, sp);
                    e = ir.call(Builtin::Fma, &[two, l, e], sp);
                }
            } else {
                if let Some(l) = tail(ir, *x) {
                    e = ir.call(Builtin::Fma, &[l, yv, e], sp);
                }
                if let Some(l) = tail(ir, *y) {
                    e = ir.call(Builtin::Fma, &[xv, l, e], sp);
                }
            }
            Some(e)
        }
        _ => None,
    }
}

// exp(K·q) → e + e·t, e = exp(Kʰ·q);  expmuldiv(K·q, K_b·u, c) → expmuldiv(Kʰ·q, (K_b + K_b·t)·u, c)
// t = (K·q − Kʰ·q) to first order: K = Kʰ + Kˡ the parameter-only factors in double-double, q the live ones
pub(super) fn compensated_exp(a: &Analysis) -> (Ir, NodeId, bool) {
    let (f, inv, ranges) = (&a.f, a.invariant(), a.ranges());
    let mut b = Builder::new(f, inv);
    rebuild(f, |ir, map, id, n| {
        let Node::Call(call @ (Builtin::Exp | Builtin::ExpMulDiv), [arg, bv, cv]) = n else { return None };
        if inv[arg.index()] {
            return None;
        }
        let (negated, num, den) = factors(f, inv, arg)?;
        // An exponent ≤ 0 (by its factors' signs): where a divisor of it vanishes, the exponential does.
        let mut neg = negated;
        for x in num.iter().chain(&den) {
            let r = ranges[x.index()];
            match (r.lo >= 0.0, r.hi <= 0.0) {
                (true, _) => {}
                (false, true) => neg = !neg,
                (false, false) => return None,
            }
        }
        if !neg {
            return None;
        }
        let (kn, qn): (Vec<NodeId>, Vec<NodeId>) = num.iter().partition(|x| inv[x.index()]);
        let (kd, qd): (Vec<NodeId>, Vec<NodeId>) = den.iter().partition(|x| inv[x.index()]);
        // Nothing to carry: no parameter-only factor, or no live one.
        if kn.len() + kd.len() == 0 || qn.len() + qd.len() == 0 {
            return None;
        }
        // Divisors must be ≥ 0 for the floor above to keep their sign.
        if qd.iter().any(|d| ranges[d.index()].lo < 0.0 || ranges[d.index()].nan) {
            return None;
        }
        let sp = f.ir.span(id);
        b.sp = sp;
        // K in double-double, from the parameter-only factors as the kernel computes them (what baking folds
        // them to, so baked and live kernels start from the same K).
        let dd = |b: &Builder, ir: &mut Ir, xs: &[NodeId]| {
            let mut acc = Dd { hi: ir.konst(1.0, sp), lo: None };
            for x in xs {
                acc = b.mul(ir, acc, Dd { hi: map[x.index()], lo: None });
            }
            acc
        };
        let (kn, kd) = (dd(&b, ir, &kn), dd(&b, ir, &kd));
        let mut k = b.div(ir, kn, kd);
        if negated {
            k = b.neg(ir, k);
        }
        let q = {
            let n = product(ir, map, &qn, sp);
            let d = product(ir, map, &qd, sp).map(|d| {
                let floor = ir.konst(MIN_DIVISOR, sp);
                ir.call(Builtin::Max, &[d, floor], sp)
            });
            let n = n.unwrap_or_else(|| ir.konst(1.0, sp));
            d.map_or(n, |d| ir.bin(BinOp::Div, n, d, sp))
        };
        let (a, mut t) = IrEmit::new(ir, sp).two_prod(k.hi, q);
        if let Some(kl) = k.lo {
            t = ir.call(Builtin::Fma, &[kl, q, t], sp);
        }
        if let Some(e) = core_error(f, ir, map, &qn, &qd, q, sp) {
            t = ir.call(Builtin::Fma, &[k.hi, e, t], sp);
        }
        Some(if call == Builtin::Exp {
            let e = ir.call(Builtin::Exp, &[a], sp);
            ir.call(Builtin::Fma, &[e, t, e], sp)
        } else {
            // A finite c carries the tail as c·(1 − t) (the same to O(t²)), off the path that forms b, so b's
            // division and the tail's chain run side by side; otherwise b's parameter-only factor carries it (a
            // value computed once per parameter set, finite where b overflows).
            let rc = ranges[cv.index()];
            let c_carries = rc.lo.is_finite() && rc.hi.is_finite() && !rc.nan;
            let (negb, bn, bd) = factors(f, inv, bv)?;
            let (kbn, un): (Vec<NodeId>, Vec<NodeId>) = bn.iter().partition(|x| inv[x.index()]);
            let (kbd, ud): (Vec<NodeId>, Vec<NodeId>) = bd.iter().partition(|x| inv[x.index()]);
            let kb = (kbn.len() + kbd.len() > 0).then(|| divide_apart(ir, map, &kbn, &kbd, &[], sp));
            let kb = kb.map(|k| if negb { ir.neg(k, sp) } else { k });
            let (bb, cc) = match kb {
                Some(kb) => {
                    let mut x = if c_carries { kb } else { ir.call(Builtin::Fma, &[kb, t, kb], sp) };
                    if let Some(n) = product(ir, map, &un, sp) {
                        x = ir.bin(BinOp::Mul, x, n, sp);
                    }
                    if let Some(d) = product(ir, map, &ud, sp) {
                        x = ir.bin(BinOp::Div, x, d, sp);
                    }
                    (x, map[cv.index()])
                }
                None if c_carries => (map[bv.index()], map[cv.index()]),
                None => {
                    let u = map[bv.index()];
                    (ir.call(Builtin::Fma, &[u, t, u], sp), map[cv.index()])
                }
            };
            let cc = if c_carries {
                let nt = ir.neg(t, sp);
                ir.call(Builtin::Fma, &[nt, cc, cc], sp)
            } else {
                cc
            };
            ir.call(Builtin::ExpMulDiv, &[a, bb, cc], sp)
        })
    })
}

/// Rounding operations a parameter-only subtree's plain evaluation makes, counting pow and acos twice (their
/// results are not correctly rounded, and their tails exist); capped at 2, the threshold that matters.
fn roundings(f: &Formula, x: NodeId, memo: &mut HashMap<NodeId, u8>) -> u8 {
    crate::base::stack::deep(|| {
        if let Some(&c) = memo.get(&x) {
            return c;
        }
        let n = *f.ir.node(x);
        let mut c: u8 = match n {
            Node::Const(_) | Node::Param(_) | Node::Input(_) | Node::Column(_) | Node::Neg(_) => 0,
            Node::Call(Builtin::Pow | Builtin::Acos, _) => 2,
            _ => 1,
        };
        n.for_each_arg(|a| c = c.saturating_add(roundings(f, a, memo)));
        let c = c.min(2);
        memo.insert(x, c);
        c
    })
}

/// A parameter-only subtree in double-double (old node → new `Dd`), memoised.
struct ParamDd<'a> {
    b: Builder<'a>,
    ranges: &'a [crate::simplify::range::Range],
    memo: HashMap<NodeId, Dd>,
}

impl ParamDd<'_> {
    fn dd(&mut self, ir: &mut Ir, map: &[NodeId], x: NodeId) -> Dd {
        crate::base::stack::deep(|| {
            if let Some(&d) = self.memo.get(&x) {
                return d;
            }
            let f = self.b.f;
            let sp = self.b.sp;
            let n = *f.ir.node(x);
            let pos = |r: crate::simplify::range::Range| r.lo > 0.0 && !r.nan;
            let d = match n {
                Node::Const(_) | Node::Param(_) | Node::Input(_) | Node::Column(_) => Dd { hi: map[x.index()], lo: None },
                Node::Neg(a) => {
                    let a = self.dd(ir, map, a);
                    self.b.neg(ir, a)
                }
                Node::Binary(op, a, c) => {
                    let (a, c) = (self.dd(ir, map, a), self.dd(ir, map, c));
                    match op {
                        BinOp::Add => self.b.add(ir, a, c),
                        BinOp::Sub => {
                            let c = self.b.neg(ir, c);
                            self.b.add(ir, a, c)
                        }
                        BinOp::Mul => self.b.mul(ir, a, c),
                        BinOp::Div => self.b.div(ir, a, c),
                    }
                }
                // x^y + powlo(x, y), and to first order x^y·(y·xˡ/x + ln(x)·yˡ) for the operands' low parts.
                Node::Call(Builtin::Pow, [a, c, _]) if pos(self.ranges[a.index()]) && self.ranges[x.index()].hi.is_finite() => {
                    let (a, c) = (self.dd(ir, map, a), self.dd(ir, map, c));
                    let p = ir.call(Builtin::Pow, &[a.hi, c.hi], sp);
                    let mut lo = ir.call(Builtin::PowLo, &[a.hi, c.hi], sp);
                    let mut rel = a.lo.map(|al| {
                        let q = ir.bin(BinOp::Div, al, a.hi, sp);
                        ir.bin(BinOp::Mul, c.hi, q, sp)
                    });
                    if let Some(cl) = c.lo {
                        let l = ir.call(Builtin::Ln, &[a.hi], sp);
                        rel = Some(match rel {
                            Some(r) => ir.call(Builtin::Fma, &[l, cl, r], sp),
                            None => ir.bin(BinOp::Mul, l, cl, sp),
                        });
                    }
                    if let Some(r) = rel {
                        lo = ir.call(Builtin::Fma, &[p, r, lo], sp);
                    }
                    self.b.norm(ir, p, Some(lo))
                }
                // acos + acoslo, and to first order −xˡ/√(1 − x²), kept only while it is small next to acos (near
                // ±1 the first order fails: acos grows like √(1 − x)); √((1 − x)(1 + x)) avoids 1 − x²'s cancellation.
                Node::Call(Builtin::Acos, [a, ..]) => {
                    let a = self.dd(ir, map, a);
                    let h = ir.call(Builtin::Acos, &[a.hi], sp);
                    let mut lo = ir.call(Builtin::AcosLo, &[a.hi], sp);
                    if let Some(al) = a.lo {
                        let one = ir.konst(1.0, sp);
                        let (m, p) = (ir.bin(BinOp::Sub, one, a.hi, sp), ir.bin(BinOp::Add, one, a.hi, sp));
                        let s = ir.bin(BinOp::Mul, m, p, sp);
                        let s = ir.call(Builtin::Sqrt, &[s], sp);
                        let t = ir.bin(BinOp::Div, al, s, sp);
                        let at = ir.call(Builtin::Abs, &[t], sp);
                        let small = ir.konst(2f64.powi(-20), sp);
                        let bound = ir.bin(BinOp::Mul, h, small, sp);
                        let ok = ir.call(Builtin::Lt, &[at, bound], sp);
                        let zero = ir.konst(0.0, sp);
                        let t = ir.call(Builtin::Select, &[ok, t, zero], sp);
                        lo = ir.bin(BinOp::Sub, lo, t, sp);
                    }
                    self.b.norm(ir, h, Some(lo))
                }
                // √x + (x − s² + xˡ)/(2s), the remainder exact by fma.
                Node::Call(Builtin::Sqrt, [a, ..]) if pos(self.ranges[a.index()]) => {
                    let a = self.dd(ir, map, a);
                    let s = ir.call(Builtin::Sqrt, &[a.hi], sp);
                    let ns = ir.neg(s, sp);
                    let mut r = ir.call(Builtin::Fma, &[ns, s, a.hi], sp);
                    if let Some(al) = a.lo {
                        r = ir.bin(BinOp::Add, r, al, sp);
                    }
                    let two_s = ir.bin(BinOp::Add, s, s, sp);
                    let lo = ir.bin(BinOp::Div, r, two_s, sp);
                    self.b.norm(ir, s, Some(lo))
                }
                // Other calls: their operands' low parts to first order where the derivative is at hand, else
                // computed from the rounded operands as the kernel would.
                _ => {
                    let mut args = [NodeId(0); 3];
                    let mut lows = [None; 3];
                    let mut k = 0;
                    n.for_each_arg(|a| {
                        args[k] = a;
                        k += 1;
                    });
                    for i in 0..k {
                        let d = self.dd(ir, map, args[i]);
                        args[i] = d.hi;
                        lows[i] = d.lo;
                    }
                    let v = match n {
                        Node::Call(b, _) => ir.call(b, &args[..b.arity()], sp),
                        _ => map[x.index()],
                    };
                    let lo = match (n, lows[0]) {
                        (Node::Call(Builtin::Exp, _), Some(al)) if self.ranges[x.index()].hi.is_finite() => Some(ir.bin(BinOp::Mul, v, al, sp)),
                        (Node::Call(Builtin::Ln, [a, ..]), Some(al)) if pos(self.ranges[a.index()]) => Some(ir.bin(BinOp::Div, al, args[0], sp)),
                        _ => None,
                    };
                    self.b.norm(ir, v, lo)
                }
            };
            self.memo.insert(x, d);
            d
        })
    }
}

/// `compensated-params`: each maximal parameter-only subtree that a live node reads, and whose plain evaluation
/// rounds at least twice (or calls pow or acos), computed in double-double and rounded once where the kernel
/// reads it. Runs on the live formula (`numerics::robust`), so a baked parameter folds the same double-double
/// expression the live kernel's prepared block computes: baked and live agree bit for bit.
pub(super) fn compensated_params(a: &Analysis) -> (Ir, NodeId, bool) {
    let (f, inv, ranges) = (&a.f, a.invariant(), a.ranges());
    let mut boundary = vec![false; f.ir.len()];
    for id in f.ir.ids() {
        if !inv[id.index()] {
            f.ir.node(id).for_each_arg(|a| boundary[a.index()] |= inv[a.index()]);
        }
    }
    let mut count = HashMap::new();
    let mut pd = ParamDd { b: Builder::new(f, inv), ranges, memo: HashMap::new() };
    rebuild(f, |ir, map, id, _| {
        if !boundary[id.index()] || roundings(f, id, &mut count) < 2 {
            return None;
        }
        pd.b.sp = f.ir.span(id);
        let d = pd.dd(ir, map, id);
        // Only where some operation left a low part: otherwise the subtree is what the kernel computes anyway.
        d.lo.is_some().then_some(d.hi)
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(src: &str) -> Formula {
        let f = crate::front::parse_internal("t.brdf", src).unwrap();
        crate::simplify::simplify(&f, &[])
    }

    fn apply(src: &str) -> Option<String> {
        let f = parse(src);
        let (ir, root, fired) = rational_form(&Analysis::new(f.clone()));
        fired.then(|| crate::simplify::simplify_with(&Formula { ir, root, ..f }, &[], &crate::simplify::Policy::default()).0.to_program_text())
    }

    #[test]
    fn linear_fractional_sums_become_one_quotient() {
        // 1 − 1.1·u/(u + 2c): one division of two fma-evaluated linear polynomials.
        let t = apply("let c = NH\nmax((-1.1/(-n + n*c - 2*c)) * n * (c - 1) + 1, 0)^2").unwrap();
        assert_eq!(t.matches(" / ").count(), 1, "{t}");
        assert!(t.contains("fma("), "{t}");
        let t = apply("let c = NH\nc/(n - n*c + c) - 0.25").unwrap();
        assert!(t.contains("fma(") && t.matches(" / ").count() == 1, "{t}");
        // A polynomial of degree 1: two fmas of double-double coefficients, no division.
        let t = apply("n*0.5*(NH - 1) + 1").unwrap();
        assert!(t.contains("fma(") && !t.contains(" / "), "{t}");
        // A term of higher degree is added to the regrouped part as written.
        let t = apply("let c = NH\nc/(n - n*c + c) + (c^8 - 0.25)").unwrap();
        assert!(t.contains("fma(") && t.matches(" / ").count() == 1 && t.contains("t2 * t2"), "{t}");
        // Same-signed qualifying terms beside it are not regrouped.
        assert!(apply("let c = NH\nc/(n - n*c + c) + (c^8 + 0.25)").is_none());
        // Degree 2 over one atom, two atoms, a sum already x + a₀ are left alone; a linear one is rewritten.
        assert!(apply("NH*NH - n*NH").is_none());
        assert!(apply("NH/(n + NL) - 1").is_none());
        assert!(apply("NH - n").is_none());
        // n·(1 − NH) and NH are both ≥ 0: no cancellation to move.
        assert!(apply("n*(1 - NH) + NH").is_none());
        assert!(apply("1/(n*(1 - NH) - NH) - 1").is_some());
    }

    #[test]
    fn shapes_add_degrees() {
        // The shape of the last `/` or `*` node (the root itself may be the lowering's max(…, 0)).
        let last = |src: &str| {
            let f = parse(src);
            let s = shapes(&f, &f.ir.invariant());
            let id = f.ir.ids().filter(|id| matches!(f.ir.node(*id), Node::Binary(BinOp::Div | BinOp::Mul, ..))).last().unwrap();
            s[id.index()].map(|s| (s.num, s.den))
        };
        assert_eq!(last("let c = NH\n(n*c + 1)/(c + 2)"), Some((1, 1)));
        assert_eq!(last("let c = NH\n(n*c + 1)/(c + 2)*c"), None);
    }

    #[test]
    fn compensated_params_computes_parameter_parts_in_double_double() {
        let f = parse("param k = 2 in 1..5\nparam Q = 0.5 in 0.1..0.9\nacos(pow(Q, 1/k)) * NH");
        let (ir, root, fired) = compensated_params(&Analysis::new(f.clone()));
        assert!(fired);
        let t = crate::simplify::simplify_with(&Formula { ir, root, ..f }, &[], &crate::simplify::Policy::default()).0.to_program_text();
        // pow's and acos's own roundings through their tails, rounded once where NH reads the product.
        assert!(t.contains("powlo(") && t.contains("acoslo("), "{t}");
        // A parameter part that rounds once (n·2) or none (n) is left as the kernel computes it.
        assert!(!compensated_params(&Analysis::new(parse("n * 2 * NH"))).2);
        assert!(!compensated_params(&Analysis::new(parse("n * NH"))).2);
    }

    #[test]
    fn compensated_exp_carries_the_exponent_tail() {
        let apply = |src: &str| {
            let f = parse(src);
            let (ir, root, fired) = compensated_exp(&Analysis::new(f.clone()));
            fired.then(|| crate::simplify::simplify_with(&Formula { ir, root, ..f }, &[], &crate::simplify::Policy::default()).0.to_program_text())
        };
        // Beckmann after scaled-exp: K = 1/m² in double-double, the tail on b's parameter-only factor, the
        // vanishing divisor floored so the tail stays a number.
        let t = apply("param m = 0.3 in 0.01..1\nlet nh = clamp(NH, 0, 1)\nexpmuldiv((nh*nh - 1) / (m*m * (nh*nh)), 1 / (m*m * nh * nh * nh), nh)").unwrap();
        assert!(t.contains("max(") && t.matches("fma(").count() >= 3 && t.contains("expmuldiv("), "{t}");
        // A plain exp: e + e·t.
        let t = apply("exp(-n * NH * NH)").unwrap();
        assert!(t.contains("fma(") && t.contains("exp("), "{t}");
        // An exponent that may be positive, one without a parameter, and a parameter-only one are left alone.
        assert!(apply("exp(n * NH)").is_none());
        assert!(apply("exp(-NH * NH)").is_none());
        assert!(apply("exp(-n * 2) * NH").is_none());
    }
}
