//! Numerical robustness: bits of error against the truth over a formula's domain, and the accuracy pass's
//! choice among candidate rewrites.
//!
//! # Design
//! Herbie's measure (Panchekha et al., PLDI 2015): at each input point the error of an f64 result `y` is
//! `log2(ulps(y, t) + 1)` bits, where `t` is the true value ([`super::truth`]: the formula as written, baked
//! parameters folded, evaluated in ~104-bit precision with an unbounded exponent) rounded once to f64; 0 bits is
//! correctly rounded, 64 bits is NaN or ∞ where the truth is finite. [`measure`] reports the average and the
//! maximum over a sample of the domain with the worst input, counts the points where the result is NaN/∞ but the
//! truth is finite, the points where the formula is undefined even in exact arithmetic (0/0, ∞·0 at e.g. NH = 0
//! exactly, with no limit along an input on its edge, [`truth::limit`]; left out of the averages; where the
//! limit exists it is the truth, and the report counts those points), and the points where the formula is *ill-conditioned by nature*: a 1-ulp
//! change of one input or live parameter moves the true value by more than [`ILL_CONDITIONED_ULPS`] ulps, so no
//! f64 evaluation can be accurate there (the Gaussian at large n: exp amplifies its argument). The maximum over
//! well-conditioned points is reported separately.
//!
//! The domain ([`sample`]): every input the formula reads in [0, 1], a quarter of the values from the edge
//! classes (0, 1, 1 − 2⁻⁵³, 1 − 2⁻⁵², the smallest denormal, a denormal, 2⁻¹⁰²², 10⁻³⁰⁰, 1.6·10⁻¹⁶², 10⁻¹⁵⁴,
//! 10⁻⁷⁷, 10⁻²⁰, ½), a quarter 1 − 10⁻ᵘ (u ∈ [0, 16]), a fifth log-uniform down to 10⁻³²³, the rest uniform;
//! live parameters over their declared ranges (endpoints, uniform, log-uniform). A formula that reads VH with
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
//! The pass ([`improve`]): start from the simplified formula (the fastest form lobe builds), try
//! `compensated-params` first (it rewrites the formula before baking, so a baked parameter folds what the live
//! kernel computes), then each candidate of `simplify::accuracy` in turn on the current best, keep it when it is more accurate — fewer non-finite
//! results where the truth is finite, then a lower maximum over well-conditioned points (by half a bit, or from
//! above [`TARGET_BITS`] to within it), then a lower average — and its static cost ([`crate::simplify::accuracy::cost`]) stays within the budget: [`Prefer::Speed`] keeps
//! only rewrites that cost nothing, [`Prefer::Accuracy`] (default) those within `max_cost` (1.3) × the fastest
//! form's cost — up to [`NONFINITE_BUDGET`] (2×) for a rewrite that removes NaN/∞ results where the true
//! value is finite, since those are wrong answers, not imprecise ones — and up to the cost of the `pow`-call
//! form for `compensated-power` (large baked integer powers as compensated chains): a baked exponent then never
//! costs more than the live formula, which calls pow, and agrees with it within a few ulp instead of the plain
//! chain's hundreds. Each trial is reported with what it bought. A rule applied everywhere that was dropped as
//! no more accurate is tried once more after a later rule was kept: two defects at the same points (a zero
//! normalize length and an underflowing 1/(NL·NV)) each hide the other's fix.
//!
//! Bake-consistent choices: a baked kernel must agree with the live one at the baked values (within 4 ulp,
//! tests/it/robust.rs), but a pass measured on the baked domain alone decides by what that domain needs, so it
//! dropped rewrites the live pass kept (Beckmann's `compensated-exp` at m = 0.3, F_dsh's `rational-form` at
//! n = 50), and the two kernels then differ by the correction. So with baked values the pass first decides
//! with every parameter live, then bakes that choice: the live choice simplified with the values folded in
//! (`live-choice`, its first trial), parameter-only subexpressions folding to exactly what the live kernel
//! computes once per parameter set (the folder and the backends share `BinOp::apply` and `Builtin::eval`).
//! Replaying the live rules on the baked form instead would need their sites to match across two arenas
//! whose folding differs; baking the choice keeps it by construction. It is kept unless it measures less
//! accurate than the plain baked form (ties kept) or costs more than both the budget and the live kernel
//! (folding only removes work, so in practice never). The search then goes on from it with the rules the
//! live choice did not keep, the power candidates built from it: a baked exponent still gets its
//! compensated chain (the live kernel calls pow). A baked value the formula does not read is dropped first
//! (the live decision is then the whole decision). Cost: a baked formula's pass measures twice (live, then
//! baked), ~2× the time; with nothing kept live, it is the baked pass alone plus the live one's measuring.
//!
//! Cost: one truth evaluation per point (1–5 µs for a catalogue formula in release; a limit, up to three per
//! input on an edge, only where it is not finite), computed once per pass ([`truths`]), plus one interpreter
//! evaluation per point and candidate, plus the condition estimate (two truth evaluations per read input) at the
//! points with more than 4 bits of error; parallel over points (rayon). 10⁵ points: 0.3–2 s per formula.

