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
//! lobe builds): each candidate ([`Cand`]: a rule of `simplify::accuracy` at a site, or a whole-formula form) is
//! built from the current best, measured on the same points against the same truth, and kept when more accurate (`better`) —
//! the invariants first (no more NaN/∞ where the truth is finite, missed poles or wrong signs), no point taken
//! beyond [`TARGET_BITS`] where it was within it unless ten times as many are fixed, then fewer well-conditioned
//! points beyond the target, a lower maximum, fewer points near the target, a lower average — and within the
//! cost budget (`simplify::accuracy::cost`): [`Prefer::Speed`] keeps only rewrites that cost nothing,
//! [`Prefer::Accuracy`] (default) those within `max_cost` (1.3) × the fastest form's cost, up to
//! [`NONFINITE_BUDGET`] (2×) for a rewrite that keeps lobe's promise at more points (`keeps_promise`), and up
//! to the pow calls' cost for compensated power chains. A rule applied everywhere that was dropped as no more
//! accurate is tried once more after a later rule was kept (two defects at the same points each hide the other's
//! fix). Every candidate keeps the formula's sign where range analysis of the formula as written bounds it
//! ([`crate::simplify::keep_sign`]). The search stops at [`PassOptions::budget`] with the best form so far.
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
//! which gives the interpreter's bits, from [`JIT_FROM_POINTS`] points; interpreted below), and the condition
//! (two truth evaluations per read input, re-evaluating only the nodes that read it) once per point where some
//! candidate is more than [`TARGET_BITS`] off, or everywhere for the report ([`Conditioning::Everywhere`]);
//! parallel over points (rayon). On one core: 3–65 ms per catalogue formula, up to ~265 ms for BRDF Explorer's
//! largest files, and 6 s for `lobe check`'s 10⁵ points on the largest
//! (BENCHMARKS.md, the `pass` bench).

use crate::base::cancel::Cancel;
use super::truth;
use crate::base::json::{self, Named};
use crate::base::rng::Rng;
use crate::backend::interp::Interp;
use crate::backend::Evaluator;
use crate::ir::{Formula, Input, ParamKind, N_INPUTS};
use crate::simplify::accuracy::{compensated_params, compensated_powers, cost, pow_call_policy, Rule};
use crate::simplify::rewrite::Analysis;
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


/// Values of each parameter where the formula changes character, so the pass measures there: where a
/// parameter times a constant is 1 or a parameter minus a constant is 0 (the quadratic model's 0.786·n = 1,
/// where its linear term vanishes), where a parameter divided by a constant is 1, and the integers 1 and 2
/// where a parameter is an exponent (a baked pow(x, 1) or pow(x, 2) folds away). Only values inside the
/// declared range; a pair of parameters equal to each other (F_ST's n = a) is drawn by [`sample`] itself.
pub fn special_values(f: &Formula) -> Vec<Vec<f64>> {
    use crate::builtins::Builtin;
    use crate::ir::{BinOp, Node};
    let mut out = vec![Vec::new(); f.params.len()];
    let param = |x| match *f.ir.node(x) {
        Node::Param(k) => Some(k as usize),
        _ => None,
    };
    let konst = |x| f.ir.node(x).as_const().filter(|c: &f64| c.is_finite() && *c != 0.0);
    for id in f.ir.ids() {
        let found: Vec<(usize, f64)> = match *f.ir.node(id) {
            Node::Binary(BinOp::Mul, a, b) => [(a, b), (b, a)].iter().filter_map(|&(p, k)| Some((param(p)?, 1.0 / konst(k)?))).collect(),
            Node::Binary(BinOp::Div, a, b) => [(a, b), (b, a)].iter().filter_map(|&(p, k)| Some((param(p)?, konst(k)?))).collect(),
            Node::Binary(BinOp::Sub, a, b) => [(a, b), (b, a)].iter().filter_map(|&(p, k)| Some((param(p)?, konst(k)?))).collect(),
            Node::Binary(BinOp::Add, a, b) => [(a, b), (b, a)].iter().filter_map(|&(p, k)| Some((param(p)?, -konst(k)?))).collect(),
            Node::Call(Builtin::Pow, [_, y, _]) => param(y).map(|k| vec![(k, 1.0), (k, 2.0)]).unwrap_or_default(),
            _ => vec![],
        };
        for (k, v) in found {
            let d = &f.params[k];
            if d.kind == ParamKind::Float && v > d.lo && v < d.hi && !out[k].contains(&v) {
                out[k].push(v);
            }
        }
    }
    out
}

/// One parameter value: a bool is 0 or 1; otherwise an endpoint, a special value ([`special_values`]), uniform
/// or log-uniform in the declared range. Draws the same count of random numbers whatever the outcome.
fn param_value(d: &crate::ir::ParamDecl, special: &[f64], r: &mut Rng) -> f64 {
    let (u, v) = (r.unit(), r.unit());
    if d.kind == ParamKind::Bool {
        return if u < 0.5 { 0.0 } else { 1.0 };
    }
    let val = if u < 0.15 {
        d.lo
    } else if u < 0.3 {
        d.hi
    } else if u < 0.45 && !special.is_empty() {
        special[((v * special.len() as f64) as usize).min(special.len() - 1)]
    } else if u < 0.7 || d.lo <= 0.0 {
        d.lo + v * (d.hi - d.lo)
    } else {
        d.lo * (d.hi / d.lo).powf(v)
    };
    val.clamp(d.lo, d.hi)
}

