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

/// How many ulps the truth moves when one read input or live parameter moves by one ulp (the larger of the two
/// directions; inputs and parameters at 0 are not moved); a finite-difference condition number in ulps. A
/// parameter is an input of the function too: where a 1-ulp change of n moves the value by millions of ulps,
/// so does the rounding of any expression of n.
pub fn condition_ulps(truth_f: &Formula, pt: &Point, t: f64) -> f64 {
    condition_ulps_with(truth_f, &truth::Readers::new(truth_f), pt, t, u64::MAX, None)
}

/// [`condition_ulps`] with the formula's [`truth::Readers`] built beforehand (once per formula, not per point),
/// over the variables in `only` (bit k: the k-th read input, then the parameters it reads, in the readers'
/// order; bits past 63 always count), from the nodes' exact values at the point when the caller has them.
fn condition_ulps_with(truth_f: &Formula, readers: &truth::Readers, pt: &Point, t: f64, only: u64, base: Option<&[truth::Xf]>) -> f64 {
    use truth::Move;
    let wanted = |k: usize| k >= 64 || only & (1u64 << k) != 0;
    let inputs = readers.used.iter().map(|i| (i.index(), pt.x[i.index()]));
    let params = readers.params().map(|p| (p, pt.p.get(p).copied().unwrap_or(0.0)));
    let n_inputs = readers.used.len();
    let moves: Vec<Move> = inputs
        .enumerate()
        .filter(|&(k, (_, v))| wanted(k) && v != 0.0)
        .flat_map(|(_, (i, v))| [Move::Input(i, v.next_up()), Move::Input(i, v.next_down())])
        .chain(
            params
                .enumerate()
                .filter(|&(k, (_, v))| wanted(n_inputs + k) && v != 0.0 && v.is_finite())
                .flat_map(|(_, (p, v))| [Move::Param(p, v.next_up()), Move::Param(p, v.next_down())]),
        )
        .collect();
    if moves.is_empty() {
        return 0.0;
    }
    let values = match base {
        Some(base) => truth::eval_moves_from(truth_f, readers, base, &pt.x, &pt.p, &moves),
        None => truth::eval_moves_with(truth_f, readers, &pt.x, &pt.p, &moves),
    };
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

/// What the truth's first-order condition ([`truth::Linear`]) decides at a point about [`ILL_CONDITIONED_ULPS`].
#[derive(Clone, Copy, Debug, PartialEq)]
enum FirstOrder {
    /// Some variable the first order describes moves the truth by more than 4 × the threshold.
    Ill,
    /// Well conditioned unless moving these variables exactly (bit k, [`condition_ulps_with`]'s order) says
    /// otherwise: those the first order does not describe, and those whose bounds straddle the threshold;
    /// `Check(0)` is well conditioned.
    Check(u64),
    /// The exact condition over the variables a `Check` named (moved in the same pass as the first order).
    Checked(f64),
    /// Not estimated (a limit point, a formula with more than 64 variables): the exact condition decides.
    Exact,
}

/// The first order's verdict from a [`truth::Estimate`]: a variable it describes decides where its bounds on
/// the exact count lie both above or both at or below the threshold; the others are moved exactly.
fn first_order(e: &truth::Estimate) -> FirstOrder {
    let mut check = e.unsure;
    for (k, &(lo, hi)) in e.ulps.iter().enumerate() {
        if check & (1 << k) != 0 {
            continue;
        }
        if lo > ILL_CONDITIONED_ULPS {
            return FirstOrder::Ill;
        }
        // (A NaN bound checks too.)
        if hi.is_nan() || hi > ILL_CONDITIONED_ULPS {
            check |= 1 << k;
        }
    }
    FirstOrder::Check(check)
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
        TruthAt::from_value(truth_f, pt, truth::eval(truth_f, &pt.x, &pt.p))
    }

    /// From the truth at the point rounded to f64 ([`truth::eval`]'s `value`).
    fn from_value(truth_f: &Formula, pt: &Point, value: f64) -> TruthAt {
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
    /// At every point: the honest report. With a [`Reference::everywhere`], decided by the truth's first-order
    /// condition and its bound, moving exactly only the variables they do not settle ([`FirstOrder`]); with a
    /// [`Reference::new`], two truth evaluations per read input and live parameter at every point.
    Everywhere,
}

/// What every candidate is measured against: the points, the truth at each, and the truth's condition at each,
/// computed the first time a measurement needs it and kept (it depends on the point, not on the candidate).
pub struct Reference<'a> {
    truth_f: &'a Formula,
    points: Vec<Point>,
    truth: Vec<TruthAt>,
    cond: Vec<std::sync::OnceLock<f64>>,
    /// With [`Reference::everywhere`]: the first order's verdict at each point.
    first: Option<Vec<FirstOrder>>,
    readers: truth::Readers,
}