use super::truth;
use crate::base::json::{self, Named};
use crate::base::rng::Rng;
use crate::backend::interp::Interp;
use crate::backend::Evaluator;
use crate::ir::{Formula, Input, N_INPUTS};
use crate::simplify::accuracy::{compensated_params, compensated_powers, cost, pow_call_policy, Rule};

const COMPENSATED: &str = "compensated-power";
const PARAMS: &str = "compensated-params";
use rayon::prelude::*;

/// Budget multiple for a candidate that removes NaN/∞ results where the truth is finite (wrong answers rather
/// than imprecise ones) under `Prefer::Accuracy`, whatever `max_cost` says; `Prefer::Speed` never pays it.
pub const NONFINITE_BUDGET: f64 = 2.0;

/// The error allowed where the formula is well conditioned: 4 bits, 15 ulp (issue 12).
pub const TARGET_BITS: f64 = 4.0;

/// A 1-ulp change of an input moving the truth by more than this many ulps marks a point ill-conditioned.
pub const ILL_CONDITIONED_ULPS: f64 = 16.0;

/// One point of the domain: inputs in [`Input::ALL`] order and the full parameter vector.
#[derive(Clone, Debug, PartialEq)]
pub struct Point {
    pub x: [f64; N_INPUTS],
    pub p: Vec<f64>,
}

/// Distance in units in the last place between two f64 (NaN–NaN is 0, NaN–number is 2⁶⁴).
pub fn ulps(a: f64, b: f64) -> f64 {
    if a.is_nan() || b.is_nan() {
        return if a.is_nan() && b.is_nan() { 0.0 } else { 2f64.powi(64) };
    }
    let ord = |x: f64| {
        let b = x.to_bits() as i64;
        i128::from(if b < 0 { i64::MIN - b } else { b })
    };
    (ord(a) - ord(b)).unsigned_abs() as f64
}

/// Herbie's bits of error: log2(ulps + 1).
pub(crate) fn bits(a: f64, b: f64) -> f64 {
    (ulps(a, b) + 1.0).log2()
}

/// The edge classes every input draws from (module docs).
pub(crate) const EDGES: [f64; 13] = [
    0.0,
    1.0,
    1.0 - 1.1102230246251565e-16,
    1.0 - 2.220446049250313e-16,
    5e-324,
    1e-310,
    2.2250738585072014e-308,
    1e-300,
    1.6e-162,
    1e-154,
    1e-77,
    1e-20,
    0.5,
];

fn input_value(r: &mut Rng) -> f64 {
    let u = r.unit();
    let v = r.unit();
    if u < 0.25 {
        EDGES[r.below(EDGES.len() as u64) as usize]
    } else if u < 0.5 {
        1.0 - 10f64.powf(-16.0 * v)
    } else if u < 0.7 {
        10f64.powf(-323.0 * v)
    } else {
        v
    }
}

/// A unit direction on the upper hemisphere: its normal component drawn like an input, a uniform azimuth (a
/// fifth on the frame axes).
fn direction(r: &mut Rng) -> super::V3 {
    let z = input_value(r);
    if r.unit() < 0.2 {
        // On the axes the other component is exactly 0 (cos(π/2) is 6e-17, not 0).
        let k = r.below(4) as usize;
        let mut d = super::dir_from_cos(z, k as f64 * std::f64::consts::FRAC_PI_2);
        d[(k + 1) % 2] = 0.0;
        return d;
    }
    super::dir_from_cos(z, std::f64::consts::TAU * r.unit())
}

