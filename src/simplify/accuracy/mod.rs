//! The accuracy pass's candidate rewrites: IR → IR forms that avoid overflow, underflow and cancellation.
//!
//! # Design
//! Herbie's split (Panchekha et al., PLDI 2015): this module only *proposes* — each [`Rule`] rewrites a whole
//! simplified formula into an algebraically equal one and states its cost ([`cost`]); it evaluates nothing.
//! The rules are data (egg's `rw!` list): one [`Rule`] trait — name, description, how it applies, the rewrite
//! and an example — and one list of them, [`RULES`]; reports, the pass's search, the pass cache and the
//! registry's test all read the list. A new rule is its own code in its family's file and one line there.
//! Families: `scale.rs` (overflow and underflow), `compensated.rs` (rounding carried through sums and
//! powers), `power.rs` (integer powers and the baked live choice), `cancel.rs` (cancellation moved to the
//! parameters), `vector.rs` (what a formula's own normalised vectors make exact: half-vector BRDFs),
//! `angle.rs` (direction-based formulas: normalised vectors, powers of cosines, angles from acos).
//! Every rule reads the formula through one [`Analysis`] (ranges, guards, product lists), built once for all
//! the rules and sites tried on a formula; the builders they share are in `rewrite.rs`, below this module.
//! What one search measures is built here too, in one call per search (`candidates.rs`: the formula as
//! written and its truth's formula, the fastest form and its sign, each rule's candidate from the current best
//! and its cost). Which candidates are kept is decided above the backends (`numerics::robust`), by measured
//! bits of error against a higher-precision truth over the formula's domain, within a cost budget. A rule that does not
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
//!   s = a + b and e, the rounding error of the sum and of the `+ − × /` below it ([`rounding_error`](compensated)), and
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
//!   else c scaled by 2¹⁵³⁶ and E by 1536·ln 2 (exact there; [`two_divisors`](scale); a compare, three selects and four
//!   operations, ~+14, where nesting costs a second exp);
//!   and the exponent halved over two nested builtins so two tiny divisors (Cook–Torrance's NL, NV ~1e-224)
//!   each meet one half (twice the cost). One division by a product rather than a chain: dependent divisions
//!   add latency the static cost does not see (Cook–Torrance's `/nh/nh/nh/nh`: 1.36× measured at 1.23× static).
//!   A divisor that may be exactly 0 and reads inputs no other factor reads (Ward's √NL) makes a pole there, which
//!   the builtin (an infinite b/c taken for an overflowed factor) would turn into 0 where e^E underflows: such
//!   a product is guarded, `d == 0 ? rest/d : expmuldiv(…)` ([`pole_guard`](scale), +6 per product).
//!
//! - `smith-g1`: Smith's G1 for GGX written with tan², `K/(1 + sqrt(1 + A·(1 − c²)/c²))` (tan² spelt
//!   `(1 − c²)/(c²)` or `(1 − c²)/c/c`, A any product), → `K·|c|/(|c| + sqrt(c² + A·(1 − c²)))`, c itself where
//!   c > 0 (range or guard), then c cancelled against a divisor c of the products around it (BRDF Explorer's
//!   GGX: `G·…/(4·NL·NV)`). At grazing c, c² underflows: tan² = 1/0 and G1 = 0, and the product meets 0/0.
//!   Cheaper than the written form (no division by c², no 4·NL·NV).
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
//! - `sine-square` (in `vector.rs`): `1 − c²`, `c² − 1` and `c²·(A − 1) + 1` where c = x/sqrt(x² + R) is a
//!   component of a vector the formula normalises (R the other squares; `scaled-norm`'s scaled form included)
//!   → `R/(x² + R)`, `−R/(x² + R)`, `R/(x² + R) + A·c²`: exact in real arithmetic, and free of the
//!   cancellation near c = 1 (GGX's D at α = 0.001 near the normal lost ~20 bits in NH²(α² − 1) + 1; Beckmann's
//!   exponent (NH² − 1)/(m²NH²) at small m). Of any other c (an input: NL), `fma(−c, c, 1)`, one rounding.
//! - `cancel-tan` (in `vector.rs`): `x·(a ± b/x) → x·a ± b` (and `b/x ± a`): BRDF Explorer's GGX D writes
//!   `c²·(α² + tan²)` with tan² = (1 − c²)/c², ∞·0 where c² underflows.
//! - `half-complement` (in `vector.rs`): `1 − u·h` with h = (L + V)/|L + V| (u = V or L: Schlick's 1 − VH) →
//!   `(|u × o|² + (1 − |u|²)·|w|²)/(|w|·(|w| + u·w))` (w = L + V, o the other direction) where u·h > 1/2,
//!   else as written. Exact for directions that are not unit (Lagrange's identity |u|²|w|² − (u·w)² = |u × w|²
//!   and u × w = u × o); the cross product by Kahan's fma differences of products, 1 − |u|² from the squares'
//!   exact pairs (2Sum, fma), since where 1 − VH is ~10⁻¹² the few-ulp deviation of an f64 direction from unit
//!   length is most of it. Cost ~+60: kept where the formula around it pays for it (GGX, principled), not in
//!   Schlick's Fresnel alone.
//! - `cancel-common` (in `vector.rs`): a product/quotient tree with a factor x in both numerator and
//!   denominator, x cancelled (`|x|` over x: the sign of x, as a select); the divisors left divide one by one
//!   where they may be tiny or huge. BRDF Explorer's G files write `G·(1/(NL·NV))` with G = NL·NV·…: 0·∞ where
//!   NL·NV underflows. Where x = 0 the written form is 0/0 and the rewrite is its continuous extension (the
//!   truth's limit there).
//! - `interleave-quotient` (in `vector.rs`): `x·y·…/(d·…) → (x/d)·y·…/…` where x, y (the first two numerator
//!   factors that may be tiny or huge) and d may leave the f64 range: BRDF Explorer's AP07 and Neumann G terms,
//!   `NL·NV/(NL + NV − NL·NV)`, where NL·NV underflows to 0 and the value is ~min(NL, NV).
//! - `norm-cancel` (in `angle.rs`): a quotient `n/d` whose numerator and denominator have the same degree k
//!   in a vector's length s = √(a² + b² + …) (each is s^k times an expression without s: products and quotients
//!   of the components w/s, sums of equal degrees) → the same quotient with s replaced by m = max(|a|, |b|, …):
//!   Ward's `(hx²/αx² + hy²/αy²)/hz²` of H = w/|w| as `((wx/m)²/αx² + (wy/m)²/αy²)/(wz/m)²`. Exact wherever
//!   s > 0 (m^k cancels as s^k did); the squares, their sum, the sqrt and its rounding no longer reach the
//!   quotient, and w/m is as far from underflow as w/s (the largest component is ±1). Placed after
//!   `scaled-norm`, whose scaled components it keeps.
//! - `one-minus-power` (in `angle.rs`): `1 − m^k` (a multiplication chain or pow with k ≤ 16) →
//!   `d·(1 + m·(1 + m·(…(1 + m))))` with d = x where m = 1 − x, else d = 1 − m (exact near m = 1, Sterbenz):
//!   Ashikhmin–Shirley's `1 − (1 − c/2)⁵` at small c was 1 minus a rounded 1 (62 bits); the Horner sum of
//!   positive terms rounds a few times. Cost k − 1 multiply-adds for the chain's ~log₂ k products.
//! - `compensated-exponent` (in `angle.rs`): `exp(E)` → `exp(E) + exp(E)·e`, or expmuldiv's b as `b + b·e`, e the
//!   first-order rounding error of E's `+ − × /` tree (as `compensated-sum` carries it; e taken as 0 where |e| ≥ ½,
//!   an overflowed exponent), after `norm-cancel` (fewer roundings to carry, and cheaper): exp turns E's absolute
//!   error into a relative one, so Ward's `(hx²/αx² + hy²/αy²)/hz²` of a few units lost its ~6 roundings times
//!   that size (5.1 bits at 130 of 10⁵ points; none over 4 with it). Cost ~3 per operation of E.
//! - `one-minus-exp` (in `angle.rs`): `1 − exp(E)` → `|E| < ½ ? (u == 1 ? −E·(1 + E/2) : (1 − u)·E/ln(u)) : 1 − u`,
//!   u = exp(E) (Kahan's expm1 through exp and ln; exact in reals, the series where u rounds to 1 within 2⁻¹⁰⁷):
//!   at small E, 1 − u was the rounding of u (Nishino's
//!   `1 − exp(−k·NH^n)`). Cost: one ln (20) and a few operations.
//! - `tan-pole` (in `angle.rs`): `tan(x)` with x built from acos calls by min, max, sums and halvings (Oren–Nayar's
//!   tan(β), tan((α + β)/2)) → `t = tan(c ? d : x)`, `c ? 1/t : t`, c = π/4 < x, d = (π/2ʰ − x) + (π/2ˡ − xˡ) with
//!   xˡ x's low part (acos's `acoslo`, 2Sum errors of the sums, the tail of the operand a min or max picks):
//!   π/2ʰ − x is exact there (Sterbenz), so tan near its pole is computed from the distance to it. At z = 1e-20
//!   acos(z) rounds to π/2ʰ and tan gave 1.6e16 for 1e20. Cost: acoslo per acos (8), a compare and two selects.
//! - `rational-form` (in `cancel.rs`): a cancelling sum rational in one input, as one linear-fractional form
//!   with double-double parameter-only coefficients.
//! - `compensated-exp` (in `cancel.rs`): exp's (or expmuldiv's) argument K·q, K its parameter-only factors in
//!   double-double, computed as Kʰ·q with the product's rounding error (and q's own, acos's through `acoslo`)
//!   carried as a relative tail t: e + e·t, or into expmuldiv's b.
//! - `compensated-params` (in `cancel.rs`): each parameter-only subtree the
//!   kernel reads, when it rounds more than once or calls pow or acos, in double-double (pow's and acos's own
//!   roundings through the builtins `powlo` and `acoslo`) and rounded once. Applied to the live formula, so a
//!   baked kernel folds the value the live one's prepared block computes; free per point (F_kutlog's acos(Q^(1/k))/acos(Q^(1/n)), where acos
//!   near 1 multiplied pow's half ulp ~20 times).
//!
//! Another candidate, large integer powers kept as `pow` calls instead of multiplication chains, is the
//! simplifier's own [`super::Policy::max_chain`] (`pow-call`, with [`pow_call_policy`]). Another,
//! `compensated-power` ([`compensated_powers`]), rebuilds those calls as multiplication chains that carry their rounding errors
//! (fma) where a step's rounding would weigh more than 3u, within 3 ulp of pow at ~2.5–3× the plain chain's
//! operations and below pow's cost.
//!
//! # Cost model
//! [`cost`] counts live nodes with weights fitted to JIT timings on x86-64 (measured when they were fitted: five
//! extra divisions add ~3.4 ns to Beckmann's 8.5 ns, a libm exp ~5 ns): `+ − ×`, abs, min, max 1; clamp 2;
//! `/` and sqrt 3; fma 1; math-library calls (exp, ln, trig) 20, expmuldiv 28 (it replaces an exp, a `×` and
//! a `/` (24) and adds a range test: Beckmann's kernel takes ~1.15× the unrewritten one with it, on `lobe
//! bench`'s inputs and on inputs where no lane takes its rare branch alike), acoslo 8 (beside the acos it
//! corrects, whose reduction the JIT shares: the Gaussian's kernel measured +1.5 ns batched on 8.5), pow 60 (pow(NH, e) with e live took 5.0× the
//! ns of the 14-multiplication chain for NH¹⁰⁰⁰); leaves and negation 0.
//! Nodes that read no input (parameters only) cost nothing: the kernels compute them once per parameter set
//! (the prepared block, hoisted out of batch loops).
//! It ranks candidates; the kernel's run time, measured in `lobe bench`, is what BENCHMARKS.md reports.

