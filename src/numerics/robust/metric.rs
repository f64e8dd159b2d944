//! The pass's metric and judgement: bits of error (Herbie's `log2(ulps + 1)`), the statistics of a measurement,
//! and when one measurement is better than another (module docs of [`super`]).

use super::sample::Point;

/// The error allowed where the formula is well conditioned: 4 bits, 15 ulp (issue 12).
pub const TARGET_BITS: f64 = 4.0;

/// A 1-ulp change of an input moving the truth by more than this many ulps marks a point ill-conditioned.
pub const ILL_CONDITIONED_ULPS: f64 = 16.0;

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
    /// ([`truth::limit`](crate::numerics::truth::limit)): left out of the averages, as Herbie samples only points with a defined truth.
    pub undefined: usize,
    /// The exact value is not finite but its limit along an input exactly on an edge is ([`truth::limit`](crate::numerics::truth::limit)):
    /// counted like any point, with the limit as the truth (Cook–Torrance's G/(NL·NV) at NL = 0).
    pub limits: usize,
    /// The exact value is +∞ or −∞ (a pole: Ward's 1/√(NL·NV) at NL = 0 with a finite numerator): left out of
    /// the averages; the result must be that infinity.
    pub poles: usize,
    /// Poles where the result is not the exact infinity (0 or a finite number or NaN).
    pub pole_misses: usize,
    pub first_pole_miss: Option<Worst>,
    /// The result is below 0 where the truth is ≥ +0, or above 0 where it is ≤ −0, at a well-conditioned point
    /// (near a zero crossing an ill-conditioned value may take either sign).
    pub wrong_sign: usize,
    pub first_wrong_sign: Option<Worst>,
    /// Points where the formula is ill-conditioned by nature (module docs). Exact when the conditioning was
    /// measured everywhere ([`Conditioning::Everywhere`](super::measure::Conditioning::Everywhere)); otherwise only points with more than
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
    /// The condition (ulps, [`condition_ulps`](super::measure::condition_ulps)) at `worst_well`, when it was measured there.
    pub condition_at_worst_well: Option<f64>,
}

impl ErrorStats {
    /// The wrong answers, as opposed to imprecise ones: NaN/∞ where the truth is finite, missed poles, results
    /// of the wrong sign, well-conditioned points beyond [`TARGET_BITS`] (in that order; the first three are
    /// the invariants no rewrite may trade).
    pub(super) fn wrong_answers(&self) -> [usize; 4] {
        [self.nonfinite, self.pole_misses, self.wrong_sign, self.over_target]
    }
}

/// `a` is more accurate than `b` (module docs). First the invariants no rewrite may trade: no more NaN/∞ where
/// the truth is finite, missed poles or wrong signs (fewer of any is better); then no well-conditioned point
/// newly beyond [`TARGET_BITS`] (fewer is better); then a lower well-conditioned maximum (by half a bit); then,
/// at no higher maximum or average, fewer points near the target or a lower average.
pub(super) fn better(a: &ErrorStats, b: &ErrorStats) -> bool {
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
pub(super) fn better_measured(a: &ErrorStats, b: &ErrorStats) -> bool {
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
pub(super) fn pays_for_regressions(a: &ErrorStats, b: &ErrorStats) -> bool {
    let wrong = |s: &ErrorStats| s.wrong_answers().iter().sum::<usize>();
    a.regressions == 0 || wrong(b) >= wrong(a) + 10 * a.regressions
}

/// `a` gets more points right than `b` in the sense of lobe's promise ([`ErrorStats::wrong_answers`]) and none
/// fewer: such a rewrite may cost up to [`NONFINITE_BUDGET`] × the fastest form, since those are wrong answers,
/// not imprecise ones.
pub(super) fn keeps_promise(a: &ErrorStats, b: &ErrorStats) -> bool {
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

#[cfg(test)]
mod tests {
    use super::*;

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