/// `n` points of `f`'s domain (module docs); parameters listed in `bake` keep their baked value.
pub fn sample(f: &Formula, bake: &[(usize, f64)], n: usize, seed: u64) -> Vec<Point> {
    let mut r = Rng(seed.max(1));
    let used = f.used_inputs();
    (0..n)
        .map(|_| {
            let mut x = [0.5; N_INPUTS];
            if used.reads_directions() {
                let l = direction(&mut r);
                let mut v = direction(&mut r);
                // A twentieth of the pairs face each other across the normal (L + V ∥ N, of length 2·(Lz + Vz)
                // for grazing pairs): normalize(L + V)'s degenerate case.
                let lt = (l[0] * l[0] + l[1] * l[1]).sqrt();
                if r.unit() < 0.05 && lt > 0.0 {
                    let t = (1.0 - v[2] * v[2]).max(0.0).sqrt() / lt;
                    v = [-l[0] * t, -l[1] * t, v[2]];
                }
                x = super::inputs_from_dirs(l, v);
            }
            for i in Input::ALL {
                if used.contains(i) && !used.reads_directions() {
                    x[i.index()] = input_value(&mut r);
                }
            }
            // Geometry: N·(L + V) = |L + V|·NH and |L + V| = 2·VH, so NL + NV = 2·NH·VH; split that total.
            if !used.reads_directions() && used.contains(Input::VH) && (used.contains(Input::NL) || used.contains(Input::NV)) {
                let total = 2.0 * x[Input::NH.index()] * x[Input::VH.index()];
                let nl = (input_value(&mut r) * total).min(1.0);
                let nv = (total - nl).min(1.0);
                x[Input::NL.index()] = (total - nv).min(1.0);
                x[Input::NV.index()] = nv;
            }
            let p = f
                .params
                .iter()
                .enumerate()
                .map(|(k, d)| {
                    // Drawn even when baked, so baking a parameter leaves every other value of the sample as it
                    // was (and the pass measures a baked and a live compile on the same points).
                    let (u, v) = (r.unit(), r.unit());
                    if let Some((_, v)) = bake.iter().find(|(j, _)| *j == k) {
                        return *v;
                    }
                    let val = if u < 0.2 {
                        d.lo
                    } else if u < 0.4 {
                        d.hi
                    } else if u < 0.7 || d.lo <= 0.0 {
                        d.lo + v * (d.hi - d.lo)
                    } else {
                        d.lo * (d.hi / d.lo).powf(v)
                    };
                    val.clamp(d.lo, d.hi)
                })
                .collect();
            Point { x, p }
        })
        .collect()
}

/// The worst point of a measurement.
#[derive(Clone, Debug, PartialEq)]
pub struct Worst {
    pub point: Point,
    pub got: f64,
    pub truth: f64,
    pub bits: f64,
}

/// Bits of error over a sample (module docs).
#[derive(Clone, Debug, PartialEq, Default)]
pub struct ErrorStats {
    pub points: usize,
    /// Mean bits over the points where the truth is defined.
    pub avg_bits: f64,
    pub max_bits: f64,
    pub worst: Option<Worst>,
    /// NaN or ±∞ where the true value is finite.
    pub nonfinite: usize,
    pub first_nonfinite: Option<Worst>,
    /// The truth itself is not finite (0/0, ∞·0, ∞−∞ in exact arithmetic, or a pole such as 1/√(NL·NV) at
    /// NV = 0) and has no limit along an edge input ([`truth::limit`]): left out of the averages, as Herbie
    /// samples only points with a finite truth.
    pub undefined: usize,
    /// The exact value is not finite but its limit along an input exactly on an edge is ([`truth::limit`]):
    /// counted like any point, with the limit as the truth (Cook–Torrance's G/(NL·NV) at NL = 0).
    pub limits: usize,
    /// Points where the formula is ill-conditioned by nature (module docs).
    pub ill_conditioned: usize,
    /// Largest bits of error at a well-conditioned point, and the point.
    pub max_bits_well: f64,
    pub worst_well: Option<Worst>,
}

/// How many ulps the truth moves when one read input or live parameter moves by one ulp (the larger of the
/// two directions); a finite-difference condition number in ulps.
pub fn condition_ulps(truth_f: &Formula, pt: &Point, t: f64) -> f64 {
    let used = truth_f.used_inputs();
    let live = truth_f.ir.used_params(truth_f.root);
    let mut worst: f64 = 0.0;
    let mut probe = |x: [f64; N_INPUTS], p: &[f64]| {
        let mut u = truth::eval(truth_f, &x, p);
        // At a limit point its neighbours along the other inputs are limits too.
        if u.is_nan() {
            u = truth::limit(truth_f, &x, p).unwrap_or(u);
        }
        if !u.is_nan() {
            worst = worst.max(ulps(u, t));
        }
    };
    for i in used.iter() {
        let v = pt.x[i.index()];
        if v == 0.0 {
            continue;
        }
        for w in [v.next_up(), v.next_down()] {
            let mut x = pt.x;
            x[i.index()] = w;
            probe(x, &pt.p);
        }
    }
    for k in live {
        let v = pt.p[k as usize];
        if v == 0.0 {
            continue;
        }
        for w in [v.next_up(), v.next_down()] {
            let mut p = pt.p.clone();
            p[k as usize] = w;
            probe(pt.x, &p);
        }
    }
    worst
}

/// The truth at one point rounded to f64 ([`truth::eval`]), or where that is not finite the limit along an edge
/// input when there is one ([`truth::limit`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct TruthAt {
    pub value: f64,
    pub limit: bool,
}

impl TruthAt {
    pub(crate) fn new(truth_f: &Formula, pt: &Point) -> TruthAt {
        let value = truth::eval(truth_f, &pt.x, &pt.p);
        if value.is_finite() {
            return TruthAt { value, limit: false };
        }
        match truth::limit(truth_f, &pt.x, &pt.p) {
            Some(l) => TruthAt { value: l, limit: true },
            None => TruthAt { value, limit: false },
        }
    }
}