/// `n` points of `f`'s domain (module docs); parameters listed in `bake` keep their baked value.
pub fn sample(f: &Formula, bake: &[(usize, f64)], n: usize, seed: u64) -> Vec<Point> {
    let mut r = Rng(seed.max(1));
    let used = f.used_inputs();
    let special = special_values(f);
    let floats: Vec<usize> = (0..f.params.len()).filter(|&k| f.params[k].kind == ParamKind::Float).collect();
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
            // Drawn even when baked, so baking a parameter leaves every other value of the sample as it was (and
            // the pass measures a baked and a live compile on the same points).
            let mut p: Vec<f64> = f.params.iter().enumerate().map(|(k, d)| param_value(d, &special[k], &mut r)).collect();
            // A tenth of the points set one float parameter equal to another (F_ST's n = a, where its base
            // cancels to the cosine itself), when that value lies in its range.
            for &(k, v) in bake {
                p[k] = v;
            }
            let (u, i, j) = (r.unit(), r.below(floats.len().max(1) as u64) as usize, r.below(floats.len().max(1) as u64) as usize);
            if u < 0.1 && floats.len() >= 2 && i != j {
                let (i, j) = (floats[i], floats[j]);
                let d = &f.params[j];
                if (d.lo..=d.hi).contains(&p[i]) && !bake.iter().any(|(k, _)| *k == j) {
                    p[j] = p[i];
                }
            }
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
    /// Mean bits over the points where the truth is finite.
    pub avg_bits: f64,
    pub max_bits: f64,
    pub worst: Option<Worst>,
    /// NaN or ±∞ where the true value is finite.
    pub nonfinite: usize,
    pub first_nonfinite: Option<Worst>,
    /// The truth itself is NaN (0/0, ∞·0, ∞−∞ in exact arithmetic) and has no limit along an edge input
    /// ([`truth::limit`]): left out of the averages, as Herbie samples only points with a defined truth.
    pub undefined: usize,
    /// The exact value is not finite but its limit along an input exactly on an edge is ([`truth::limit`]):
    /// counted like any point, with the limit as the truth (Cook–Torrance's G/(NL·NV) at NL = 0).
    pub limits: usize,
    /// The exact value is +∞ or −∞ (a pole: Ward's 1/√(NL·NV) at NL = 0 with a finite numerator): left out of
    /// the averages; the result must be that infinity.
    pub poles: usize,
    /// Poles where the result is not the exact infinity (0 or a finite number or NaN).
    pub pole_misses: usize,
    pub first_pole_miss: Option<Worst>,
    /// The result is below 0 where the truth is ≥ +0, or above 0 where it is ≤ −0.
    pub wrong_sign: usize,
    pub first_wrong_sign: Option<Worst>,
    /// Points where the formula is ill-conditioned by nature (module docs). Exact when the conditioning was
    /// measured everywhere ([`Conditioning::Everywhere`]); otherwise only points with more than
    /// [`TARGET_BITS`] of error are examined, and the others count as well conditioned.
    pub ill_conditioned: usize,
    /// Well-conditioned points with more than [`TARGET_BITS`] of error.
    pub over_target: usize,
    /// Against the formula a candidate would replace: well-conditioned points it takes beyond [`TARGET_BITS`]
    /// and more than a bit worse (0 for a measurement without a base).
    pub regressions: usize,
    /// Points with more than [`TARGET_BITS`] − 1 bits of error (conditioning not examined below the target):
    /// the points a denser sample may push over it.
    pub near_target: usize,
    /// Largest bits of error at a well-conditioned point, and the point.
    pub max_bits_well: f64,
    pub worst_well: Option<Worst>,
    /// The condition (ulps, [`condition_ulps`]) at `worst_well`, when it was measured there.
    pub condition_at_worst_well: Option<f64>,
}

impl ErrorStats {
    /// The wrong answers, as opposed to imprecise ones: NaN/∞ where the truth is finite, missed poles, results
    /// of the wrong sign, well-conditioned points beyond [`TARGET_BITS`] (in that order; the first three are
    /// the invariants no rewrite may trade).
    fn wrong_answers(&self) -> [usize; 4] {
        [self.nonfinite, self.pole_misses, self.wrong_sign, self.over_target]
    }
}

/// How many ulps the truth moves when one read input moves by one ulp (the larger of the two directions); a
/// finite-difference condition number in ulps. Parameters are not perturbed: a parameter's value reaches the
/// kernel exactly as given (a baked one is a constant, a live one an argument), so where the formula is
/// sensitive to it (F_ST's n/a·(c − 1) + 1 at n = a) the kernel must still be accurate.
pub fn condition_ulps(truth_f: &Formula, pt: &Point, t: f64) -> f64 {
    condition_ulps_with(truth_f, &truth::Readers::new(truth_f), pt, t)
}

/// [`condition_ulps`] with the formula's [`truth::Readers`] built beforehand (once per formula, not per point).
fn condition_ulps_with(truth_f: &Formula, readers: &truth::Readers, pt: &Point, t: f64) -> f64 {
    let moves: Vec<(usize, f64)> = readers
        .used
        .iter()
        .map(|i| (i.index(), pt.x[i.index()]))
        .filter(|&(_, v)| v != 0.0)
        .flat_map(|(i, v)| [(i, v.next_up()), (i, v.next_down())])
        .collect();
    let values = truth::eval_moves_with(truth_f, readers, &pt.x, &pt.p, &moves);
    let mut worst: f64 = 0.0;
    for (&(i, w), mut u) in moves.iter().zip(values) {
        // At a limit point its neighbours along the other inputs are limits too.
        if u.is_nan() {
            let mut x = pt.x;
            x[i] = w;
            u = truth::limit(truth_f, &x, &pt.p).unwrap_or(u);
        }
        if !u.is_nan() {
            worst = worst.max(ulps(u, t));
        }
    }
    worst
}

/// The truth at one point rounded to f64 ([`truth::eval`]), or where that is NaN (0/0, ∞·0) the limit along an
/// edge input when there is one ([`truth::limit`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct TruthAt {
    pub value: f64,
    pub limit: bool,
}

impl TruthAt {
    pub(crate) fn new(truth_f: &Formula, pt: &Point) -> TruthAt {
        let value = truth::eval(truth_f, &pt.x, &pt.p);
        // A pole (±∞) is the value, not a limit to look for: only 0/0-like points (NaN) get one.
        if !value.is_nan() {
            return TruthAt { value, limit: false };
        }
        match truth::limit(truth_f, &pt.x, &pt.p) {
            Some(l) => TruthAt { value: l, limit: true },
            None => TruthAt { value, limit: false },
        }
    }
}

/// Where the condition of the truth is measured.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Conditioning {
    /// Only at points with more than [`TARGET_BITS`] of error: enough to rank candidates (a point within the
    /// target cannot raise a maximum above it), and cheap.
    #[default]
    WhereInaccurate,
    /// At every point (two truth evaluations per read input and live parameter): the honest report.
    Everywhere,
}

/// What every candidate is measured against: the points, the truth at each, and the truth's condition at each,
/// computed the first time a measurement needs it and kept (it depends on the point, not on the candidate).
pub struct Reference<'a> {
    truth_f: &'a Formula,
    points: Vec<Point>,
    truth: Vec<TruthAt>,
    cond: Vec<std::sync::OnceLock<f64>>,
    readers: truth::Readers,
}

