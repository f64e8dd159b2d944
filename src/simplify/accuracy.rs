//! The accuracy pass's candidate rewrites: IR → IR forms that avoid overflow, underflow and cancellation.
//!
//! # Design
//! Herbie's split (Panchekha et al., PLDI 2015): this module only *proposes* — each [`Rule`] rewrites a whole
//! simplified formula into an algebraically equal one and states its cost ([`cost`]); it evaluates nothing.
//! Every rule reads the formula through one [`Analysis`] (ranges, guards, product lists), built once for all
//! the rules and sites tried on a formula; the builders they share are in `rewrite.rs`, below this module and
//! `cancel.rs`.
//! Which candidates are kept is decided above the backends (`numerics::robust`), by measured bits of error
//! against a higher-precision truth over the formula's domain, within a cost budget. A rule that does not
//! apply returns `None`. Every rule is exact in real arithmetic; what changes is where f64 rounds:
//!
//! - `split-sqrt`: `sqrt(a·b) → sqrt(a)·sqrt(b)` for a, b ≥ 0 (range analysis, or a guard: the sqrt is used
//!   only in the else branch of `a <= 0 || b <= 0 ? … : …`, as in an explorer BRDF's early return). a·b underflows to 0 when both
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
//! - `compensated-base`: `pow(a + b, y)` (y live) → `p + p·y·(e'/s')` with (s', e') the renormalised pair of
//!   s = a + b and e, the rounding error of the sum and of the `+ − × /` below it ([`rounding_error`]), and
//!   p = pow(s', y): |e'/s'| ≤ 2⁻⁵³ even where s cancels to nothing (F_ST at n = a). pow amplifies its base's
//!   relative error y times, so F_ST's `(n/a·(c − 1) + 1)^a` at a = 1000 lost 500 ulp where its condition is
//!   1, and at a = 640 still 16 ulp with the sum's error alone (n/a and c − 1 round too). Cost ~12–20.
//! - `compensated-sum`: `a + b` where a and b may have opposite signs (by range) → `(a + b) + e`, e as above,
//!   one site at a time: the error terms are first order, so they are exact to ~2⁻¹⁰⁶ relative to the terms,
//!   and the cancellation no longer amplifies the terms' roundings. An acos below it carries its own rounding
//!   (`acoslo`), and a parameter-only sum is taken as `compensated-params`' rounded double-double, whose error is
//!   its 2Sum residual (F_kutlog's π/2 − C·acos(NH) near C·acos(NH) = π/2). Sums that read no input are not
//!   sites. Cost ~3 per `+ − × /` below the sum, 8 per acos.
//!
//! - `scaled-exp`: a product/quotient tree with an `exp(E)` factor, `exp(E)·n/(d₁·…·d_k)`, →
//!   `expmuldiv(E, n/(d₁·…·d_{k−1}), d_k)` (the builtin applies every power of two last, so e^E may be far
//!   below the denormals while the result is not: Beckmann's and Ward's values near 1e-311). Three variants,
//!   tried in turn: the other divisors as one product; the safe ones and the exponent's own (NH, whose tininess
//!   makes e^E vanish first) as one product, each other that may be tiny or huge on its own, and two such
//!   (Cook–Torrance's VH and max(NL, NV)) taken apart at run time inside the one builtin: b/VH where VH ≥ 2⁻¹⁰⁰⁰,
//!   else c scaled by 2¹⁵³⁶ and E by 1536·ln 2 (exact there; [`two_divisors`]; a compare, three selects and four
//!   operations, ~+14, where nesting costs a second exp);
//!   and the exponent halved over two nested builtins so two tiny divisors (Cook–Torrance's NL, NV ~1e-224)
//!   each meet one half (twice the cost). One division by a product rather than a chain: dependent divisions
//!   add latency the static cost does not see (Cook–Torrance's `/nh/nh/nh/nh`: 1.36× measured at 1.23× static).
//!   A divisor that may be exactly 0 and reads inputs no other factor reads (Ward's √NL) makes a pole there, which
//!   the builtin (an infinite b/c taken for an overflowed factor) would turn into 0 where e^E underflows: such
//!   a product is guarded, `d == 0 ? rest/d : expmuldiv(…)` ([`pole_guard`], +6 per product).
//!
//! - `smith-g1`: Smith's G1 for GGX written with tan², `K/(1 + sqrt(1 + A·(1 − c²)/c²))`, → `K·c/(c + sqrt(c² +
//!   A·(1 − c²)))` for c > 0 (range or guard), then c cancelled against a divisor c of the products around it
//!   (BRDF Explorer's GGX: `G·…/(4·NL·NV)`). At grazing c, c² underflows: tan² = 1/0 and G1 = 0, and the
//!   product meets 0/0. Cheaper than the written form (no division by c², no 4·NL·NV).
//! - `cancel-min`: a product/quotient tree `z·min(K, c·x, c·y)/(v·x·y)` with K > 0 and x, y, c ≥ 0 (Cook–Torrance's
//!   `G/(π·NL·NV)`, G = min(1, 2·NH·NV/VH, 2·NH·NL/VH)) → `z·g/(v·e)/w` with c = n/d, u = min(x, y),
//!   w = max(x, y) and (g, e) = (K, u) where K·d < n·u, else (n, d): with c ≥ 0, min(K, c·x, c·y) = min(K, c·u)
//!   and x·y = u·w, so the two are equal wherever u, d > 0; at u = 0 (NL or NV exactly 0), where the written
//!   form is 0/0, the test fails and n/(d·w) is the limit. The branch is decided by products, each side scaled
//!   by a power of two (2⁶⁰⁰ where the ranges allow) so a subnormal d or u compares at full precision: no
//!   quotient rounds into the subnormals before it is divided again (K·VH/u at VH = 5·10⁻³²⁴ was 26 % low),
//!   and d (VH) and w divide one by one after the small factors, so nothing overflows where the value does not.
//! - `scaled-norm`: `x/sqrt(a² + b² + …)`, x one of a, b, …, (a normalize) with the vector scaled by 2^600
//!   when its largest component is below 2^-500 (exact), so L + V at L ≈ −V (grazing light and view facing each
//!   other) has a length, not 0. Cost: abs and max per component, a compare, a select, a product each (~+12).
//! - `rational-form` (in `cancel.rs`): a cancelling sum rational in one input, as one linear-fractional form
//!   with double-double parameter-only coefficients.
//! - `compensated-exp` (in `cancel.rs`): exp's (or expmuldiv's) argument K·q, K its parameter-only factors in
//!   double-double, computed as Kʰ·q with the product's rounding error (and q's own, acos's through `acoslo`)
//!   carried as a relative tail t: e + e·t, or into expmuldiv's b.
//! - `compensated-params` (in `cancel.rs`, through [`compensated_params`]): each parameter-only subtree the
//!   kernel reads, when it rounds more than once or calls pow or acos, in double-double (pow's and acos's own
//!   roundings through the builtins `powlo` and `acoslo`) and rounded once. Applied to the live formula, so a
//!   baked kernel folds the value the live one's prepared block computes; free per point (F_kutlog's acos(Q^(1/k))/acos(Q^(1/n)), where acos
//!   near 1 multiplied pow's half ulp ~20 times).
//!
//! Another candidate, large integer powers kept as `pow` calls instead of multiplication chains, is the
//! simplifier's own [`super::Policy::max_chain`]; the chooser builds it with [`pow_call_policy`]. Another,
//! [`compensated_powers`], rebuilds those calls as multiplication chains that carry their rounding errors
//! (fma) where a step's rounding would weigh more than 3u, within 3 ulp of pow at ~2.5–3× the plain chain's
//! operations and below pow's cost.
//!
//! # Cost model
//! [`cost`] counts live nodes with weights fitted to JIT timings on x86-64 (BENCHMARKS.md, 2026-11-30: five
//! extra divisions add ~3.4 ns to Beckmann's 8.5 ns, a libm exp ~5 ns): `+ − ×`, abs, min, max 1; clamp 2;
//! `/` and sqrt 3; fma 1; math-library calls (exp, ln, trig) 20, expmuldiv 28 (it replaces an exp, a `×` and
//! a `/` (24) and adds a range test: Beckmann's kernel takes ~1.15× the unrewritten one with it, on `lobe
//! bench`'s inputs and on inputs where no lane takes its rare branch alike), acoslo 8 (beside the acos it
//! corrects, whose reduction the JIT shares: the Gaussian's kernel measured +1.5 ns batched on 8.5), pow 60 (pow(NH, e) with e live took 5.0× the
//! ns of the 14-multiplication chain for NH¹⁰⁰⁰); leaves and negation 0.
//! Nodes that read no input (parameters only) cost nothing: the kernels compute them once per parameter set
//! (the prepared block, hoisted out of batch loops).
//! It ranks candidates; the kernel's run time, measured in `lobe bench`, is what BENCHMARKS.md reports.