/// The truth at every point, in parallel: computed once and shared by every candidate the pass measures.
pub(crate) fn truths(truth_f: &Formula, points: &[Point]) -> Vec<TruthAt> {
    points.par_iter().map(|pt| TruthAt::new(truth_f, pt)).collect()
}

#[derive(Default)]
struct Acc {
    stats: ErrorStats,
    sum: f64,
    defined: usize,
}

impl Acc {
    fn add(mut self, truth_f: &Formula, pt: &Point, got: f64, ta: TruthAt) -> Acc {
        self.stats.points += 1;
        let t = ta.value;
        if !t.is_finite() {
            self.stats.undefined += 1;
            return self;
        }
        self.stats.limits += usize::from(ta.limit);
        let b = bits(got, t);
        let w = || Some(Worst { point: pt.clone(), got, truth: t, bits: b });
        if !got.is_finite() && t.is_finite() {
            self.stats.nonfinite += 1;
            if self.stats.first_nonfinite.is_none() {
                self.stats.first_nonfinite = w();
            }
        }
        self.defined += 1;
        self.sum += b;
        if b > self.stats.max_bits || self.stats.worst.is_none() {
            self.stats.max_bits = b;
            self.stats.worst = w();
        }
        let ill = b > 4.0 && t.is_finite() && condition_ulps(truth_f, pt, t) > ILL_CONDITIONED_ULPS;
        if ill {
            self.stats.ill_conditioned += 1;
        } else if b > self.stats.max_bits_well || self.stats.worst_well.is_none() {
            self.stats.max_bits_well = b;
            self.stats.worst_well = w();
        }
        self
    }
    fn merge(mut self, o: Acc) -> Acc {
        let (a, b) = (&mut self.stats, o.stats);
        a.points += b.points;
        a.nonfinite += b.nonfinite;
        a.undefined += b.undefined;
        a.limits += b.limits;
        a.ill_conditioned += b.ill_conditioned;
        if a.first_nonfinite.is_none() {
            a.first_nonfinite = b.first_nonfinite;
        }
        if b.worst.is_some() && (a.worst.is_none() || b.max_bits > a.max_bits) {
            a.max_bits = b.max_bits;
            a.worst = b.worst;
        }
        if b.worst_well.is_some() && (a.worst_well.is_none() || b.max_bits_well > a.max_bits_well) {
            a.max_bits_well = b.max_bits_well;
            a.worst_well = b.worst_well;
        }
        self.sum += o.sum;
        self.defined += o.defined;
        self
    }
}

/// Bits of error of `ev` against the truth of `truth_f` (the formula as written, baked values folded) at
/// `points`; in parallel.
pub fn measure(ev: &dyn Evaluator, truth_f: &Formula, points: &[Point]) -> ErrorStats {
    measure_against(ev, truth_f, points, &truths(truth_f, points))
}

/// [`measure`] with the truth at each point given ([`truths`]).
pub(crate) fn measure_against(ev: &dyn Evaluator, truth_f: &Formula, points: &[Point], truths: &[TruthAt]) -> ErrorStats {
    let acc = points
        .par_chunks(256)
        .zip(truths.par_chunks(256))
        .map(|(ch, ts)| ch.iter().zip(ts).fold(Acc::default(), |a, (pt, t)| a.add(truth_f, pt, ev.eval(&pt.x, &pt.p), *t)))
        .reduce(Acc::default, Acc::merge);
    let mut s = acc.stats;
    s.avg_bits = if acc.defined > 0 { acc.sum / acc.defined as f64 } else { 0.0 };
    s
}

/// What to optimise for: speed or accuracy.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Prefer {
    /// Only rewrites that cost nothing.
    Speed,
    /// The most accurate form within `max_cost` × the fastest form's cost.
    #[default]
    Accuracy,
}

impl std::str::FromStr for Prefer {
    type Err = String;
    fn from_str(s: &str) -> Result<Prefer, String> {
        match s {
            "speed" => Ok(Prefer::Speed),
            "accuracy" => Ok(Prefer::Accuracy),
            _ => Err(format!("unknown preference `{s}`; expected `speed` or `accuracy`")),
        }
    }
}

/// Settings of the accuracy pass.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PassOptions {
    pub prefer: Prefer,
    /// Budget for `Prefer::Accuracy`, as a multiple of the fastest form's static cost.
    pub max_cost: f64,
    /// Domain points the candidates are measured on.
    pub points: usize,
    pub seed: u64,
    /// The math mode candidates are measured in: the one the chosen formula will be compiled in.
    pub math: crate::Mode,
}