impl<'a> Reference<'a> {
    /// The truth of `truth_f` (the formula as written, baked values folded) at `points`, in parallel.
    pub fn new(truth_f: &'a Formula, points: Vec<Point>) -> Reference<'a> {
        let truth = points.par_iter().map(|pt| TruthAt::new(truth_f, pt)).collect();
        let cond = (0..points.len()).map(|_| std::sync::OnceLock::new()).collect();
        Reference { truth_f, points, truth, cond, readers: truth::Readers::new(truth_f) }
    }

    pub fn points(&self) -> &[Point] {
        &self.points
    }

    fn cond(&self, i: usize) -> f64 {
        *self.cond[i].get_or_init(|| condition_ulps_with(self.truth_f, &self.readers, &self.points[i], self.truth[i].value))
    }

    /// Bits of error of `ev` at every point, in parallel.
    pub fn measure(&self, ev: &dyn Evaluator, c: Conditioning) -> ErrorStats {
        self.measure_from(ev, c, None).0
    }

    /// [`Reference::measure`], with the value at each point, and the regressions against `base`'s values (a
    /// previous measurement's): well-conditioned points where `ev` is beyond [`TARGET_BITS`] and more than a bit
    /// worse than `base` was.
    fn measure_from(&self, ev: &dyn Evaluator, c: Conditioning, base: Option<&[f64]>) -> (ErrorStats, Vec<f64>) {
        let got: Vec<f64> = self.points.par_iter().map(|p| ev.eval(&p.x, &p.p)).collect();
        let idx: Vec<usize> = (0..self.points.len()).collect();
        let acc = idx.par_chunks(256).map(|ch| ch.iter().fold(Acc::default(), |a, &i| a.add(self, i, got[i], c))).reduce(Acc::default, Acc::merge);
        let mut s = acc.stats;
        s.avg_bits = if acc.defined > 0 { acc.sum / acc.defined as f64 } else { 0.0 };
        if let Some(base) = base {
            s.regressions = idx
                .par_iter()
                .filter(|&&i| {
                    let t = self.truth[i].value;
                    let b = bits(got[i], t);
                    t.is_finite() && b > TARGET_BITS && b > bits(base[i], t) + 1.0 && self.cond(i) <= ILL_CONDITIONED_ULPS
                })
                .count();
        }
        (s, got)
    }
}

#[derive(Default)]
struct Acc {
    stats: ErrorStats,
    sum: f64,
    defined: usize,
}

/// Keeps the first example of a count (in point order, merged in order).
fn first(slot: &mut Option<Worst>, w: impl FnOnce() -> Worst) {
    if slot.is_none() {
        *slot = Some(w());
    }
}

impl Acc {
    fn add(mut self, r: &Reference, i: usize, got: f64, c: Conditioning) -> Acc {
        self.stats.points += 1;
        let (pt, ta) = (&r.points[i], r.truth[i]);
        let t = ta.value;
        let w = |b: f64| Worst { point: pt.clone(), got, truth: t, bits: b };
        if t.is_nan() {
            self.stats.undefined += 1;
            return self;
        }
        if t.is_infinite() {
            self.stats.poles += 1;
            if got != t {
                self.stats.pole_misses += 1;
                first(&mut self.stats.first_pole_miss, || w(64.0));
            }
            return self;
        }
        self.stats.limits += usize::from(ta.limit);
        let b = bits(got, t);
        if !got.is_finite() {
            self.stats.nonfinite += 1;
            first(&mut self.stats.first_nonfinite, || w(b));
        }
        if (got < 0.0 && t.is_sign_positive()) || (got > 0.0 && t.is_sign_negative()) {
            self.stats.wrong_sign += 1;
            first(&mut self.stats.first_wrong_sign, || w(b));
        }
        self.defined += 1;
        self.sum += b;
        if b > self.stats.max_bits || self.stats.worst.is_none() {
            self.stats.max_bits = b;
            self.stats.worst = Some(w(b));
        }
        self.stats.near_target += usize::from(b > TARGET_BITS - 1.0);
        let kappa = (c == Conditioning::Everywhere || b > TARGET_BITS).then(|| r.cond(i));
        if kappa.is_some_and(|k| k > ILL_CONDITIONED_ULPS) {
            self.stats.ill_conditioned += 1;
        } else {
            self.stats.over_target += usize::from(b > TARGET_BITS);
            if b > self.stats.max_bits_well || self.stats.worst_well.is_none() {
                self.stats.max_bits_well = b;
                self.stats.worst_well = Some(w(b));
                self.stats.condition_at_worst_well = kappa;
            }
        }
        self
    }

    fn merge(mut self, o: Acc) -> Acc {
        let (a, b) = (&mut self.stats, o.stats);
        a.points += b.points;
        a.nonfinite += b.nonfinite;
        a.undefined += b.undefined;
        a.limits += b.limits;
        a.poles += b.poles;
        a.pole_misses += b.pole_misses;
        a.wrong_sign += b.wrong_sign;
        a.ill_conditioned += b.ill_conditioned;
        a.over_target += b.over_target;
        a.near_target += b.near_target;
        for (x, y) in [(&mut a.first_nonfinite, b.first_nonfinite), (&mut a.first_pole_miss, b.first_pole_miss), (&mut a.first_wrong_sign, b.first_wrong_sign)] {
            if x.is_none() {
                *x = y;
            }
        }
        if b.worst.is_some() && (a.worst.is_none() || b.max_bits > a.max_bits) {
            a.max_bits = b.max_bits;
            a.worst = b.worst;
        }
        if b.worst_well.is_some() && (a.worst_well.is_none() || b.max_bits_well > a.max_bits_well) {
            a.max_bits_well = b.max_bits_well;
            a.worst_well = b.worst_well;
            a.condition_at_worst_well = b.condition_at_worst_well;
        }
        self.sum += o.sum;
        self.defined += o.defined;
        self
    }
}

/// Bits of error of `ev` against the truth of `truth_f` (the formula as written, baked values folded) at
/// `points`, the conditioning measured everywhere; in parallel.
pub fn measure(ev: &dyn Evaluator, truth_f: &Formula, points: &[Point]) -> ErrorStats {
    Reference::new(truth_f, points.to_vec()).measure(ev, Conditioning::Everywhere)
}


/// What to optimise for: speed or accuracy.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
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

/// The search budget of commands that compile a formula to use it (`eval`, `render`, `energy`, the page's
/// renders): small, so the first command on a new file answers quickly; the decision cache makes the second free.
pub(crate) const COMMAND_BUDGET: std::time::Duration = std::time::Duration::from_secs(2);

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
    /// Wall-clock time after which the search stops and keeps the best candidate so far ([`Outcome::truncated`]
    /// says so). The measuring of one candidate is not interrupted.
    pub budget: std::time::Duration,
    /// Where the condition of the truth is measured for the report of the chosen formula (the search itself
    /// always measures it only where it matters).
    pub conditioning: Conditioning,
}

impl PassOptions {
    /// The static cost a rewrite may reach, the fastest form costing `cost_before`: itself under
    /// [`Prefer::Speed`], `max_cost` × it under [`Prefer::Accuracy`].
    fn budget_for(&self, cost_before: f64) -> f64 {
        match self.prefer {
            Prefer::Speed => cost_before,
            Prefer::Accuracy => self.max_cost * cost_before,
        }
    }
}

impl Default for PassOptions {
    fn default() -> PassOptions {
        PassOptions {
            prefer: Prefer::Accuracy,
            max_cost: 1.3,
            points: 4096,
            seed: 0x5eed_1ab5,
            math: crate::Mode::Precise,
            // A library caller gets the whole search (deterministic); the CLI's compiles set 2 s.
            budget: std::time::Duration::from_secs(600),
            conditioning: Conditioning::WhereInaccurate,
        }
    }
}

