//! Measuring a candidate against the truth on the sample's points: the truth and its condition at each point
//! ([`Reference`], computed once per search), a candidate's values (JIT-compiled or interpreted) and their
//! statistics.

use super::metric::{bits, ulps, ErrorStats, Worst, ILL_CONDITIONED_ULPS, TARGET_BITS};
use super::sample::Point;
use crate::backend::interp::Interp;
use crate::backend::Evaluator;
use crate::ir::Formula;
use crate::base::cancel::Cancel;
use crate::numerics::truth;
use rayon::prelude::*;

/// How many ulps the truth moves when one read input moves by one ulp (the larger of the two directions); a
/// finite-difference condition number in ulps. Parameters are not perturbed: a parameter's value reaches the
/// kernel exactly as given (a baked one is a constant, a live one an argument), so where the formula is
/// sensitive to it (F_ST's n/a·(c − 1) + 1 at n = a) the kernel must still be accurate.
pub fn condition_ulps(truth_f: &Formula, pt: &Point, t: f64) -> f64 {
    condition_ulps_with(truth_f, &truth::Readers::new(truth_f), pt, t)
}

/// [`condition_ulps`] with the formula's [`truth::Readers`] built beforehand (once per formula, not per point).
fn condition_ulps_with(truth_f: &Formula, readers: &truth::Readers, pt: &Point, t: f64) -> f64 {
    use truth::Move;
    // Each read input and each live parameter the formula reads, one ulp either way (a parameter is an input
    // of the function too: where a 1-ulp change of n moves the value by millions of ulps, so does the rounding
    // of any expression of n).
    let inputs = readers.used.iter().map(|i| (i.index(), pt.x[i.index()])).filter(|&(_, v)| v != 0.0).flat_map(|(i, v)| [Move::Input(i, v.next_up()), Move::Input(i, v.next_down())]);
    let params = readers
        .params()
        .filter_map(|p| pt.p.get(p).map(|&v| (p, v)))
        .filter(|&(_, v)| v != 0.0 && v.is_finite())
        .flat_map(|(p, v)| [Move::Param(p, v.next_up()), Move::Param(p, v.next_down())]);
    let moves: Vec<Move> = inputs.chain(params).collect();
    let values = truth::eval_moves_with(truth_f, readers, &pt.x, &pt.p, &moves);
    let mut worst: f64 = 0.0;
    for (&m, mut u) in moves.iter().zip(values) {
        // At a limit point its neighbours along the other inputs are limits too.
        if u.is_nan() {
            let (mut x, mut p) = (pt.x, pt.p.clone());
            match m {
                Move::Input(i, w) => x[i] = w,
                Move::Param(i, w) => p[i] = w,
            }
            u = truth::limit(truth_f, &x, &p).unwrap_or(u);
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
        Reference::new_until(truth_f, points, &Cancel::never())
    }

    /// [`Reference::new`], polling `stop` between chunks of points: once it trips, the points not yet reached
    /// hold NaN (the caller, whose search is over, reads nothing from them but that it stopped). The truth in
    /// high precision of a large formula at thousands of points is the longest stretch of a search.
    pub(crate) fn new_until(truth_f: &'a Formula, points: Vec<Point>, stop: &Cancel) -> Reference<'a> {
        let not_reached = TruthAt { value: f64::NAN, limit: false };
        let truth = points
            .par_chunks(16)
            .flat_map_iter(|ch| {
                let stopped = stop.is_cancelled();
                ch.iter().map(move |pt| if stopped { not_reached } else { TruthAt::new(truth_f, pt) })
            })
            .collect();
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
    pub(super) fn measure_from(&self, ev: &dyn Evaluator, c: Conditioning, base: Option<&[f64]>) -> (ErrorStats, Vec<f64>) {
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
        // A wrong sign counts where the value is well conditioned: where a 1-ulp move of an input moves it by more
        // than 16 ulps, a value near a zero crossing may take either sign (a direction formula's 1 − H·L is
        // −1e-202 where L is a few ulps from unit length).
        if ((got < 0.0 && t.is_sign_positive()) || (got > 0.0 && t.is_sign_negative())) && r.cond(i) <= ILL_CONDITIONED_ULPS {
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

/// Points from which a measurement compiles the candidate with the JIT rather than interpreting it: the JIT
/// computes the interpreter's values bit for bit (the differential tests) at a tenth or less of its time per
/// point, and its compile time (~10 µs per node) is repaid from a few thousand points.
pub(super) const JIT_FROM_POINTS: usize = 4096;

/// The evaluator a measurement of `f` on `points` points runs: the JIT from [`JIT_FROM_POINTS`] (uncached: a
/// candidate is measured once, and must not push the user's kernels out of the cache), the interpreter below
/// that or if compiling fails.
pub(super) fn measurer(f: &Formula, mode: crate::Mode, points: usize) -> Box<dyn Evaluator> {
    if points >= JIT_FROM_POINTS {
        if let Ok(k) = crate::backend::jit::jit_kernel_uncached(f, mode) {
            return Box::new(k);
        }
    }
    Box::new(Interp::with_mode(f, mode))
}