impl Default for PassOptions {
    fn default() -> PassOptions {
        PassOptions { prefer: Prefer::Accuracy, max_cost: 1.3, points: 4096, seed: 0x5eed_1ab5, math: crate::Mode::Precise }
    }
}

/// Most truth work per measurement, in static cost units × points ([`cost`]); a formula above ~200 cost units
/// (40 shared trigonometric `let`s, say) is measured on fewer points than asked, and the report says how many.
/// Every catalogue formula (cost ≤ ~150) gets 10⁵ points.
pub(crate) const MAX_WORK: f64 = 2e7;

/// One candidate tried by the pass.
#[derive(Clone, Debug)]
pub struct Trial {
    pub rule: &'static str,
    pub describe: &'static str,
    pub kept: bool,
    /// Why it was kept or dropped.
    pub reason: String,
    pub stats: ErrorStats,
    pub cost: f64,
}

/// The pass's result: the chosen formula, its error before and after, and every trial.
#[derive(Clone, Debug)]
pub struct Outcome {
    pub formula: Formula,
    pub before: ErrorStats,
    pub after: ErrorStats,
    pub cost_before: f64,
    pub cost_after: f64,
    pub trials: Vec<Trial>,
    /// Domain points measured (fewer than asked for a costly formula; [`MAX_WORK`]).
    pub points: usize,
}

/// `a` is more accurate than `b` (module docs: non-finite first, then well-conditioned max, then average).
fn better(a: &ErrorStats, b: &ErrorStats) -> bool {
    if a.nonfinite != b.nonfinite {
        return a.nonfinite < b.nonfinite;
    }
    if a.max_bits_well < b.max_bits_well - 0.5 {
        return true;
    }
    // Reaching the bound counts however small the step (F_dsh: 4.25 → 3.9 bits).
    if b.max_bits_well > TARGET_BITS && a.max_bits_well <= TARGET_BITS && a.avg_bits <= b.avg_bits + 0.01 {
        return true;
    }
    a.max_bits_well <= b.max_bits_well + 0.01 && a.avg_bits < b.avg_bits - 0.05
}