/// Most truth work per measurement, in static cost units × points ([`cost`]); a formula above ~200 cost units
/// (40 shared trigonometric `let`s, say) is measured on fewer points than asked, and the report says how many.
pub(crate) const MAX_WORK: f64 = 2e7;

/// A candidate of the pass: one of the simplifier's rules ([`Rule`]) or a whole-formula alternative.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Cand {
    /// Parameter-only subexpressions in double-double, rounded once (`simplify::accuracy::compensated_params`).
    Params,
    /// Integer powers above 8 as pow calls ([`pow_call_policy`]).
    PowCall,
    /// Integer powers above 8 as compensated chains ([`compensated_powers`]).
    CompensatedPower,
    Rule(Rule),
}

impl Cand {
    pub fn name(self) -> &'static str {
        match self {
            Cand::Params => "compensated-params",
            Cand::PowCall => "pow-call",
            Cand::CompensatedPower => "compensated-power",
            Cand::Rule(r) => r.name(),
        }
    }

    pub fn describe(self) -> &'static str {
        match self {
            Cand::Params => "parameter-only subexpressions in double-double, rounded once where the kernel reads them",
            Cand::PowCall => "integer powers above 8 as pow calls instead of multiplication chains",
            Cand::CompensatedPower => "integer powers above 8 as compensated multiplication chains (fma error terms)",
            Cand::Rule(r) => r.describe(),
        }
    }

    /// Rules that go site by site (or variant by variant) rather than everywhere at once.
    fn by_site(self) -> bool {
        matches!(self, Cand::Rule(Rule::QuotientChain | Rule::ScaledExp | Rule::CompensatedSum))
    }

    /// The order of the live search: the whole-formula candidates first (they rebuild from the source), then
    /// the rules.
    /// Parameter-only parts are rewritten first when they call a transcendental builtin (F_kutlog's
    /// C = acos(Q^(1/k))/acos(Q^(1/n))): the rules after it carry those parts' residuals, which exist only once
    /// they are double-double. Otherwise last: the rules' patterns read rational parameter parts as written
    /// (the quadratic model's 1 − A beside A).
    fn order(f: &Formula) -> Vec<Cand> {
        use crate::builtins::Builtin;
        let inv = f.ir.invariant();
        let transcendental = f.ir.ids().any(|id| {
            inv[id.index()] && matches!(f.ir.node(id), crate::ir::Node::Call(b, _) if !matches!(b, Builtin::Min | Builtin::Max | Builtin::Abs | Builtin::Clamp | Builtin::Sqrt | Builtin::Fma | Builtin::Select))
        });
        let mut v = vec![Cand::PowCall, Cand::CompensatedPower];
        if transcendental {
            v.push(Cand::Params);
        }
        v.extend(Rule::ALL.iter().map(|&r| Cand::Rule(r)));
        if !transcendental {
            v.push(Cand::Params);
        }
        v
    }
}

/// Why a trial was kept or dropped.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Verdict {
    Kept,
    /// No more accurate on the sample (or less accurate somewhere it was as accurate before).
    NotBetter,
    /// More accurate, but over the cost budget.
    OverBudget,
}

/// One candidate tried by the pass.
#[derive(Clone, Debug)]
pub struct Trial {
    /// The candidate (`None` for the baked live choice).
    pub cand: Option<Cand>,
    pub rule: &'static str,
    pub describe: &'static str,
    pub kept: bool,
    pub verdict: Verdict,
    /// The site (or variant) of a site-by-site rule.
    pub site: Option<usize>,
    /// Why it was kept or dropped.
    pub reason: String,
    pub stats: ErrorStats,
    pub cost: f64,
}

/// A kept step of the search, enough to rebuild its result without measuring ([`Decision`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Step {
    pub cand: Cand,
    pub site: Option<usize>,
}

/// What the pass decided, replayable without measuring: the live steps in order, and for baked values whether
/// the baked live choice was kept and which power form ended the baked search.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Decision {
    pub live: Vec<Step>,
    pub baked_live_choice: bool,
    pub baked_power: Option<Cand>,
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
    /// The search stopped at [`PassOptions::budget`] with candidates left untried.
    pub truncated: bool,
    pub decision: Decision,
}

/// `a` is more accurate than `b` (module docs). First the invariants no rewrite may trade: no more NaN/∞ where
/// the truth is finite, missed poles or wrong signs (fewer of any is better); then no well-conditioned point
/// newly beyond [`TARGET_BITS`] (fewer is better); then a lower well-conditioned maximum (by half a bit); then,
/// at no higher maximum or average, fewer points near the target or a lower average.
fn better(a: &ErrorStats, b: &ErrorStats) -> bool {
    if !pays_for_regressions(a, b) {
        return false;
    }
    let (ia, ib) = (&a.wrong_answers()[..3], &b.wrong_answers()[..3]);
    if ia.iter().zip(ib).any(|(x, y)| x > y) {
        return false;
    }
    if ia != ib {
        return true;
    }
    if a.over_target != b.over_target {
        return a.over_target < b.over_target && a.max_bits_well <= b.max_bits_well + 0.5;
    }
    better_measured(a, b)
}

/// [`better`] past its invariants: a lower well-conditioned maximum (by half a bit); then, at no higher
/// maximum or average, fewer points near the target or a lower average.
fn better_measured(a: &ErrorStats, b: &ErrorStats) -> bool {
    if a.regressions > 0 || a.over_target > b.over_target {
        return false;
    }
    if a.max_bits_well < b.max_bits_well - 0.5 {
        return true;
    }
    if a.max_bits_well > b.max_bits_well + 0.01 || a.avg_bits > b.avg_bits + 0.01 {
        return false;
    }
    // Fewer points near the target (by a tenth, at least 2): what the sample saw of the worst case is not all
    // of it (F_dsh's rational form: the same maximum on the sample, a lower one on a denser one).
    a.near_target + (b.near_target / 10).max(2) <= b.near_target || a.avg_bits < b.avg_bits - 0.05
}

/// Points `a` gets wrong that `b` got right ([`ErrorStats::regressions`]) are allowed only where `a` fixes ten
/// times as many (NaN/∞, missed poles, wrong signs, well-conditioned points beyond the target): a rewrite must be
/// at least as accurate everywhere it was measured, except where it trades a handful of points for thousands
/// (a quotient chain that ends NaN at every grazing angle but rounds differently at a few facing pairs).
fn pays_for_regressions(a: &ErrorStats, b: &ErrorStats) -> bool {
    let wrong = |s: &ErrorStats| s.wrong_answers().iter().sum::<usize>();
    a.regressions == 0 || wrong(b) >= wrong(a) + 10 * a.regressions
}