impl<'a> Reference<'a> {
    /// The truth of `truth_f` (the formula as written, baked values folded) at `points`, in parallel.
    pub fn new(truth_f: &'a Formula, points: Vec<Point>) -> Reference<'a> {
        Reference::new_until(truth_f, points, &Cancel::never())
    }

    /// [`Reference::new`] for measuring with [`Conditioning::Everywhere`]: the truth's first-order condition
    /// at every point too ([`truth::Linear`], in the same pass as the truth), so that the exact condition is
    /// computed only where the first order does not settle it.
    pub fn everywhere(truth_f: &'a Formula, points: Vec<Point>) -> Reference<'a> {
        Reference::build(truth_f, points, &Cancel::never(), true)
    }

    /// [`Reference::new`], polling `stop` between chunks of points: once it trips, the points not yet reached
    /// hold NaN (the caller, whose search is over, reads nothing from them but that it stopped). The truth in
    /// high precision of a large formula at thousands of points is the longest stretch of a search.
    pub(crate) fn new_until(truth_f: &'a Formula, points: Vec<Point>, stop: &Cancel) -> Reference<'a> {
        Reference::build(truth_f, points, stop, false)
    }

    fn build(truth_f: &'a Formula, points: Vec<Point>, stop: &Cancel, estimate: bool) -> Reference<'a> {
        let readers = truth::Readers::new(truth_f);
        let linear = if estimate { truth::Linear::new(truth_f, &readers) } else { None };
        let readers_ref = &readers;
        let not_reached = (TruthAt { value: f64::NAN, limit: false }, FirstOrder::Exact);
        let linear = linear.as_ref();
        // The first order's buffers are kept from one point to the next (one set per rayon job).
        let rows: Vec<(TruthAt, FirstOrder)> = points
            .par_chunks(16)
            .map_init(truth::Scratch::default, |scratch, ch| {
                let stopped = stop.is_cancelled();
                ch.iter()
                    .map(|pt| match linear {
                        _ if stopped => not_reached,
                        None => (TruthAt::new(truth_f, pt), FirstOrder::Exact),
                        Some(l) => {
                            let (value, estimate) = l.eval(truth_f, &pt.x, &pt.p, scratch);
                            let at = TruthAt::from_value(truth_f, pt, value);
                            let verdict = match first_order(&estimate) {
                                _ if at.limit || !value.is_finite() => FirstOrder::Exact,
                                FirstOrder::Check(only) if only != 0 => {
                                    FirstOrder::Checked(condition_ulps_with(truth_f, readers_ref, pt, value, only, Some(scratch.values())))
                                }
                                v => v,
                            };
                            (at, verdict)
                        }
                    })
                    .collect::<Vec<_>>()
            })
            .flatten_iter()
            .collect();
        let (truth, first): (Vec<TruthAt>, Vec<FirstOrder>) = rows.into_iter().unzip();
        let cond = (0..points.len()).map(|_| std::sync::OnceLock::new()).collect();
        Reference { truth_f, points, truth, cond, first: estimate.then_some(first), readers }
    }

    pub fn points(&self) -> &[Point] {
        &self.points
    }

    /// The exact condition at point `i` ([`condition_ulps`]).
    fn cond(&self, i: usize) -> f64 {
        *self.cond[i].get_or_init(|| condition_ulps_with(self.truth_f, &self.readers, &self.points[i], self.truth[i].value, u64::MAX, None))
    }

    /// Whether point `i` is ill-conditioned (its condition above [`ILL_CONDITIONED_ULPS`]): from the first order
    /// where there is one and it settles the question ([`FirstOrder`]), else exactly.
    fn ill(&self, i: usize) -> bool {
        let exact = |r: &Self| r.cond(i) > ILL_CONDITIONED_ULPS;
        if self.cond[i].get().is_some() {
            return exact(self);
        }
        match self.first.as_ref().map(|f| f[i]) {
            Some(FirstOrder::Ill) => true,
            Some(FirstOrder::Check(0)) => false,
            Some(FirstOrder::Check(_)) => unreachable!("a check is made when the first order is"),
            Some(FirstOrder::Checked(k)) => k > ILL_CONDITIONED_ULPS,
            Some(FirstOrder::Exact) | None => exact(self),
        }
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
        // The condition shown at the worst well-conditioned point is the exact one, wherever it was judged.
        s.condition_at_worst_well = acc.worst_well_at.and_then(|(i, judged)| judged.then(|| self.cond(i)));
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
    /// The index of `stats.worst_well`, and whether its condition was judged there.
    worst_well_at: Option<(usize, bool)>,
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
        if ((got < 0.0 && t.is_sign_positive()) || (got > 0.0 && t.is_sign_negative())) && !r.ill(i) {
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
        let judged = c == Conditioning::Everywhere || b > TARGET_BITS;
        if judged && r.ill(i) {
            self.stats.ill_conditioned += 1;
        } else {
            self.stats.over_target += usize::from(b > TARGET_BITS);
            if b > self.stats.max_bits_well || self.stats.worst_well.is_none() {
                self.stats.max_bits_well = b;
                self.stats.worst_well = Some(w(b));
                self.worst_well_at = Some((i, judged));
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
            self.worst_well_at = o.worst_well_at;
        }
        self.sum += o.sum;
        self.defined += o.defined;
        self
    }
}

/// Bits of error of `ev` against the truth of `truth_f` (the formula as written, baked values folded) at
/// `points`, the conditioning measured everywhere; in parallel.
pub fn measure(ev: &dyn Evaluator, truth_f: &Formula, points: &[Point]) -> ErrorStats {
    Reference::everywhere(truth_f, points.to_vec()).measure(ev, Conditioning::Everywhere)
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

#[cfg(test)]
mod tests {
    use super::*;

    /// The first order and its bound classify every point as the exact condition does (κ ≤ 16 or not), on
    /// formulas with steps, kinks, powers, quotients and functions near their singularities, over the sample's
    /// points (edge classes included); and where it decides without moving anything, the exact condition is on
    /// the side it says.
    #[test]
    fn first_order_classifies_as_the_exact_condition() {
        let sources = [
            "param m = 0.3 in 0.01..1\nlet d = exp((NH^2 - 1)/(m*m*NH^2))\nNL <= 0 ? 0 : d*VH/(NL*NV + m) + NV^3",
            "param n = 50 in 1..1000\npow(NH, n)*(n + 2)/(2*pi)",
            "param a = 0.5 in 0..1\nclamp(1 - VH, 0, 1)^5*(1 - a) + a*sqrt(1 - NL*NL)/max(NV, 0.001)",
            "param s = 25 in 0..90\nlet b = min(acos(NL), acos(NV))\nsin(max(acos(NL), acos(NV)))*tan(b)*s/90 + atan(NH/(VH + 0.1))",
            "param k = 2 in 0.1..10\nfloor(k*NH*4)/4 + ln(NL + 1e-3)*abs(NV - 0.5) + (NH < VH ? NL : NV)",
        ];
        let mut decided = 0;
        for src in sources {
            let f = crate::front::parse("t.brdf", src).unwrap();
            let truth_f = crate::simplify::bake_only(&f, &[]);
            let points = super::super::sample(&f, &[], 3000, 7);
            let r = Reference::everywhere(&truth_f, points);
            let first = r.first.as_ref().unwrap();
            for (i, &verdict) in first.iter().enumerate() {
                if !r.truth[i].value.is_finite() {
                    continue;
                }
                let exact = condition_ulps(&truth_f, &r.points[i], r.truth[i].value);
                let ill = exact > ILL_CONDITIONED_ULPS;
                assert_eq!(r.ill(i), ill, "{src}: at {:?} the exact condition is {exact} ulps, the first order says {verdict:?}", r.points[i]);
                match verdict {
                    FirstOrder::Ill => assert!(ill),
                    FirstOrder::Check(0) => assert!(!ill),
                    _ => continue,
                }
                decided += 1;
            }
        }
        assert!(decided > 10_000, "the first order decided only {decided} points");
    }
}