/// The accuracy pass on `orig` with `bake` folded in (module docs).
pub fn improve(orig: &Formula, bake: &[(usize, f64)], o: &PassOptions) -> Outcome {
    // A baked value the formula never reads changes nothing: the live decision is the whole decision.
    let read = crate::simplify::simplify(orig, &[]);
    let read = read.ir.used_params(read.root);
    let bake: Vec<(usize, f64)> = bake.iter().copied().filter(|(k, _)| read.contains(&(*k as u16))).collect();
    let bake = bake.as_slice();
    // Decided with every parameter live first (module docs: bake-consistent choices).
    let live = (!bake.is_empty()).then(|| improve(orig, &[], o)).filter(|l| l.trials.iter().any(|t| t.kept));
    let base = crate::simplify::simplify(orig, bake);
    let truth_f = crate::simplify::bake_only(orig, bake);
    // The simplified form's cost stands for the truth's work (the truth's own `x^2` is a pow call).
    let n = o.points.min((MAX_WORK / cost(&base).max(1.0)) as usize).max(64);
    let points = sample(orig, bake, n, o.seed);
    let truth = truths(&truth_f, &points);
    let run = |f: &Formula| measure_against(&Interp::with_mode(f, o.math), &truth_f, &points, &truth);
    let before = run(&base);
    let cost_before = cost(&base);
    let base_budget = match o.prefer {
        Prefer::Speed => cost_before,
        Prefer::Accuracy => o.max_cost * cost_before,
    };
    let (mut cur, mut cur_stats, mut cur_cost) = (base.clone(), before.clone(), cost_before);
    let mut trials = Vec::new();
    // The formula the power candidates start from: the live choice once it is kept.
    let mut src = orig;
    // Rules the live choice kept are not tried again: where they apply was decided live.
    let mut decided: Vec<&'static str> = vec![];
    if let Some(l) = &live {
        let cand = crate::simplify::simplify(&l.formula, bake);
        let stats = run(&cand);
        let c = cost(&cand);
        let rules: Vec<&'static str> = l.trials.iter().filter(|t| t.kept).map(|t| t.rule).collect();
        // Not less accurate than the plain baked form (ties kept), and no costlier than the budget or the live
        // kernel the pass already chose.
        let budget = base_budget.max(l.cost_after);
        let (kept, reason) = if better(&before, &stats) {
            (false, format!("{}: less accurate than the plain form with these values baked", rules.join(", ")))
        } else if c > budget {
            (false, format!("{}: costs {:.2}× the fastest form (budget {:.2}×)", rules.join(", "), c / cost_before, budget / cost_before))
        } else {
            (true, format!("{}: cost {:.2}× the fastest form", rules.join(", "), c / cost_before))
        };
        trials.push(Trial { rule: LIVE_CHOICE, describe: LIVE_CHOICE_DESCRIBE, kept, reason, stats: stats.clone(), cost: c });
        if kept {
            (cur, cur_stats, cur_cost) = (cand, stats, c);
            src = &l.formula;
            decided = rules;
        }
    }
    // compensated-params rewrites the formula before baking (so baked and live fold the same expression): when
    // kept, the candidates built from the source below are rebuilt from it.
    let params = if decided.contains(&PARAMS) { None } else { compensated_params(src) };
    let params_cand = params.as_ref().map(|g| crate::simplify::simplify(g, bake));
    let mut pow_call = crate::simplify::simplify_with(src, bake, &pow_call_policy()).0;
    let mut compensated = compensated_powers(&pow_call);
    let mut pow_cost = cost(&pow_call);
    let mut tries: Vec<(&'static str, &'static str, Option<usize>)> = vec![
        (PARAMS, "parameter-only subexpressions in double-double, rounded once where the kernel reads them", None),
        ("pow-call", "integer powers above 8 as pow calls instead of multiplication chains", None),
        (COMPENSATED, "integer powers above 8 as compensated multiplication chains (fma error terms)", None),
    ];
    for r in Rule::ALL.iter().filter(|r| !decided.contains(&r.name())) {
        tries.push((r.name(), r.describe(), None));
    }
    let mut k = 0;
    let mut i = 0;
    let mut second_round = false;
    loop {
        if i == tries.len() {
            // A rule applied everywhere may have been dropped only because another defect hid its gain (the
            // explorer Cook–Torrance's facing pairs need both scaled-norm and a quotient chain): once, after a
            // later rule was kept, those rules are tried again on the result.
            let retry = retries(&trials);
            if second_round || retry.is_empty() {
                break;
            }
            second_round = true;
            tries.extend(retry.into_iter().map(|r| (r.name(), r.describe(), None)));
            continue;
        }
        let (name, describe, _) = tries[i];
        let rule = Rule::ALL.iter().copied().find(|r| r.name() == name);
        // quotient-chain and compensated-sum go site by site, scaled-exp variant by variant (Rule::apply_at); the others apply
        // everywhere at once.
        let site = matches!(rule, Some(Rule::QuotientChain | Rule::ScaledExp | Rule::CompensatedSum)).then_some(k);
        let cand = match rule {
            None if name == COMPENSATED => compensated.clone(),
            None if name == PARAMS => params_cand.clone(),
            None => Some(pow_call.clone()).filter(|p| p.to_program_text() != cur.to_program_text()),
            Some(r) => r.apply_at(&cur, site),
        };
        let Some(cand) = cand else {
            i += 1;
            k = 0;
            continue;
        };
        if site.is_some() && cand.to_program_text() == cur.to_program_text() {
            k += 1;
            continue;
        }
        let stats = run(&cand);
        let c = cost(&cand);
        let fixes = stats.nonfinite < cur_stats.nonfinite;
        let budget = match o.prefer {
            Prefer::Accuracy if fixes => base_budget.max(NONFINITE_BUDGET * cost_before),
            // A baked power may cost what the live formula's pow call costs (module docs).
            Prefer::Accuracy if name == COMPENSATED => base_budget.max(pow_cost),
            _ => base_budget,
        };
        let (kept, mut reason) = if !better(&stats, &cur_stats) {
            (false, NOT_BETTER.to_string())
        } else if c > budget {
            (false, format!("more accurate but costs {:.2}× the fastest form (budget {:.2}×)", c / cost_before, budget / cost_before))
        } else {
            (true, format!("cost {:.2}× the fastest form", c / cost_before))
        };
        if let Some(s) = site {
            reason = format!("site {}: {reason}", s + 1);
        }
        trials.push(Trial { rule: name, describe, kept, reason, stats: stats.clone(), cost: c });
        if kept {
            if let Some(g) = params.as_ref().filter(|_| name == PARAMS) {
                pow_call = crate::simplify::simplify_with(g, bake, &pow_call_policy()).0;
                compensated = compensated_powers(&pow_call);
                pow_cost = cost(&pow_call);
            }
            cur = cand;
            cur_stats = stats;
            cur_cost = c;
        } else {
            k += 1;
        }
        // One compensated sum at most: its own error terms (2Sum's differences) would be sites next.
        if site.is_none() || (kept && rule == Some(Rule::CompensatedSum)) {
            i += 1;
            k = 0;
        }
    }
    Outcome { formula: cur, before, after: cur_stats, cost_before, cost_after: cur_cost, trials, points: n }
}

/// The first trial of a pass with baked values: the live decision, baked (module docs).
pub const LIVE_CHOICE: &str = "live-choice";
const LIVE_CHOICE_DESCRIBE: &str = "the rewrites chosen with every parameter live, the baked values folded into them: baked and live kernels agree";

/// A trial's reason when it measured no more accurate than the current best.
const NOT_BETTER: &str = "no more accurate on the sample";