/// `a` gets more points right than `b` in the sense of lobe's promise ([`ErrorStats::wrong_answers`]) and none
/// fewer: such a rewrite may cost up to [`NONFINITE_BUDGET`] × the fastest form, since those are wrong answers,
/// not imprecise ones.
fn keeps_promise(a: &ErrorStats, b: &ErrorStats) -> bool {
    if !pays_for_regressions(a, b) {
        return false;
    }
    let (va, vb) = (a.wrong_answers(), b.wrong_answers());
    if !va.iter().zip(&vb).all(|(x, y)| x <= y) {
        return false;
    }
    // A quarter of the points within a bit of the target gone counts too: the sample saw some of the worst
    // case, not all of it (Beckmann at 3.7 bits on 4096 points is 4.1 on 10⁵).
    // And at the target's edge (within a quarter bit of it on the sample), any more accurate form: a denser
    // sample finds points beyond it (Beckmann's 4.00 bits on 4096 points are 4.09 on 10⁵).
    va != vb
        || (b.near_target > 0 && 4 * a.near_target <= 3 * b.near_target && a.max_bits_well <= b.max_bits_well + 0.01)
        || (b.max_bits_well >= TARGET_BITS - 0.25 && better_measured(a, b))
}

/// The candidates of one search, built from its source formula (the formula as written, or the live choice
/// for baked values) and rebuilt from the compensated-params form once that is kept.
struct Candidates<'a> {
    bake: &'a [(usize, f64)],
    sign: crate::simplify::Sign,
    pow_call: Formula,
    compensated: Option<Formula>,
}

impl<'a> Candidates<'a> {
    fn new(src: &Formula, bake: &'a [(usize, f64)], sign: crate::simplify::Sign) -> Candidates<'a> {
        let pow_call = crate::simplify::simplify_with(src, bake, &pow_call_policy()).0;
        let compensated = compensated_powers(&pow_call);
        Candidates { bake, sign, pow_call, compensated }
    }

    fn base(&self, src: &Formula) -> Formula {
        crate::simplify::keep_sign(&self.sign, crate::simplify::simplify(src, self.bake))
    }

    /// The candidate `c` from the current best, analysed once for every candidate built from it (`None`: it
    /// does not apply, or changes nothing).
    fn build(&self, c: Cand, an: &Analysis, site: Option<usize>) -> Option<Formula> {
        let cur = &an.f;
        let g = match c {
            // On the live formula only (a baked one folds what this computes): baked and live agree.
            Cand::Params => compensated_params(cur).map(|g| crate::simplify::simplify(&g, self.bake)),
            Cand::PowCall => Some(self.pow_call.clone()).filter(|p| p.to_program_text() != cur.to_program_text()),
            Cand::CompensatedPower => self.compensated.clone(),
            Cand::Rule(r) => r.apply_in(an, site),
        }?;
        Some(crate::simplify::keep_sign(&self.sign, g))
    }

    fn pow_cost(&self) -> f64 {
        cost(&self.pow_call)
    }
}

/// The live pass's formula from its steps, without measuring (what [`Decision::live`] replays).
fn replay_live(orig: &Formula, steps: &[Step]) -> Formula {
    let sign = crate::simplify::sign_of(orig, &[]);
    let cands = Candidates::new(orig, &[], sign);
    let mut cur = Analysis::new(cands.base(orig));
    for s in steps {
        if let Some(g) = cands.build(s.cand, &cur, s.site) {
            cur = Analysis::new(g);
        }
    }
    cur.f
}

/// The baked formula from a decision, without measuring.
pub fn replay(orig: &Formula, bake: &[(usize, f64)], d: &Decision, prefer: Prefer) -> Formula {
    let bake = read_bake(orig, bake);
    let live = replay_live(orig, &d.live);
    if bake.is_empty() {
        return live;
    }
    let sign = crate::simplify::sign_of(orig, &bake);
    let src = if d.live.is_empty() { orig } else { &live };
    let cands = Candidates::new(if d.baked_live_choice { src } else { orig }, &bake, sign);
    match (d.baked_power, d.baked_live_choice) {
        (Some(c), _) => {
            let base = Analysis::new(cands.base(orig));
            cands.build(c, &base, None).unwrap_or(base.f)
        }
        (None, true) => baked_live(&cands, src, prefer),
        (None, false) => cands.base(orig),
    }
}

/// The baked values the formula reads (a value it never reads changes nothing: the live decision is the whole
/// decision).
fn read_bake(orig: &Formula, bake: &[(usize, f64)]) -> Vec<(usize, f64)> {
    let read = crate::simplify::simplify(orig, &[]);
    let read = read.ir.used_params(read.root);
    bake.iter().copied().filter(|(k, _)| read.contains(&(*k as u16))).collect()
}

/// The measuring half of a search: the reference, the interpreter in the pass's math mode, the budget.
struct Bench<'a> {
    reference: Reference<'a>,
    o: &'a PassOptions,
    /// Trips at the search's time budget ([`PassOptions::budget`]) or when the caller's token does.
    stop: &'a Cancel,
    observe: &'a dyn Fn(Stage),
}

/// What the pass is doing, for a progress display ([`improve_observed`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Stage {
    /// The truth at the sample's points (the first and, with few candidates, the largest part).
    Truth { points: usize },
    /// Measuring a candidate, the `tried`-th of the search.
    Candidate { name: &'static str, tried: usize },
    /// The final report of the chosen form (with the conditioning measured everywhere for `lobe check`).
    Report,
}

impl Bench<'_> {
    /// A candidate's error and values, its regressions against `base`'s values.
    fn run(&self, f: &Formula, base: Option<&[f64]>) -> (ErrorStats, Vec<f64>) {
        self.reference.measure_from(&*measurer(f, self.o.math, self.reference.points.len()), Conditioning::WhereInaccurate, base)
    }

    fn out_of_time(&self) -> bool {
        self.stop.is_cancelled()
    }

    /// The final report of a formula, with the conditioning the options ask for.
    fn report(&self, f: &Formula, s: ErrorStats) -> ErrorStats {
        (self.observe)(Stage::Report);
        match self.o.conditioning {
            Conditioning::WhereInaccurate => s,
            Conditioning::Everywhere => self.reference.measure(&*measurer(f, self.o.math, self.reference.points.len()), Conditioning::Everywhere),
        }
    }
}

/// Points from which a measurement compiles the candidate with the JIT rather than interpreting it: the JIT
/// computes the interpreter's values bit for bit (the differential tests) at a tenth or less of its time per
/// point, and its compile time (~10 µs per node) is repaid from a few thousand points.
const JIT_FROM_POINTS: usize = 4096;

/// The evaluator a measurement of `f` on `points` points runs: the JIT from [`JIT_FROM_POINTS`] (uncached: a
/// candidate is measured once, and must not push the user's kernels out of the cache), the interpreter below
/// that or if compiling fails.
fn measurer(f: &Formula, mode: crate::Mode, points: usize) -> Box<dyn Evaluator> {
    if points >= JIT_FROM_POINTS {
        if let Ok(k) = crate::backend::jit::jit_kernel_uncached(f, mode) {
            return Box::new(k);
        }
    }
    Box::new(Interp::with_mode(f, mode))
}