mod angle;
mod cancel;
mod candidates;
mod chain;
mod compensated;
mod power;
mod rule;
mod scale;
mod vector;

pub use chain::{compensated_powers, pow_call_policy};
pub use rule::{identity, Example, Rule, Sites};
pub(crate) use candidates::{Candidate, Candidates, Written};

use super::rewrite::Analysis;
use super::Policy;
use crate::builtins::Builtin;
use crate::ir::{BinOp, Formula, Ir, Node, NodeId};

/// Every candidate of the accuracy pass, one line each, in the order the live search tries them (a rule that
/// asks to go early on the formula first, [`Rule::early`]): a rule kept first can hide another's pattern, and the
/// notes on the lines say where the order matters.
pub static RULES: &[&dyn Rule] = &[
    &power::PowCall,
    &power::CompensatedPower,
    &scale::SplitSqrt,
    &scale::SmithG1,
    &scale::CancelMin,
    // Before quotient-chain, which flattens (x/√s)·(x/√s) into x·x/√s/√s, where scaled-norm cannot see it.
    &scale::ScaledNorm,
    // After scaled-norm and before quotient-chain: they read c = x/sqrt(S) and c·c as the formula has them.
    &vector::CancelTan,
    &vector::SineSquare,
    &vector::HalfComplement,
    &vector::CancelCommon,
    &vector::InterleaveQuotient,
    // After scaled-norm, whose scaled components it keeps; before quotient-chain flattens the quotients.
    &angle::NormCancel,
    &scale::QuotientChain,
    &scale::ScaledExp,
    &compensated::FactorQuadratic,
    // Before compensated-sum, which would carry the errors of the same cancellation at a higher cost.
    &angle::OneMinusPower,
    &angle::OneMinusExp,
    &compensated::CompensatedBase,
    &compensated::CompensatedSum,
    &angle::TanPole,
    &cancel::RationalForm,
    &cancel::CompensatedExp,
    &angle::CompensatedExponent,
    &cancel::CompensatedParams,
    &power::LiveChoice,
];