/// The rules applied everywhere (a site-by-site trial's reason starts "site k:") dropped as no more accurate
/// before the last trial that was kept, in the order they were tried.
fn retries(trials: &[Trial]) -> Vec<Rule> {
    let Some(last_kept) = trials.iter().rposition(|t| t.kept) else { return vec![] };
    trials[..last_kept].iter().filter(|t| t.reason == NOT_BETTER).filter_map(|t| Rule::ALL.iter().copied().find(|r| r.name() == t.rule)).collect()
}

/// The accuracy pass as the compile step's chooser ([`crate::FormulaChooser`]).
#[derive(Clone, Copy, Debug, Default)]
pub(crate) struct Chooser(pub PassOptions);

impl crate::FormulaChooser for Chooser {
    fn choose(&self, original: &Formula, bake: &[(usize, f64)], simplified: Formula) -> Formula {
        let out = improve(original, bake, &self.0);
        if out.trials.iter().any(|t| t.kept) {
            out.formula
        } else {
            simplified
        }
    }
}

/// Compile options with the accuracy pass on.
pub fn with_pass(mut opts: crate::Options, pass: PassOptions) -> crate::Options {
    let pass = PassOptions { math: opts.math, ..pass };
    opts.accuracy = Some(std::sync::Arc::new(Chooser(pass)));
    opts
}

/// The check command's JSON report (keys listed in docs/commands.md; numbers follow [`crate::base::json`]): the formula, its
/// simplification, the builtins' bounds, the pass's [`Outcome`] (the error after the pass at the top level,
/// `before` for the plain simplification), and the compile times. The caller fills it; the error statistics
/// come from [`ErrorStatsJson::new`].
#[derive(Clone, Debug, serde::Serialize)]
pub struct CheckReport {
    pub file: String,
    pub name: String,
    pub citation: Option<String>,
    /// `null`, or `"red"` for a colour formula (its red channel is checked).
    pub channel: Option<&'static str>,
    pub params: Vec<ParamJson>,
    pub formula: String,
    pub simplified: String,
    pub nodes_before: usize,
    pub nodes_after: usize,
    pub rewrites: Vec<RewriteCount>,
    pub rounding_changes: Vec<RoundingJson>,
    pub passes: usize,
    pub used_inputs: Vec<&'static str>,
    pub unused_inputs: Vec<&'static str>,
    pub math: &'static str,
    pub builtins: Vec<BuiltinBound>,
    pub points: usize,
    #[serde(flatten)]
    pub after: ErrorStatsJson,
    #[serde(serialize_with = "json::opt_num")]
    pub condition_ulps_at_worst_well_conditioned: Option<f64>,
    pub before: ErrorStatsJson,
    pub accuracy_rewrites: Vec<TrialJson>,
    pub compiled: String,
    #[serde(serialize_with = "json::num")]
    pub cost_ratio: f64,
    pub compile_us: CompileUs,
}

/// A declared parameter: its range, its baked value (`null` when live or unused) and whether code reads it.
#[derive(Clone, Debug, serde::Serialize)]
pub struct ParamJson {
    pub name: String,
    #[serde(serialize_with = "json::num")]
    pub default: f64,
    #[serde(serialize_with = "json::num")]
    pub lo: f64,
    #[serde(serialize_with = "json::num")]
    pub hi: f64,
    #[serde(serialize_with = "json::opt_num")]
    pub baked: Option<f64>,
    pub live: bool,
}

#[derive(Clone, Debug, serde::Serialize)]
pub struct RewriteCount {
    pub rule: &'static str,
    pub count: usize,
}

/// A simplification that changed rounding, at a line and column of the source.
#[derive(Clone, Debug, serde::Serialize)]
pub struct RoundingJson {
    pub rule: &'static str,
    pub line: usize,
    pub col: usize,
    pub detail: String,
}

#[derive(Clone, Debug, serde::Serialize)]
pub struct BuiltinBound {
    pub name: &'static str,
    pub bound: String,
}

/// Compile times in µs.
#[derive(Clone, Debug, serde::Serialize)]
pub struct CompileUs {
    #[serde(serialize_with = "json::num")]
    pub jit: f64,
    #[serde(serialize_with = "json::num")]
    pub interp: f64,
}

/// [`ErrorStats`] in a report.
#[derive(Clone, Debug, serde::Serialize)]
pub struct ErrorStatsJson {
    #[serde(serialize_with = "json::num")]
    pub bits_error_avg: f64,
    #[serde(serialize_with = "json::num")]
    pub bits_error_max: f64,
    pub bits_error_worst: Option<WorstJson>,
    #[serde(serialize_with = "json::num")]
    pub bits_error_max_well_conditioned: f64,
    pub bits_error_worst_well_conditioned: Option<WorstJson>,
    pub nonfinite_where_finite: usize,
    pub ill_conditioned: usize,
    pub undefined: usize,
    pub limit_points: usize,
}