/// The points a search measures: fewer for a costly kernel, and for a formula whose truth (every node as
/// written, parameter-only ones included, at every point) is far larger than its simplified kernel — an eighth
/// of a cost unit per node, so only such formulas are affected (a 10⁶-node chain that simplifies to `NH`).
fn points_for(base: &Formula, truth_f: &Formula, o: &PassOptions) -> usize {
    let truth_nodes = truth_f.ir.use_counts(truth_f.root).iter().filter(|&&u| u > 0).count() as f64;
    let work = cost(base).max(truth_nodes / 8.0).max(1.0);
    o.points.min((MAX_WORK / work) as usize).max(64)
}

/// The accuracy pass on `orig` with `bake` folded in (module docs).
pub fn improve(orig: &Formula, bake: &[(usize, f64)], o: &PassOptions) -> Outcome {
    improve_observed(orig, bake, o, &|_| {})
}

/// [`improve`], telling `observe` each [`Stage`] as it starts.
pub(crate) fn improve_observed(orig: &Formula, bake: &[(usize, f64)], o: &PassOptions, observe: &dyn Fn(Stage)) -> Outcome {
    improve_cancellable(orig, bake, o, &Cancel::never(), observe)
}

/// [`improve_observed`], also stopping (with the best form so far, [`Outcome::truncated`]) once `cancel` trips:
/// the time budget is a child of the caller's token, so one mechanism stops the search either way.
pub(crate) fn improve_cancellable(orig: &Formula, bake: &[(usize, f64)], o: &PassOptions, cancel: &Cancel, observe: &dyn Fn(Stage)) -> Outcome {
    let stop = cancel.child(o.budget);
    let bake = read_bake(orig, bake);
    let live = live_pass(orig, o, &stop, observe);
    if bake.is_empty() {
        return live;
    }
    baked_pass(orig, &bake, &live, o, &stop, observe)
}

/// The search with every parameter live (module docs).
fn live_pass(orig: &Formula, o: &PassOptions, stop: &Cancel, observe: &dyn Fn(Stage)) -> Outcome {
    let sign = crate::simplify::sign_of(orig, &[]);
    let cands = Candidates::new(orig, &[], sign);
    let base = cands.base(orig);
    let truth_f = crate::simplify::bake_only(orig, &[]);
    let n = points_for(&base, &truth_f, o);
    observe(Stage::Truth { points: n });
    let bench = Bench { reference: Reference::new(&truth_f, sample(orig, &[], n, o.seed)), o, stop, observe };
    let (before, mut cur_got) = bench.run(&base, None);
    let cost_before = cost(&base);
    let base_budget = o.budget_for(cost_before);
    let (mut cur, mut cur_stats, mut cur_cost) = (Analysis::new(base.clone()), before.clone(), cost_before);
    let mut trials: Vec<Trial> = Vec::new();
    let mut steps = Vec::new();
    let mut tries = Cand::order(&base);
    let (mut i, mut k) = (0, 0);
    let mut second_round = false;
    let mut truncated = false;
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
            tries.extend(retry);
            continue;
        }
        if bench.out_of_time() {
            truncated = true;
            break;
        }
        let c = tries[i];
        let site = c.by_site().then_some(k);
        let Some(cand) = cands.build(c, &cur, site) else {
            (i, k) = (i + 1, 0);
            continue;
        };
        if site.is_some() && cand.to_program_text() == cur.f.to_program_text() {
            k += 1;
            continue;
        }
        observe(Stage::Candidate { name: c.name(), tried: trials.len() + 1 });
        let (stats, got) = bench.run(&cand, Some(&cur_got));
        let cost_c = cost(&cand);
        let fixes = keeps_promise(&stats, &cur_stats);
        let budget = match o.prefer {
            Prefer::Accuracy if fixes => base_budget.max(NONFINITE_BUDGET * cost_before),
            // A baked power may cost what the live formula's pow call costs (module docs).
            Prefer::Accuracy if c == Cand::CompensatedPower => base_budget.max(cands.pow_cost()),
            _ => base_budget,
        };
        let verdict = if !better(&stats, &cur_stats) {
            Verdict::NotBetter
        } else if cost_c > budget {
            Verdict::OverBudget
        } else {
            Verdict::Kept
        };
        let mut reason = match verdict {
            Verdict::NotBetter => "no more accurate on the sample".to_string(),
            Verdict::OverBudget => format!("more accurate but costs {:.2}× the fastest form (budget {:.2}×)", cost_c / cost_before, budget / cost_before),
            Verdict::Kept => format!("cost {:.2}× the fastest form", cost_c / cost_before),
        };
        if let Some(s) = site {
            reason = format!("site {}: {reason}", s + 1);
        }
        let kept = verdict == Verdict::Kept;
        trials.push(Trial { cand: Some(c), rule: c.name(), describe: c.describe(), kept, verdict, site, reason, stats: stats.clone(), cost: cost_c });
        if kept {
            steps.push(Step { cand: c, site });
            (cur, cur_stats, cur_cost, cur_got) = (Analysis::new(cand), stats, cost_c, got);
        } else {
            k += 1;
        }
        // One compensated sum at most: its own error terms (2Sum's differences) would be sites next.
        if site.is_none() || (kept && c == Cand::Rule(Rule::CompensatedSum)) {
            (i, k) = (i + 1, 0);
        }
    }
    let before = bench.report(&base, before);
    let after = bench.report(&cur.f, cur_stats);
    let decision = Decision { live: steps, ..Decision::default() };
    Outcome { formula: cur.f, before, after, cost_before, cost_after: cur_cost, trials, points: n, truncated, decision }
}