use super::range::Range;
use super::rewrite::{add_opt, balanced_product, divide_apart, divide_by, product, rebuild, safe, Analysis};
use super::{node_ranges, Policy};
use super::emit::IrEmit;
use crate::builtins::dd;
use crate::builtins::dd::Arith;
use crate::base::span::Span;
use crate::builtins::Builtin;
use crate::ir::{BinOp, Formula, Ir, Node, NodeId};

/// One candidate rewrite of the accuracy pass.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Rule {
    SplitSqrt,
    QuotientChain,
    FactorQuadratic,
    CompensatedBase,
    CompensatedSum,
    ScaledExp,
    SmithG1,
    CancelMin,
    ScaledNorm,
    RationalForm,
    CompensatedExp,
}

impl Rule {
    pub(crate) const ALL: [Rule; 11] = [
        Rule::SplitSqrt,
        Rule::SmithG1,
        Rule::CancelMin,
        // Before quotient-chain, which flattens (x/√s)·(x/√s) into x·x/√s/√s, where scaled-norm cannot see it.
        Rule::ScaledNorm,
        Rule::QuotientChain,
        Rule::ScaledExp,
        Rule::FactorQuadratic,
        Rule::CompensatedBase,
        Rule::CompensatedSum,
        Rule::RationalForm,
        Rule::CompensatedExp,
    ];