/// The rule named `name`.
pub fn rule(name: &str) -> Option<&'static dyn Rule> {
    RULES.iter().copied().find(|r| r.name() == name)
}

/// The baked pass's first trial: the live decision with the values baked ([`Sites::Baked`]).
pub static LIVE_CHOICE: &dyn Rule = &power::LiveChoice;

/// The baked pass's second: the baked powers as compensated chains.
pub static COMPENSATED_POWER: &dyn Rule = &power::CompensatedPower;

/// A local rule's rebuilt arena as a formula, simplified again (default policy) so constants fold; `None` when
/// it did not fire.
fn finish(a: &Analysis, (ir, root, fired): (Ir, NodeId, bool)) -> Option<Formula> {
    if !fired {
        return None;
    }
    let g = Formula { ir, root, ..a.f.clone() };
    Some(super::simplify_with(&g, &[], &Policy::default()).0)
}

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

#[cfg(test)]
mod tests {
    use super::*;

    /// `src` parsed and simplified (nothing baked): the rules' unit tests start from it.
    pub(super) fn parse(src: &str) -> Formula {
        let f = crate::front::parse("t.brdf", src).unwrap();
        crate::simplify::simplify(&f, &[])
    }

    #[test]
    fn cost_leaves_out_the_prepared_block() {
        // n/a reads no input: computed once per parameter set, so it costs nothing per point.
        let (a, b) = (parse("param a = 16 in 1..1000\nn/a*NH"), parse("param a = 16 in 1..1000\nn*NH"));
        assert_eq!(cost(&a), cost(&b));
        assert_eq!(cost(&parse("NH/NL")), cost(&parse("NH*NL")) + 2.0);
    }
}