/// With baked values (module docs: bake-consistent choices): what the live kernel computes, the values folded
/// in — the live choice (or the formula as written when the live pass kept nothing) simplified with integer
/// powers above 8 kept as pow calls, as the live kernel calls pow — kept unless the plain baked form keeps
/// lobe's promise at more points; then the compensated chains of those powers where they are no less accurate
/// and cheaper (within 3 ulp of pow). No other rule is tried, so the baked kernel agrees with the live one.
/// `Prefer::Speed` bakes with the simplifier's own chains (the fastest form).
fn baked_pass(orig: &Formula, bake: &[(usize, f64)], live: &Outcome, o: &PassOptions, stop: &Cancel, observe: &dyn Fn(Stage)) -> Outcome {
    let sign = crate::simplify::sign_of(orig, bake);
    let plain = Candidates::new(orig, bake, sign);
    let base = plain.base(orig);
    let truth_f = crate::simplify::bake_only(orig, bake);
    let n = points_for(&base, &truth_f, o);
    observe(Stage::Truth { points: n });
    let bench = Bench { reference: Reference::new(&truth_f, sample(orig, bake, n, o.seed)), o, stop, observe };
    let (before, mut cur_got) = bench.run(&base, None);
    let cost_before = cost(&base);
    let base_budget = o.budget_for(cost_before);
    let (mut cur, mut cur_stats, mut cur_cost) = (base.clone(), before.clone(), cost_before);
    let mut trials = Vec::new();
    let mut decision = Decision { live: live.decision.live.clone(), ..Decision::default() };
    // The live choice's candidates; the plain ones when the live pass kept nothing (the same source).
    let (src, lc_live) = match live.decision.live.is_empty() {
        true => (orig, None),
        false => (&live.formula, Some(Candidates::new(&live.formula, bake, sign))),
    };
    let lc = lc_live.as_ref().unwrap_or(&plain);
    let cand = baked_live(lc, src, o.prefer);
    if cand.to_program_text() != base.to_program_text() {
        let (stats, got) = bench.run(&cand, None);
        let c = cost(&cand);
        let rules: Vec<&str> = live.decision.live.iter().map(|s| s.cand.name()).collect();
        let rules = if rules.is_empty() { "the formula as written".to_string() } else { rules.join(", ") };
        // Dropped only where the plain baked form keeps the promise at more points (an average or a tail a
        // little better is not worth baked ≠ live), or where it costs more than the live kernel.
        let budget = base_budget.max(live.cost_after).max(cost(&lc.pow_call));
        let (verdict, reason) = if keeps_promise(&before, &stats) {
            (Verdict::NotBetter, format!("{rules}: less accurate than the plain form with these values baked"))
        } else if c > budget {
            (Verdict::OverBudget, format!("{rules}: costs {:.2}× the fastest form (budget {:.2}×)", c / cost_before, budget / cost_before))
        } else {
            (Verdict::Kept, format!("{rules}: cost {:.2}× the fastest form", c / cost_before))
        };
        let kept = verdict == Verdict::Kept;
        trials.push(Trial { cand: None, rule: LIVE_CHOICE, describe: LIVE_CHOICE_DESCRIBE, kept, verdict, site: None, reason, stats: stats.clone(), cost: c });
        if kept {
            (cur, cur_stats, cur_cost, cur_got) = (cand, stats, c, got);
            decision.baked_live_choice = true;
        }
    }
    let mut truncated = false;
    let power = if decision.baked_live_choice { lc } else { &plain };
    if let (Some(cand), true) = (power.build(Cand::CompensatedPower, &Analysis::new(cur.clone()), None), o.prefer == Prefer::Accuracy) {
        if bench.out_of_time() {
            truncated = true;
        } else {
            let c = Cand::CompensatedPower;
            let (stats, _) = bench.run(&cand, Some(&cur_got));
            let cost_c = cost(&cand);
            // In place of pow calls: no less accurate (within a bit) and cheaper; in place of plain chains: more
            // accurate within the pow calls' cost.
            let no_worse = stats.regressions == 0
                && stats.wrong_answers().iter().zip(&cur_stats.wrong_answers()).all(|(x, y)| x <= y)
                && stats.max_bits_well <= cur_stats.max_bits_well.max(TARGET_BITS - 2.0) + 1.0;
            let verdict = if decision.baked_live_choice {
                if no_worse && cost_c < cur_cost { Verdict::Kept } else if no_worse { Verdict::OverBudget } else { Verdict::NotBetter }
            } else if !better(&stats, &cur_stats) {
                Verdict::NotBetter
            } else if cost_c > base_budget.max(cost(&plain.pow_call)) {
                Verdict::OverBudget
            } else {
                Verdict::Kept
            };
            let reason = match verdict {
                Verdict::NotBetter => "less accurate on the sample".to_string(),
                Verdict::OverBudget => format!("costs {:.2}× the fastest form, no less than the form it would replace", cost_c / cost_before),
                Verdict::Kept => format!("cost {:.2}× the fastest form", cost_c / cost_before),
            };
            let kept = verdict == Verdict::Kept;
            trials.push(Trial { cand: Some(c), rule: c.name(), describe: c.describe(), kept, verdict, site: None, reason, stats: stats.clone(), cost: cost_c });
            if kept {
                decision.baked_power = Some(c);
                (cur, cur_stats, cur_cost) = (cand, stats, cost_c);
            }
        }
    }
    let before = bench.report(&base, before);
    let after = bench.report(&cur, cur_stats);
    Outcome { formula: cur, before, after, cost_before, cost_after: cur_cost, trials, points: n, truncated: truncated || live.truncated, decision }
}

/// The baked live choice: `src` (the live formula) simplified with the baked values, integer powers above 8
/// kept as pow calls under `Prefer::Accuracy` (the live kernel calls pow), as the simplifier chains them under
/// `Prefer::Speed`.
fn baked_live(lc: &Candidates, src: &Formula, prefer: Prefer) -> Formula {
    match prefer {
        Prefer::Accuracy => crate::simplify::keep_sign(&lc.sign, lc.pow_call.clone()),
        Prefer::Speed => lc.base(src),
    }
}

/// The first trial of a pass with baked values: the live decision, baked (module docs).
pub const LIVE_CHOICE: &str = "live-choice";
const LIVE_CHOICE_DESCRIBE: &str = "the rewrites chosen with every parameter live, the baked values folded into them: baked and live kernels agree";

/// The rules applied everywhere dropped as no more accurate before the last trial that was kept, in the order
/// they were tried.
fn retries(trials: &[Trial]) -> Vec<Cand> {
    let Some(last_kept) = trials.iter().rposition(|t| t.kept) else { return vec![] };
    trials[..last_kept]
        .iter()
        .filter(|t| t.verdict == Verdict::NotBetter)
        .filter_map(|t| t.cand)
        .filter(|c| matches!(c, Cand::Rule(_)) && !c.by_site())
        .collect()
}


/// The accuracy pass as the compile step's chooser ([`crate::FormulaChooser`]): the decision comes from the
/// cache when it has one for this formula, these baked values and these options, and is stored there after a
/// search.
#[derive(Clone, Debug, Default)]
pub(crate) struct Chooser {
    pass: PassOptions,
    cache: Option<std::sync::Arc<dyn DecisionStore>>,
    /// Stops the search early (the compile then uses the best form so far and stores nothing).
    cancel: Cancel,
}

/// Where decisions are kept between commands ([`super::pass_cache::Cache`] on disk): keyed by the formula, its
/// baked values and the options; a miss or a failed store changes nothing but the time taken.
pub trait DecisionStore: Send + Sync + std::fmt::Debug {
    fn load(&self, f: &Formula, bake: &[(usize, f64)], o: &PassOptions) -> Option<Decision>;
    fn store(&self, f: &Formula, bake: &[(usize, f64)], o: &PassOptions, d: &Decision);
}