/// A [`Worst`] point: the inputs `f` reads and every parameter, by name.
#[derive(Clone, Debug, serde::Serialize)]
pub struct WorstJson {
    pub inputs: Named,
    pub params: Named,
    #[serde(serialize_with = "json::num")]
    pub value: f64,
    #[serde(serialize_with = "json::num")]
    pub truth: f64,
    #[serde(serialize_with = "json::num")]
    pub bits: f64,
}

impl WorstJson {
    pub(crate) fn new(f: &Formula, w: &Worst) -> WorstJson {
        WorstJson {
            inputs: Named::new(f.used_inputs().iter().map(|i| (i.name(), w.point.x[i.index()]))),
            params: Named::new(f.params.iter().zip(&w.point.p).map(|(d, v)| (d.name.as_str(), *v))),
            value: w.got,
            truth: w.truth,
            bits: w.bits,
        }
    }
}

impl ErrorStatsJson {
    /// The statistics of formula `f` (which names the worst points' inputs and parameters).
    pub fn new(f: &Formula, s: &ErrorStats) -> ErrorStatsJson {
        ErrorStatsJson {
            bits_error_avg: s.avg_bits,
            bits_error_max: s.max_bits,
            bits_error_worst: s.worst.as_ref().map(|w| WorstJson::new(f, w)),
            bits_error_max_well_conditioned: s.max_bits_well,
            bits_error_worst_well_conditioned: s.worst_well.as_ref().map(|w| WorstJson::new(f, w)),
            nonfinite_where_finite: s.nonfinite,
            ill_conditioned: s.ill_conditioned,
            undefined: s.undefined,
            limit_points: s.limits,
        }
    }
}

/// One [`Trial`] of the pass: its cost relative to the plain simplification's and its error.
#[derive(Clone, Debug, serde::Serialize)]
pub struct TrialJson {
    pub rule: &'static str,
    pub kept: bool,
    pub reason: String,
    #[serde(serialize_with = "json::num")]
    pub cost_ratio: f64,
    #[serde(serialize_with = "json::num")]
    pub bits_error_avg: f64,
    #[serde(serialize_with = "json::num")]
    pub bits_error_max: f64,
    pub nonfinite_where_finite: usize,
}

impl TrialJson {
    /// The pass's trials.
    pub fn all(pass: &Outcome) -> Vec<TrialJson> {
        pass.trials
            .iter()
            .map(|t| TrialJson {
                rule: t.rule,
                kept: t.kept,
                reason: t.reason.clone(),
                cost_ratio: t.cost / pass.cost_before,
                bits_error_avg: t.stats.avg_bits,
                bits_error_max: t.stats.max_bits,
                nonfinite_where_finite: t.stats.nonfinite,
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn direction_formulas_are_sampled_on_real_geometry() {
        use crate::ir::{BinOp, Ir, Meta, ParamDecl};
        let mut ir = Ir::new();
        let s = crate::base::span::Span::default();
        let (lx, vy) = (ir.input(Input::Lx, s), ir.input(Input::Vy, s));
        let root = ir.bin(BinOp::Mul, lx, vy, s);
        let f = Formula { meta: Meta::default(), params: vec![ParamDecl::float("n", 1.0, 1.0, 1.0)], ir, root, file: "t".into(), source: String::new(), rgb: None };
        let pts = sample(&f, &[], 4000, 7);
        let (mut horizon, mut normal, mut axis) = (0, 0, 0);
        for p in &pts {
            let (l, v) = ([p.x[5], p.x[6], p.x[7]], [p.x[8], p.x[9], p.x[10]]);
            assert!((super::super::dot(l, l) - 1.0).abs() < 1e-15 && (super::super::dot(v, v) - 1.0).abs() < 1e-15, "{p:?}");
            assert!(l[2] >= 0.0 && v[2] >= 0.0);
            assert_eq!(p.x, super::super::inputs_from_dirs(l, v), "every input from the same pair");
            horizon += usize::from(l[2] == 0.0);
            normal += usize::from(l[2] == 1.0);
            axis += usize::from(l[1] == 0.0 && l[2] < 1.0);
        }
        assert!(horizon > 10 && normal > 10 && axis > 10, "{horizon} {normal} {axis}");
    }

    #[test]
    fn ulps_and_bits() {
        assert_eq!(ulps(1.0, 1.0), 0.0);
        assert_eq!(ulps(1.0, 1.0f64.next_up()), 1.0);
        assert_eq!(ulps(-0.0, 0.0), 0.0);
        assert_eq!(ulps(5e-324, -5e-324), 2.0);
        assert_eq!(bits(f64::NAN, 1.0), 64.0);
        assert_eq!(bits(2.0, 2.0f64.next_up().next_up().next_up()), 2.0);
    }
}