    pub(crate) fn name(self) -> &'static str {
        match self {
            Rule::SplitSqrt => "split-sqrt",
            Rule::QuotientChain => "quotient-chain",
            Rule::FactorQuadratic => "factor-quadratic",
            Rule::CompensatedBase => "compensated-base",
            Rule::CompensatedSum => "compensated-sum",
            Rule::ScaledExp => "scaled-exp",
            Rule::SmithG1 => "smith-g1",
            Rule::CancelMin => "cancel-min",
            Rule::ScaledNorm => "scaled-norm",
            Rule::RationalForm => "rational-form",
            Rule::CompensatedExp => "compensated-exp",
        }
    }

    /// What the rule does, for reports.
    pub(crate) fn describe(self) -> &'static str {
        match self {
            Rule::SplitSqrt => "sqrt(a*b) as sqrt(a)*sqrt(b): no underflow of a*b",
            Rule::QuotientChain => "products/quotients reassociated: divide by each tiny-or-huge factor separately",
            Rule::FactorQuadratic => "A*c^2 + (1 - A)*c as c*(1 + A*(c - 1)): no cancellation near c = 1",
            Rule::CompensatedBase => "pow(a + b, y) corrected by the rounding errors of a + b and its terms: no amplification by y",
            Rule::CompensatedSum => "a + b that may cancel, plus the rounding errors of the sum and the terms below it (fma, 2Sum)",
            Rule::ScaledExp => "exp(a)*b/c as expmuldiv(a, b, c): no underflow of exp(a) before b/c rescales it",
            Rule::SmithG1 => "Smith G1 2/(1 + sqrt(1 + A*tan^2)) as 2c/(c + sqrt(c^2 + A*(1 - c^2))), c/c cancelled: no inf/inf at grazing c",
            Rule::CancelMin => "min(K, c*x, c*y)/(x*y) as (K*d < n*min(x, y) ? K/min(x, y) : n/d)/max(x, y), c = n/d: the limit, not 0/0, at x or y = 0",
            Rule::ScaledNorm => "x/sqrt(a^2 + b^2 + ...) with a tiny vector scaled by 2^600 first: no zero length",
            Rule::RationalForm => "a sum rational in one input as (a1*x + a0)/(b1*x + b0), coefficients in double-double: the cancellation moves to the parameters",
            Rule::CompensatedExp => "exp(K*q) as exp(hi)*(1 + t), K's parameter-only factors in double-double and t the product's rounding error: exp no longer amplifies it",
        }
    }

    /// The rewritten formula, or `None` when the rule does not apply. The result is simplified again (default
    /// policy) so constants fold.
    pub fn apply(self, f: &Formula) -> Option<Formula> {
        self.apply_at(f, None)
    }

    /// [`Rule::apply`] at one site only (the `k`-th place the rule matches, in arena order), so the chooser
    /// can keep it where it helps and leave it where it only costs (Beckmann: the product whose exp factor
    /// vanishes, not the exponent's own quotient). `quotient-chain` and `compensated-sum` have sites, `scaled-exp` variants; the others apply everywhere.
    pub fn apply_at(self, f: &Formula, site: Option<usize>) -> Option<Formula> {
        self.apply_in(&Analysis::new(f.clone()), site)
    }

    /// [`Rule::apply_at`] on an analysed formula: the analysis is shared by every rule and site tried on it.
    pub(crate) fn apply_in(self, a: &Analysis, site: Option<usize>) -> Option<Formula> {
        let (ir, root, fired) = match self {
            Rule::SplitSqrt => split_sqrt(a),
            Rule::QuotientChain => quotient_chain(a, site),
            Rule::FactorQuadratic => factor_quadratic(a),
            Rule::CompensatedBase => compensated_base(a),
            Rule::CompensatedSum => compensated_sum(a, site.unwrap_or(0)),
            Rule::ScaledExp => scaled_exp(a, site.unwrap_or(0)),
            Rule::SmithG1 => smith_g1(a),
            Rule::CancelMin => cancel_min(a),
            Rule::ScaledNorm => scaled_norm(a),
            Rule::RationalForm => super::cancel::rational_form(a),
            Rule::CompensatedExp => super::cancel::compensated_exp(a),
        };
        if !fired {
            return None;
        }
        let g = Formula { ir, root, ..a.f.clone() };
        Some(super::simplify_with(&g, &[], &Policy::default()).0)
    }
}