impl crate::FormulaChooser for Chooser {
    fn choose(&self, original: &Formula, bake: &[(usize, f64)], simplified: Formula) -> Formula {
        // A decision that keeps nothing compiles the plain simplification, searched or replayed alike (the
        // replay's base may carry a sign clamp the compile step's simplification does not).
        if let Some(d) = self.cache.as_ref().and_then(|c| c.load(original, bake, &self.pass)) {
            return if d == Decision::default() { simplified } else { replay(original, bake, &d, self.pass.prefer) };
        }
        let out = improve_cancellable(original, bake, &self.pass, &self.cancel, &|_| {});
        // A search cut short by the caller is not this formula's decision: the next compile searches again.
        if let Some(c) = self.cache.as_ref().filter(|_| !self.cancel.is_cancelled()) {
            c.store(original, bake, &self.pass, &out.decision);
        }
        if out.decision == Decision::default() {
            simplified
        } else {
            out.formula
        }
    }
}

/// Compile options with the accuracy pass on, no cache.
pub fn with_pass(opts: crate::Options, pass: PassOptions) -> crate::Options {
    with_pass_cached(opts, pass, None)
}

/// Compile options with the accuracy pass on, its decisions kept in `cache` ([`super::pass_cache::Cache::platform`]
/// is the user's cache directory).
pub fn with_pass_cached(opts: crate::Options, pass: PassOptions, cache: Option<std::sync::Arc<dyn DecisionStore>>) -> crate::Options {
    with_pass_until(opts, pass, cache, Cancel::never())
}

/// [`with_pass_cached`] whose searches also stop when `cancel` trips.
pub(crate) fn with_pass_until(mut opts: crate::Options, pass: PassOptions, cache: Option<std::sync::Arc<dyn DecisionStore>>, cancel: Cancel) -> crate::Options {
    let pass = PassOptions { math: opts.math, ..pass };
    opts.accuracy = Some(std::sync::Arc::new(Chooser { pass, cache, cancel }));
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
    /// The search stopped at its time budget.
    pub truncated: bool,
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
    pub poles: usize,
    pub pole_misses: usize,
    pub wrong_sign: usize,
    pub over_target_well_conditioned: usize,
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
            poles: s.poles,
            pole_misses: s.pole_misses,
            wrong_sign: s.wrong_sign,
            over_target_well_conditioned: s.over_target,
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

    /// A formula each rule rewrites, and the site (for rules tried site by site). An exhaustive match: a new
    /// rule does not compile without its example.
    fn example(r: Rule) -> (&'static str, Option<usize>) {
        match r {
            Rule::SplitSqrt => ("1/sqrt(NL*NV)", None),
            Rule::QuotientChain => ("param m = 0.3 in 0.01..1\n1/(m^2 * NH^4) * exp((NH^2 - 1) / (m^2 * NH^2))", Some(0)),
            Rule::FactorQuadratic => ("let c = NH\n0.786*n*c^2 + (1 - 0.786*n)*c", None),
            Rule::CompensatedBase => ("param a = 16 in 1..1000\nmax(n/a*(NH - 1) + 1, 0)^a", None),
            Rule::CompensatedSum => ("let q = -1.1/(n*NH - n - 2*NH)\nq*n*(NH - 1) + 1", Some(2)),
            Rule::ScaledExp => ("param m = 0.3 in 0.01..1\nexp((NH^2 - 1) / (m^2 * NH^2)) / (m*m) / NH^4 / VH / max(NL, NV)", Some(1)),
            Rule::SmithG1 => ("param a = 0.2 in 0.01..1\nlet g = 2/(1 + sqrt(1 + a*a*((1 - NL*NL)/(NL*NL))))\nNL <= 0 ? 0 : g * NH / (4*NL)", None),
            Rule::CancelMin => ("param m = 0.3 in 0.01..1\nlet G = min(1, min(2*NH*NV/VH, 2*NH*NL/VH))\nexp(-NH/m)*G/(3*NL*NV)", None),
            Rule::ScaledNorm => ("let x = Lx + Vx\nlet z = Lz + Vz\nz / sqrt(x*x + z*z)", None),
            Rule::RationalForm => ("let c = NH\nc/(n - n*c + c) - 0.25", None),
            Rule::CompensatedExp => ("exp(-n * NH * NH)", None),
        }
    }

    /// Every rule is exact in real arithmetic (only where f64 rounds changes): on its example, at points of
    /// the formula's domain and random parameter values, the rewritten formula's exact value is the written
    /// one's (the truth evaluator takes rounding-error builtins as 0, as exact arithmetic has them).
    #[test]
    fn every_rule_rewrites_its_example_to_an_equal_formula() {
        for r in Rule::ALL {
            let (src, site) = example(r);
            let f = crate::front::parse("rule.brdf", src).unwrap();
            let plain = crate::simplify::simplify(&f, &[]);
            let g = r.apply_at(&plain, site).unwrap_or_else(|| panic!("{} does not rewrite its example {src:?}", r.name()));
            assert_ne!(g.to_program_text(), plain.to_program_text(), "{}", r.name());
            let mut compared = 0;
            for p in sample(&f, &[], 3000, 11 + r as u64) {
                let (a, b) = (truth::eval(&plain, &p.x, &p.p), truth::eval(&g, &p.x, &p.p));
                if !a.is_finite() || a == 0.0 {
                    continue; // 0/0 or ∞ as written, where a rule may give the limit
                }
                compared += 1;
                assert!((a - b).abs() <= 1e-9 * a.abs(), "{}: {a} vs {b} at {p:?}\n{}", r.name(), g.to_text());
            }
            assert!(compared > 1000, "{}: {compared} points compared", r.name());
        }
    }

    /// The stages a progress display sees: the truth first, each measured candidate in order, the report last;
    /// observing changes nothing.
    #[test]
    fn the_pass_reports_its_stages_in_order() {
        let f = crate::front::parse("b.brdf", "param m = 0.3 in 0.01..1\n1/(m^2 * NH^4) * exp((NH^2 - 1) / (m^2 * NH^2))").unwrap();
        let o = PassOptions { points: 512, ..PassOptions::default() };
        let seen = std::sync::Mutex::new(vec![]);
        let out = improve_observed(&f, &[], &o, &|s| seen.lock().unwrap().push(s));
        let seen = seen.into_inner().unwrap();
        assert_eq!(seen.first(), Some(&Stage::Truth { points: out.points }));
        assert_eq!(seen.last(), Some(&Stage::Report));
        let tried: Vec<usize> = seen.iter().filter_map(|s| if let Stage::Candidate { tried, .. } = s { Some(*tried) } else { None }).collect();
        assert_eq!(tried, (1..=out.trials.len()).collect::<Vec<_>>());
        assert_eq!(out.formula.to_program_text(), improve(&f, &[], &o).formula.to_program_text());
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
