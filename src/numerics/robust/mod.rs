//! Numerical robustness: bits of error against the truth over a formula's domain, and the accuracy pass's
//! choice among candidate rewrites. By concern: the metric and the judgement (`metric.rs`), the domain's
//! points (`sample.rs`), measuring against the truth (`measure.rs`), the search (`search.rs`), the check
//! command's report (`report.rs`). The candidates themselves are built in `simplify::accuracy`: one
//! `Candidates` per search (the formula as written and its truth's formula, the base and its sign, each rule's
//! candidate from the current best with its cost), asked for once per pass; this module only measures and judges.
//!
//! # Design
//! Herbie's measure (Panchekha et al., PLDI 2015): at each input point the error of an f64 result `y` is
//! `log2(ulps(y, t) + 1)` bits, where `t` is the true value ([`super::truth`]: the formula as written, baked
//! parameters folded, evaluated in ~104-bit precision with an unbounded exponent) rounded once to f64; 0 bits is
//! correctly rounded, 64 bits is NaN or ∞ where the truth is finite. [`measure`] reports the average and the
//! maximum over a sample of the domain with the worst input, counts the points where the result is NaN/∞ but the
//! truth is finite, the points where the formula is undefined even in exact arithmetic (0/0, ∞·0 at e.g. NH = 0
//! exactly, with no limit along an input on its edge, [`truth::limit`](crate::numerics::truth::limit); left out of the averages; where the
//! limit exists it is the truth, and the report counts those points), poles (the exact value ±∞, which the
//! result must be), and the points where the formula is *ill-conditioned by nature*: a 1-ulp
//! change of one input moves the true value by more than [`ILL_CONDITIONED_ULPS`] ulps, so no
//! f64 evaluation can be accurate there (the Gaussian at large n: exp amplifies its argument). The maximum over
//! well-conditioned points is reported separately.
//!
//! The domain ([`sample`]): every input the formula reads in [0, 1], a quarter of the values from the edge
//! classes (0, 1, 1 − 2⁻⁵³, 1 − 2⁻⁵², the smallest denormal, a denormal, 2⁻¹⁰²², 10⁻³⁰⁰, 1.6·10⁻¹⁶², 10⁻¹⁵⁴,
//! 10⁻⁷⁷, 10⁻²⁰, ½), a quarter 1 − 10⁻ᵘ (u ∈ [0, 16]), a fifth log-uniform down to 10⁻³²³, the rest uniform;
//! live parameters over their declared ranges (endpoints, [`special_values`], uniform, log-uniform; a tenth of
//! the points with two parameters equal), bools at 0 and 1 only. A formula that reads VH with
//! NL or NV gets geometrically possible combinations only: N·(L + V) = |L + V|·NH and |L + V| = 2·VH, so
//! NL + NV = 2·NH·VH (VH = 0 means L = −V, where NL = NV = 0); the total is split at a random fraction drawn
//! like an input (edge classes included). Other inputs are drawn independently, the conservative choice for a
//! kernel that may be fed any cosines. A formula that reads directions (Lx..Vz) is sampled on real geometry
//! instead: unit L and V on the upper hemisphere, each with its normal component N·L drawn like an input (so
//! the edge classes become grazing and horizon directions, and directions at the normal) and a uniform azimuth
//! (a fifth on the frame axes, where components are exactly 0; a twentieth of the pairs face each other across
//! the normal, so L + V ∥ N, tiny at grazing angles), every input computed from the pair by
//! [`super::inputs_from_dirs`]. Deterministic (fixed seed).
//!
//! The pass ([`improve`]): a search with every parameter live, from the simplified formula (the fastest form
//! lobe builds): each candidate (a [`Rule`](crate::simplify::accuracy::Rule) of the registry `simplify::accuracy::RULES` at a site, or a
//! whole-formula form) is built from the current best, measured on the same points against the same truth,
//! and kept when more accurate (`better`) — the invariants first (no more NaN/∞ where the truth is finite,
//! missed poles or wrong signs), no point taken beyond [`TARGET_BITS`] where it was within it unless ten times
//! as many are fixed, then fewer well-conditioned points beyond the target, a lower maximum, fewer points near
//! the target, a lower average — and within the cost budget (`simplify::accuracy::cost`): [`Prefer::Speed`]
//! keeps only rewrites that cost nothing, [`Prefer::Accuracy`] (default) those within `max_cost` (1.3) × the
//! fastest form's cost, up to [`NONFINITE_BUDGET`] (2×) for a rewrite that keeps lobe's promise at more
//! points (`keeps_promise`), and up to the pow calls' cost for compensated power chains. Rules are tried once
//! each, in the registry's order, a rule that asks to go early on this formula first. Candidates are known by a
//! structural hash of their IR (`simplify::accuracy::identity`). Every candidate keeps the formula's sign where range analysis of the
//! formula as written bounds it ([`crate::simplify::keep_sign`]). The search stops at [`PassOptions::budget`]
//! with the best form so far.
//!
//! Decided once, for every parameter value: with baked values the live decision is baked (the live choice
//! simplified with the values folded in, integer powers above 8 kept as pow calls as the live kernel calls pow,
//! then their compensated chains where no less accurate and cheaper) and no other rule is tried, so a baked
//! kernel computes what the live one does: parameter-only subexpressions fold to exactly what the live kernel's
//! prepared block computes (the folder and the backends share `BinOp::apply` and `Builtin::eval`). The decision
//! ([`Decision`]: the kept steps) replays without measuring ([`replay`]), which is what the on-disk cache
//! ([`super::pass_cache`]) stores.
//!
//! Cost: one truth evaluation per point (1–5 µs for a catalogue formula in release; a limit only where it is
//! NaN), computed once per pass ([`Reference`]), one evaluation per point and candidate (compiled by the JIT,
//! which gives the interpreter's bits, from `JIT_FROM_POINTS` points; interpreted below), and the condition
//! (two truth evaluations per read input and live parameter, re-evaluating only the nodes that read it) once
//! per point where some candidate is more than [`TARGET_BITS`] off; for the report, at every point
//! ([`Conditioning::Everywhere`]), the truth's first-order condition and a bound on its rest, carried in the
//! truth's own pass ([`Reference::everywhere`], `truth::linear`), with exact moves only of the variables it
//! does not settle; parallel over points (rayon). On one core: 3–65 ms per catalogue formula, up to ~265 ms
//! for BRDF Explorer's largest files, and 0.5–1.5 s for `lobe check`'s 10⁵ points per explorer file
//! (BENCHMARKS.md, the `pass` bench).

mod measure;
mod metric;
mod report;
mod sample;
mod search;

pub use measure::{condition_ulps, measure, Conditioning, Reference};
pub use metric::{ulps, ErrorStats, Worst, ILL_CONDITIONED_ULPS, TARGET_BITS};
pub use report::{BuiltinBound, CheckReport, CompileUs, FastAtJson, FastJson, ErrorStatsJson, ParamJson, RewriteCount, RoundingJson, TrialJson, WorstJson};
pub use sample::{sample, special_values, Point};
pub use search::{
    improve, replay, with_pass, with_pass_cached, Decision, DecisionStore, Outcome, PassOptions, Prefer, Stage, Step, Trial, Verdict,
    NONFINITE_BUDGET,
};
pub(crate) use search::{improve_observed, with_pass_until, COMMAND_BUDGET};