/// The `compensated-params` candidate: `f` (the live formula) with each parameter-only subtree the kernel reads
/// computed in double-double and rounded once ([`super::cancel`]); `None` when no subtree qualifies. Baking the
/// pass's decision folds the same expression the live kernel's prepared block computes. Free per point: the block is computed once per
/// parameter set.
pub(crate) fn compensated_params(f: &Formula) -> Option<Formula> {
    let (ir, root, fired) = super::cancel::compensated_params(&Analysis::new(f.clone()));
    fired.then(|| Formula { ir, root, ..f.clone() })
}

/// The simplifier policy of the `pow-call` candidate: integer powers above 8 stay `pow` calls (libm's < 1 ulp)
/// instead of multiplication chains (error up to (k − 1)·u; 449 ulp measured at k = 1000).
pub fn pow_call_policy() -> Policy {
    Policy { max_chain: 8, ..Policy::default() }
}

/// The `compensated-power` candidate: `f` simplified with [`pow_call_policy`] (so integer powers above 8 are
/// still `pow` calls), each `pow(x, k)` with a constant integer 9 ≤ k ≤ [`super::MAX_POW_CHAIN`] and
/// |x| ≤ 2^(1000/k) by range analysis rebuilt as a compensated multiplication chain, then simplified again.
/// `None` when no power qualifies.
///
/// The plain chain's relative error is Σ mⱼ·δⱼ, δⱼ the rounding of step j and mⱼ how often its power enters
/// x^k ([`super::powi::multiplicities`]; Σ mⱼ = k − 1, most of it on the first squarings). Each step whose
/// error would weigh more carries x^j as an unevaluated sum `h + l`: `h = hₐ·h_b` and its exact rounding error
/// `fma(hₐ, h_b, −h)` plus the first-order terms `hₐ·l_b + lₐ·h_b` (one or two more fmas) make the new `l`.
/// The last steps, as many as keep their Σ mⱼ ≤ [`UNTAILED_WEIGHT`] (3: the last two of a binary chain), round
/// once each instead: a step whose operands carry an `l` folds it into its product with one fma
/// (`fma(hₐ, h_b, hₐ·l_b + lₐ·h_b)`), the others are plain products. The result is within 3u relative (< 3 ulp)
/// of x^k to first order whatever k, where the plain chain's grows like k·u (~490 ulp at k = 1000) and the
/// fully compensated chain's is 0.5u: measured against the truth on 10⁵ points, ≤ 2 ulp at k ∈ {9 … 1024}
/// (live `pow` ≤ 0.51), so baked and live agree within 4 ulp. It saves the last steps' tails, the error fma
/// of the fold and the final `h + l`: 13 operations over the plain chain's 7 at k = 50 where carrying every
/// step took 17, 31 over 14 at k = 1000 (BENCHMARKS.md, 2026-12-01, powchain).
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
        if !(k.fract() == 0.0 && (9.0..=f64::from(super::MAX_POW_CHAIN)).contains(&k) && !r.nan && r.lo >= -bound && r.hi <= bound) {
            return None;
        }
        let s = f.ir.span(id);
        let k = k as u32;
        let steps = super::powi::steps(k);
        let m = super::powi::multiplicities(k);
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
    Some(super::simplify_with(&g, &[], &Policy::default()).0)
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

/// Static cost of a formula's live nodes (module docs).
pub(crate) fn cost(f: &Formula) -> f64 {
    // Nodes that read no input are the prepared block's, computed once per parameter set, not per point.
    let inv = f.ir.invariant();
    let uses = f.ir.use_counts(f.root);
    let weight = |n: &Node| match n {
        Node::Const(_) | Node::Input(_) | Node::Param(_) | Node::Column(_) | Node::Neg(_) => 0.0,
        Node::Binary(BinOp::Div, ..) => 3.0,
        Node::Binary(..) => 1.0,
        Node::Call(b, _) => match b {
            Builtin::Sqrt => 3.0,
            Builtin::Abs | Builtin::Min | Builtin::Max | Builtin::Fma => 1.0,
            Builtin::Clamp => 2.0,
            Builtin::Lt | Builtin::Le | Builtin::Eq | Builtin::Ne | Builtin::Select => 2.0,
            Builtin::Floor => 6.0,
            // powlo redoes pow's work; the pass forms it only on parameter-only values, where it is free.
            Builtin::Pow | Builtin::PowLo => 60.0,
            Builtin::ExpMulDiv => 28.0,
            // Beside acos of the same argument (its only use), whose work the JIT shares: measured (robust7).
            Builtin::AcosLo => 8.0,
            // No reduction and one kernel: about half of sin's operations.
            Builtin::SinNear => 10.0,
            _ => 20.0,
        },
    };
    f.ir.ids().filter(|id| uses[id.index()] > 0 && !inv[id.index()]).map(|id| weight(f.ir.node(id))).sum()
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

// K/(1 + sqrt(1 + A·((1 − c·c)/(c·c)))) → K·c/(c + sqrt(c·c + A·(1 − c·c)))   for c > 0, then c/c cancelled
// in the products around it
fn smith_g1(a: &Analysis) -> (Ir, NodeId, bool) {
    let (f, ranges, guards) = (&a.f, a.ranges(), a.guards());
    let ir0 = &f.ir;
    let is_one = |x: NodeId| ir0.node(x).as_const() == Some(1.0);
    // (A, c, c·c) when `x` is 1 + A·((1 − c·c)/(c·c)) (either operand order of + and ·).
    let inner = |x: NodeId| -> Option<(NodeId, NodeId, NodeId)> {
        let Node::Binary(BinOp::Add, p, q) = *ir0.node(x) else { return None };
        let m = if is_one(p) { q } else if is_one(q) { p } else { return None };
        let Node::Binary(BinOp::Mul, u, v) = *ir0.node(m) else { return None };
        for (a, d) in [(u, v), (v, u)] {
            let Node::Binary(BinOp::Div, t, sq) = *ir0.node(d) else { continue };
            let Node::Binary(BinOp::Sub, one, sq2) = *ir0.node(t) else { continue };
            let Node::Binary(BinOp::Mul, c, c2) = *ir0.node(sq) else { continue };
            if is_one(one) && sq2 == sq && c == c2 {
                return Some((a, c, sq));
            }
        }
        None
    };
    let (ir, root, fired) = rebuild(f, |ir, map, id, n| {
        let Node::Binary(BinOp::Div, k, den) = n else { return None };
        let Node::Binary(BinOp::Add, p, q) = *ir0.node(den) else { return None };
        let r = if is_one(p) { q } else if is_one(q) { p } else { return None };
        let Node::Call(Builtin::Sqrt, [x, ..]) = *ir0.node(r) else { return None };
        let (a, c, sq) = inner(x)?;
        let positive = ranges[c.index()].lo > 0.0 || guards[id.index()].as_ref().is_some_and(|g| g.contains(&c));
        if !positive {
            return None;
        }
        let s = f.ir.span(id);
        let (a, c, sq) = (map[a.index()], map[c.index()], map[sq.index()]);
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
    let mut inner = vec![false; ir0.len()];
    for id in ir0.ids() {
        if let (Some(_), Node::Binary(BinOp::Mul | BinOp::Div, a, b)) = (&lists[id.index()], ir0.node(id)) {
            inner[a.index()] = true;
            inner[b.index()] = true;
        }
    }
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
fn rounding_error(f: &Formula, ranges: &[Range], ir: &mut Ir, map: &[NodeId], (x, s): (NodeId, NodeId), memo: &mut [Option<Option<NodeId>>], sp: Span) -> Option<NodeId> {
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
        // A guard makes the factors positive where the sqrt's value is used; without it, no split.
        let guarded = "let a = NL - 0.5\nlet b = NV - 0.5\na <= 0 || b <= 0 ? 0 : 1/sqrt(a*b)";
        assert!(Rule::SplitSqrt.apply(&parse(guarded)).is_some());
        assert!(Rule::SplitSqrt.apply(&parse("let a = NL - 0.5\nlet b = NV - 0.5\na <= 0 ? 0 : 1/sqrt(a*b)")).is_none());
        assert!(Rule::SplitSqrt.apply(&parse("let a = NL - 0.5\nlet b = NV - 0.5\n(a <= 0 || b <= 0 ? 0 : 1) + sqrt(a*b)")).is_none());
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

    #[test]
    fn scaled_exp_needs_an_exp_factor_and_another_factor() {
        let f = parse("param m = 0.3 in 0.01..1\nexp((NH^2 - 1) / (m^2 * NH^2)) / (m*m) / NH / NL");
        let t = |k| Rule::ScaledExp.apply_at(&f, Some(k)).map(|g| g.to_program_text());
        let (v0, v1, v2) = (t(0).unwrap(), t(1).unwrap(), t(2).unwrap());
        assert!(v0.contains("expmuldiv(") && !v0.contains("exp("), "{v0}");
        assert!(v1 != v0 && v2.matches("expmuldiv(").count() == 2, "{v1}\n{v2}");
        // Variant 1 divides by the safe divisors' product once (m·m: parameter-only, computed once per parameter
        // set), then by each divisor that may be tiny on its own, not by m twice in the chain.
        assert!(!v1.contains("/ m /") && !v1.contains("/ m,"), "{v1}");
        assert!(t(3).is_none());
        assert!(Rule::ScaledExp.apply(&parse("exp(-NH)")).is_none());
        assert!(Rule::ScaledExp.apply(&parse("NL / exp(NH)")).is_none());
    }

    #[test]
    fn scaled_exp_takes_two_tiny_divisors_apart_in_one_call() {
        let f = parse("param m = 0.3 in 0.01..1\nexp((NH^2 - 1) / (m^2 * NH^2)) / (m*m) / NH^4 / VH / max(NL, NV)");
        let g = Rule::ScaledExp.apply_at(&f, Some(1)).unwrap();
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
        let t = Rule::SmithG1.apply(&parse(&src)).unwrap().to_program_text();
        // G1·…/(4·NL) with G1 = 2·NL/(NL + …): NL cancelled, so nothing is ∞/∞ or 0/0 at tiny NL.
        assert!(!t.contains("/ nl") && !t.contains("* nl /") && t.contains("sqrt("), "{t}");
        // Without the guard NL may be 0 or negative: not rewritten.
        assert!(Rule::SmithG1.apply(&parse(&format!("param a = 0.2 in 0.01..1\n{g1}\ng * NH / (4*NL)"))).is_none());
    }

    #[test]
    fn cancel_min_needs_a_positive_bound_and_a_nonnegative_shared_factor() {
        let f = parse("param m = 0.3 in 0.01..1\nlet G = min(1, min(2*NH*NV/VH, 2*NH*NL/VH))\nexp(-NH/m)*G/(3*NL*NV)");
        let t = Rule::CancelMin.apply(&f).unwrap().to_program_text();
        // (VH·2^e < 2·NH·min(NL, NV)·2^e ? 1/min(NL, NV) : 2·NH/VH)/max(NL, NV): no NL·NV, and the branch is
        // chosen by products, not by a quotient that may round into the subnormals.
        assert!(t.contains("vh * 4.149515568880993e180 <") && t.contains("? 1 : t1)") && t.contains("? t") && t.contains("/ max("), "{t}");
        assert!(!t.contains("nl * nv") && !t.contains("vh / min("), "{t}");
        // A shared factor that may be negative (NH − 0.5) or a bound that may be 0: not rewritten.
        assert!(Rule::CancelMin.apply(&parse("min(1, min((NH - 0.5)*NV, (NH - 0.5)*NL))/(NL*NV)")).is_none());
        assert!(Rule::CancelMin.apply(&parse("min(NH, min(2*NV, 2*NL))/(NL*NV)")).is_none());
        assert!(Rule::CancelMin.apply(&parse("min(1, min(2*NV, 2*NL))/(NL*NV)")).is_some());
    }

    #[test]
    fn scaled_norm_scales_the_vector_not_a_lone_sqrt() {
        let f = parse("let x = Lx + Vx\nlet z = Lz + Vz\nz / sqrt(x*x + z*z)");
        let t = Rule::ScaledNorm.apply(&f).unwrap().to_program_text();
        assert!(t.contains("? 4.149515568880993e180 : 1") && t.contains("t5 / sqrt(t4 * t4 + t5 * t5)"), "{t}");
        assert!(Rule::ScaledNorm.apply(&parse("let x = Lx + Vx\nlet z = Lz + Vz\nNH / sqrt(x*x + z*z)")).is_none());
        assert!(Rule::ScaledNorm.apply(&parse("let x = Lx + Vx\nx / sqrt(x*x)")).is_none());
    }

    #[test]
    fn compensated_sum_carries_the_errors_below_a_cancelling_sum() {
        let f = parse("let q = -1.1/(n*NH - n - 2*NH)\nq*n*(NH - 1) + 1");
        // The sites in arena order: n·c − n, then − 2c, then the final + 1.
        let t = Rule::CompensatedSum.apply_at(&f, Some(2)).unwrap().to_program_text();
        assert!(Rule::CompensatedSum.apply_at(&f, Some(3)).is_none());
        // The sum's 2Sum error, the products' and the quotient's fma remainders, c − 1's Fast2Sum error.
        assert!(t.matches("fma(").count() >= 4, "{t}");
        // Same-signed terms do not cancel: no site. (Accuracy: tests/it/robust.rs.)
        assert!(Rule::CompensatedSum.apply(&parse("NH*NL + NV")).is_none());
    }

    #[test]
    fn compensated_base_corrects_a_live_power_of_a_sum() {
        let f = parse("param a = 16 in 1..1000\nmax(n/a*(NH - 1) + 1, 0)^a");
        let g = Rule::CompensatedBase.apply(&f).unwrap();
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
        assert!(Rule::CompensatedBase.apply(&parse("(NH + 1)^3")).is_none());
        assert!(Rule::CompensatedBase.apply(&parse("NH^n")).is_none());
    }

    #[test]
    fn cost_leaves_out_the_prepared_block() {
        // n/a reads no input: computed once per parameter set, so it costs nothing per point.
        let (a, b) = (parse("param a = 16 in 1..1000\nn/a*NH"), parse("param a = 16 in 1..1000\nn*NH"));
        assert_eq!(cost(&a), cost(&b));
        assert_eq!(cost(&parse("NH/NL")), cost(&parse("NH*NL")) + 2.0);
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
